"""rsrivc_fleet's drift across short recordings, on a dask LocalCluster with 2 worker processes and real rosbag2 files.

Two simulated machines (additive_rsrivc_ros.sim.fleetsim, open loop, 1 kHz, modes at 15 Hz and 60 Hz, forgetting
memory 20 s, the fault logic's default start-up: 3 memory lengths of settling, a baseline of 5), recorded for 120 s
at a time: too short for the fault tests to learn a baseline, long enough to settle.

* ``line_a``: four recordings whose mode-2 frequency falls 0.5 % per recording (60.00, 59.70, 59.40, 59.10 Hz),
  relevant change 1.25 %: the drift is flagged on line_a, mode 2, natural frequency, down, first reached at rec_03
  (true change 1.0 % at rec_02, 1.5 % at rec_03; output folders are named line_a_rec_03 ...: names repeat).
* ``line_b``: six healthy recordings whose modes vary from recording to recording by 0.3 % (operating point,
  temperature): far more than the within-recording std of a level. Its relevance thresholds are switched off
  (``faults.min_change.*`` at their minimum, spread factor 0), so only the significance test stands between this
  scatter and a false alarm: it must estimate the between-recording variance, not trust the within-recording std.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed")

from additive_rsrivc_ros.cli import fleet  # noqa: E402
from additive_rsrivc_ros.sim import fleetsim  # noqa: E402

DRIFT = 0.005
MACHINE = fleetsim.Machine(modes=((15.0, 0.05, 1.0), (60.0, 0.02, 0.1)), memory_s=20.0, init_duration_s=5.0,
                           settle_memory_lengths=None, baseline_duration_s=None)
NO_RELEVANCE = {"min_change.natural_frequency": 1e-6, "min_change.damping": 1e-6, "min_change.gain": 1e-6,
                "min_change.spread_factor": 0.0}


def _run(argv: list[str]) -> tuple[int, str, str]:
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        rc = fleet.main(argv)
    return rc, so.getvalue(), se.getvalue()


@pytest.fixture(scope="module")
def cluster():
    import logging

    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=logging.ERROR,
                      scheduler_kwargs={"dashboard_address": ":0"}) as c:
        yield c


@pytest.fixture(scope="module")
def two_lines(cluster, tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("lines")
    fleetsim.write_machine_recordings(root / "line_a", 4, drift_per_recording=DRIFT, duration_s=120.0, machine=MACHINE,
                                      seed=3, extra_faults={"min_change.natural_frequency": 0.0125})
    fleetsim.write_machine_recordings(root / "line_b", 6, spread=0.003, duration_s=120.0, machine=MACHINE, seed=4,
                                      extra_faults=NO_RELEVANCE)
    mapping = root / "params_map.yaml"
    mapping.write_text('"*/line_a/*": line_a/machine.yaml\n"*/line_b/*": line_b/machine.yaml\n')
    out = root / "out"
    rc, so, se = _run([str(root), "--params-file", str(mapping), "--out", str(out), "--scheduler",
                       cluster.scheduler_address, "--no-progress", "--group-by", "folder"])
    trend = json.loads((out / "fleet_trend.json").read_text()) if rc == 0 else {}
    machines = {Path(g["machine"]).name: g for g in trend.get("machines", [])}
    return {"rc": rc, "stdout": so, "stderr": se, "out": out, "machines": machines, "root": root}


def test_short_recordings_feed_the_drift_test(two_lines: dict) -> None:
    assert two_lines["rc"] == 0, two_lines["stderr"]
    a = two_lines["machines"]["line_a"]
    assert [b["used"] for b in a["bags"]] == [True] * 4, a["bags"]
    for j, b in enumerate(a["bags"]):
        assert b["verdict"] == "DEGRADED"               # no baseline: the fault tests never ran in 120 s
        assert 2 * MACHINE.memory_s <= b["level_s"] <= 120.0 - 3 * MACHINE.memory_s
        f2, std = b["value"][1][0], b["std"][1][0]
        truth = 60.0 * (1 - DRIFT * j)
        assert abs(f2 - truth) < 0.05 * DRIFT * truth          # the level: a twentieth of the step per recording
        assert 0 < std < 0.01 * DRIFT * truth                   # its std: far below the step


def test_drift_on_short_recordings_names_machine_mode_quantity_direction_first(two_lines: dict) -> None:
    findings = json.loads((two_lines["out"] / "fleet.json").read_text())
    assert len(findings) == 1, findings
    f = findings[0]
    assert Path(f["machine"]).name == "line_a"
    assert (f["mode"], f["quantity"], f["direction"]) == (2, "natural_frequency", "down")
    assert f["first_bag"] == "line_a_rec_03"
    test = next(t for t in two_lines["machines"]["line_a"]["tests"] if t["flagged"])
    assert abs(f["change_percent"] + 1.5) <= 4 * test["change_std_percent"] + 0.03
    html = (two_lines["out"] / "fleet.html").read_text()
    assert "DRIFT: mode 2 natural_frequency down" in html and "line_b" in html
    assert html.count("<svg ") >= 2                                   # one trend figure per machine


def test_recording_to_recording_scatter_does_not_cry_wolf(two_lines: dict) -> None:
    b = two_lines["machines"]["line_b"]
    assert all(r["used"] for r in b["bags"]) and len(b["bags"]) == 6
    tests = {(t["mode"], t["quantity"]): t for t in b["tests"]}
    assert len(tests) == 6 and not any(t["flagged"] for t in tests.values()), [t["reason"] for t in b["tests"]]
    f1 = tests[(1, "natural_frequency")]
    # the scatter between recordings is found (0.3 % of 15 Hz = 0.045 Hz) although each level's std is ~1e-4 Hz
    assert 0.015 < f1["tau"] < 0.15, f1
    assert max(r["std"][0][0] for r in b["bags"]) < 0.005


def test_four_memory_lengths_count(tmp_path: Path) -> None:
    """80 s with 20 s memories: the fault logic settles until about 65 s (5 s initialization, 3 memory lengths); the
    remaining 15 s give the recording's level, with a std that covers so short a settled part."""
    bag = fleetsim.write_recording(tmp_path / "rec", 0, duration_s=80.0, machine=MACHINE, seed=9)
    params = fleetsim.machine_params(tmp_path / "p.yaml", machine=MACHINE)
    res = fleet.run_bag(fleet.BagTask("rec", str(bag), str(params), str(tmp_path / "out"), None, False))
    assert res["ok"] and res["exclusion"] is None, res
    assert 0.5 * MACHINE.memory_s <= res["level_s"] < MACHINE.memory_s
    f2, std = res["modes"][1]["value"][0], res["modes"][1]["std"][0]
    assert abs(f2 - 60.0) < 4 * std and std < 0.01 * DRIFT * 60.0
