"""rsrivc_fleet on an external cluster: a ``dask scheduler`` and two ``dask worker`` processes (each under its nanny)
started from the command line on 127.0.0.1, real rosbag2 files.

Eight recordings of one simulated machine (additive_rsrivc_ros.sim.fleetsim), a truncated (corrupt) bag and a bag
without the output topic. While the run is under way, one worker process is killed (SIGKILL) in the middle of a
task: its task goes to another worker, so every good recording has its result, the two bad bags (and only they)
are in fleet_failures.json, and no temporary folder is left behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.distributed")

from dask.distributed import Client  # noqa: E402

from additive_rsrivc_ros.cli import fleet  # noqa: E402
from additive_rsrivc_ros.cli.dask_loopback import LoopbackCluster  # noqa: E402
from additive_rsrivc_ros.io.bagio import write_bag  # noqa: E402
from additive_rsrivc_ros.sim import fleetsim  # noqa: E402

N_GOOD = 8


def _bad_bags(folder: Path, good: Path) -> None:
    corrupt = folder / "corrupt"
    corrupt.mkdir()
    (corrupt / "metadata.yaml").write_text((good / "metadata.yaml").read_text())
    mcap = next(good.glob("*.mcap"))
    (corrupt / mcap.name).write_bytes(mcap.read_bytes()[:5000])
    rng = np.random.default_rng(0)
    u = rng.standard_normal(5000)
    write_bag(folder / "missing_topics", 1000.0, u, u, topics={"output": "/other/plant_output"})


def test_fleets_own_cluster_has_the_worker_settings() -> None:
    """dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers, which costs a diagnosis ~20 % of CPU time in
    page faults (every large array mapped afresh): rsrivc_fleet's LocalCluster starts its workers without it."""
    client, cluster = fleet.start_client(None, 1)
    try:
        assert set(client.run(os.getenv, "MALLOC_TRIM_THRESHOLD_").values()) == {None}
        assert set(client.run(os.getenv, "OPENBLAS_NUM_THREADS").values()) == {"1"}
    finally:
        fleet.close_client(client, cluster)


def test_killed_worker_loses_no_result_and_bad_bags_do_not_stop_the_others(tmp_path: Path) -> None:
    folder = tmp_path / "fleet"
    bags, params = fleetsim.write_machine_recordings(folder, N_GOOD, duration_s=20.0, seed=5)
    _bad_bags(folder, bags[0])
    out = tmp_path / "out"
    so, se = io.StringIO(), io.StringIO()
    with LoopbackCluster(workers=2) as cluster:
        pids_before = cluster.worker_pids()
        assert len(pids_before) == 2
        result: dict = {}

        def run() -> None:
            with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
                result["rc"] = fleet.main([str(folder), "--params-file", str(params), "--out", str(out),
                                           "--scheduler", cluster.address, "--no-report", "--no-progress"])

        runner = threading.Thread(target=run)
        runner.start()
        killed, in_flight = None, []
        addr, pid = next(iter(pids_before.items()))
        with Client(cluster.address, timeout="10s") as client:
            assert set(client.run(os.getenv, "MALLOC_TRIM_THRESHOLD_").values()) == {None}
            t_end = time.monotonic() + 120.0
            while runner.is_alive() and time.monotonic() < t_end:
                done = list(out.glob("rec_*/summary.json")) if out.exists() else []
                in_flight = list(client.processing([addr]).get(addr, ()))
                if done and in_flight:    # a task has finished and this worker is on its next one: kill it
                    os.kill(pid, signal.SIGKILL)
                    killed = pid
                    break
                time.sleep(0.02)
        runner.join(300.0)
        assert not runner.is_alive()
        pids_after = cluster.worker_pids()
    assert killed is not None and in_flight, "the worker was never killed in the middle of a task"
    assert killed not in pids_after.values()                   # the worker did die (its nanny started another)
    assert result["rc"] == 0, se.getvalue()
    good_done = sorted(p.parent.name for p in out.glob("rec_*/summary.json"))
    assert good_done == [b.name for b in bags]
    rows = {r.split(",")[0] for r in (out / "fleet.csv").read_text().splitlines()[1:]}
    assert rows == {b.name for b in bags}
    failures = {f["bag"]: f["error"] for f in json.loads((out / "fleet_failures.json").read_text())}
    assert set(failures) == {"corrupt", "missing_topics"}, failures
    assert "plant_output" in failures["missing_topics"] or "output" in failures["missing_topics"]
    assert not list(out.glob(".*.partial-*"))                    # the dead worker's temporary folder is gone
    assert f"{N_GOOD} of {N_GOOD + 2} bag(s) diagnosed" in so.getvalue()
