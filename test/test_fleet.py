"""rsrivc_fleet end to end on a dask LocalCluster with 2 worker processes, real rosbag2 files.

One simulated machine (additive_rsrivc_ros.sim.fleetsim: open loop, 1 kHz, modes 5 Hz and 20 Hz), recordings one
day apart whose mode-2 natural frequency declines 0.5 % per recording (constant within each 10 s recording, so
no single bag shows it), plus a corrupt bag; and a healthy machine (no drift) with a recording too short to be
monitored.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.distributed")

from additive_rsrivc_ros.cli import diagnose, fleet  # noqa: E402
from additive_rsrivc_ros.sim import fleetsim  # noqa: E402

DRIFT = 0.005                      # per recording
MIN_CHANGE_F = 0.0175              # between the true cumulative changes 1.5 % (rec_03) and 2.0 % (rec_04)
N_BAGS = 6
FLEET_HEADER = ("bag,start_time_s,mode,natural_frequency_hz,damping_ratio,gain,baseline_natural_frequency_hz,"
                "baseline_damping_ratio,baseline_gain,events,verdict")


def _run(argv: list[str]) -> tuple[int, str, str]:
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        rc = fleet.main(argv)
    return rc, so.getvalue(), se.getvalue()


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def cluster():
    """A LocalCluster of 2 single-threaded worker processes (one for the module; rsrivc_fleet --scheduler ADDR)."""
    import logging

    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=logging.ERROR,
                      scheduler_kwargs={"dashboard_address": ":0"}) as c:
        yield c


@pytest.fixture(scope="module")
def drift_run(cluster, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The drifting machine's 6 recordings and a corrupt bag, given in shuffled order, on 2 workers (per-bag
    reports off to keep the test short: the report is rsrivc_diagnose's, tested there)."""
    root = tmp_path_factory.mktemp("fleet")
    bags, params = fleetsim.write_machine_recordings(root / "machine", N_BAGS, drift_per_recording=DRIFT,
                                                     extra_faults={"min_change.natural_frequency": MIN_CHANGE_F})
    corrupt = root / "machine" / "corrupt"
    corrupt.mkdir()
    (corrupt / "metadata.yaml").write_text((bags[0] / "metadata.yaml").read_text())
    (corrupt / "rec_00.mcap").write_bytes((bags[0] / "rec_00.mcap").read_bytes()[:5000])   # truncated
    order = [3, 0, 5, 1, 4, 2]
    argv = [str(bags[i]) for i in order[:3]] + [str(corrupt)] + [str(bags[i]) for i in order[3:]]
    out = root / "out"
    rc, so, se = _run([*argv, "--params-file", str(params), "--out", str(out), "--scheduler",
                       cluster.scheduler_address, "--no-report", "--progress"])
    return {"rc": rc, "stdout": so, "stderr": se, "out": out, "bags": bags, "params": params}


def test_drift_across_recordings_is_flagged(drift_run: dict) -> None:
    out = drift_run["out"]
    assert drift_run["rc"] == 0, drift_run["stderr"]
    findings = json.loads((out / "fleet.json").read_text())
    assert len(findings) == 1, findings           # mode 2's frequency only: nothing on mode 1, damping or gains
    f = findings[0]
    assert list(f) == ["machine", "mode", "quantity", "direction", "first_bag", "change_percent"]
    assert f["machine"] == str(drift_run["params"].resolve())      # one params file: one machine
    assert (f["mode"], f["quantity"], f["direction"]) == (2, "natural_frequency", "down")
    # true cumulative change at the k-th recording: -0.5 k %; the threshold 1.75 % is first reached at rec_04
    assert f["first_bag"] == "rec_04"
    test = next(t for g in json.loads((out / "fleet_trend.json").read_text())["machines"] for t in g["tests"]
                if t["flagged"])
    truth = -100.0 * DRIFT * (N_BAGS - 1)
    assert abs(f["change_percent"] - truth) <= 4.0 * test["change_std_percent"] + 0.02 * abs(truth), test
    # no single bag shows it: every recording is OK without events
    rows = _rows(out / "fleet.csv")
    assert {r["verdict"] for r in rows} == {"OK"} and {r["events"] for r in rows} == {"0"}
    assert "DRIFT: mode 2 natural frequency down" in drift_run["stdout"]
    assert "7 bag(s) on 2 worker(s)" in drift_run["stderr"]
    html = (out / "fleet.html").read_text()
    assert "DRIFT: mode 2 natural_frequency down" in html and "<svg " in html


def test_fleet_csv_contract_order_and_truth(drift_run: dict) -> None:
    out = drift_run["out"]
    text = (out / "fleet.csv").read_text()
    assert text.split("\n", 1)[0] == FLEET_HEADER
    rows = _rows(out / "fleet.csv")
    names = [f"rec_{i:02d}" for i in range(N_BAGS)]
    assert [r["bag"] for r in rows] == [n for n in names for _ in (1, 2)]     # by first sample time, 2 modes each
    assert [int(r["mode"]) for r in rows] == [1, 2] * N_BAGS
    for i, name in enumerate(names):
        mine = [r for r in rows if r["bag"] == name]
        # the first sample's Unix time, as written into the bag (one day apart)
        assert float(mine[0]["start_time_s"]) == pytest.approx(fleetsim.T0_NS / 1e9 + 86400.0 * i, abs=1e-6)
        summary = json.loads((out / name / "summary.json").read_text())
        assert mine[0]["verdict"] == summary["verdict"] and int(mine[0]["events"]) == len(summary["events"])
        f2 = fleetsim.MODES[1][0] * (1 - DRIFT * i)
        # the level of mode 2 against the bag's truth: within a tenth of the per-recording step
        assert abs(float(mine[1]["natural_frequency_hz"]) - f2) < 0.1 * DRIFT * f2
        base = summary["modes"][1]["baseline"]["natural_frequency_hz"]
        assert float(mine[1]["baseline_natural_frequency_hz"]) == base


def test_corrupt_bag_is_reported_and_skipped(drift_run: dict) -> None:
    out, se = drift_run["out"], drift_run["stderr"]
    assert "Traceback" not in se
    lines = [ln for ln in se.splitlines() if "corrupt" in ln]
    assert len(lines) == 1 and "failed, skipped" in lines[0], se
    failures = json.loads((out / "fleet_failures.json").read_text())
    assert [f["bag"] for f in failures] == ["corrupt"] and failures[0]["error"]
    assert not (out / "corrupt").exists()
    assert "corrupt" not in (out / "fleet.csv").read_text()


def _without_run_details(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in ("timings_s", "realtime_factor", "files")}


def test_per_bag_outputs_equal_rsrivc_diagnose(drift_run: dict, tmp_path: Path) -> None:
    bag = drift_run["bags"][2].resolve()
    ref = tmp_path / "ref"
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        rc = diagnose.main([str(bag), "--params-file", str(drift_run["params"].resolve()), "--out", str(ref),
                            "--no-report"])
    assert rc == 0, se.getvalue()
    mine = drift_run["out"] / bag.name
    assert sorted(p.name for p in mine.iterdir()) == sorted(p.name for p in ref.iterdir())
    for name in ("estimates.csv", "events.csv"):
        assert (mine / name).read_bytes() == (ref / name).read_bytes(), name
    a, b = (_without_run_details(json.loads((d / "summary.json").read_text())) for d in (mine, ref))
    assert a == b, {k: (a.get(k), b.get(k)) for k in set(a) | set(b) if a.get(k) != b.get(k)}


def test_reports_are_on_by_default(tmp_path: Path) -> None:
    bag = tmp_path / "b"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("x: 1\n")
    params = fleetsim.machine_params(tmp_path / "p.yaml")
    args = fleet._parser().parse_args([str(bag), "--params-file", str(params), "--out", str(tmp_path / "o")])
    (task,), _ = fleet.make_tasks(args)
    assert task.report and task.out_dir == str((tmp_path / "o" / "b").resolve())


def test_healthy_fleet_has_no_drift_and_short_bag_is_excluded(cluster, tmp_path: Path) -> None:
    bags, params = fleetsim.write_machine_recordings(tmp_path / "healthy", N_BAGS, seed=7)
    short = fleetsim.write_recording(tmp_path / "healthy" / "short", N_BAGS, duration_s=5.0, seed=7)
    mapping = tmp_path / "map.yaml"                       # a mapping file: every bag of this folder -> one machine
    mapping.write_text(f'"*/healthy/*": {params.relative_to(tmp_path)}\n')
    out = tmp_path / "out"
    rc, so, se = _run([str(tmp_path / "healthy"), "--params-file", str(mapping), "--out", str(out), "--scheduler",
                       cluster.scheduler_address, "--no-report", "--no-progress"])
    assert rc == 0, se
    assert json.loads((out / "fleet.json").read_text()) == []
    trend = json.loads((out / "fleet_trend.json").read_text())["machines"][0]
    assert not any(t["flagged"] for t in trend["tests"])
    assert sum(1 for t in trend["tests"] if len(t["indices"]) == N_BAGS) == 6          # 2 modes x 3 quantities
    (row,) = [b for b in trend["bags"] if b["bag"] == short.name]
    assert not row["used"] and "no settled estimate" in row["exclusion"]   # a bag that never settled: no level
    assert f"not in the drift test: {short.name}" in so
    assert trend["machine"] == "*/healthy/*"
    assert not (out / bags[0].name / "report.html").exists()          # --no-report passed to rsrivc_diagnose


def test_missing_dask_gives_a_one_line_hint(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    rc, _, se = _run([str(tmp_path), "--params-file", "x.yaml", "--out", str(tmp_path / "o")])
    assert rc == 2 and se.count("\n") == 1 and "pip install 'additive_rsrivc_ros[fleet]'" in se


@pytest.mark.parametrize("case", ["missing", "no_bags", "bad_params", "bad_workers"])
def test_bad_arguments_are_one_line(case: str, tmp_path: Path) -> None:
    params = fleetsim.machine_params(tmp_path / "p.yaml")
    bag = tmp_path / "empty"
    bag.mkdir()
    argv = {"missing": [str(tmp_path / "nope"), "--params-file", str(params)],
            "no_bags": [str(bag), "--params-file", str(params)],
            "bad_params": [str(bag), "--params-file", str(tmp_path / "none.yaml")],
            "bad_workers": [str(bag), "--params-file", str(params), "--workers", "0"]}[case]
    rc, so, se = _run([*argv, "--out", str(tmp_path / "o")])
    assert rc == 2 and se.count("\n") == 1 and se.startswith("rsrivc_fleet: error:"), se


def test_params_mapping_file(tmp_path: Path) -> None:
    (tmp_path / "cfg").mkdir()
    mapping = tmp_path / "cfg" / "fleet_params.yaml"
    mapping.write_text('"*/machine_a/*": a.yaml\n"b_*": /abs/b.yaml\n')
    resolve = fleet.params_resolver(str(mapping))
    a = tmp_path / "machine_a" / "rec1"
    assert resolve(a, str(a)) == (str(tmp_path / "cfg" / "a.yaml"), "*/machine_a/*")      # (params, machine)
    assert resolve(tmp_path / "x" / "b_rec", "x/b_rec") == ("/abs/b.yaml", "b_*")       # matched by the bag's name
    assert resolve(tmp_path / "c_rec", "c_rec") is None
    params = fleetsim.machine_params(tmp_path / "p.yaml")
    assert fleet.params_resolver(str(params))(a, str(a)) == (str(params), str(params))   # every bag, one machine


def test_find_bags_searches_directories_and_skips_the_output(tmp_path: Path) -> None:
    for d in ("a", "n/c", "out/old"):
        (tmp_path / d).mkdir(parents=True)
        (tmp_path / d / "metadata.yaml").write_text("x: 1\n")
    (tmp_path / "a" / "sub").mkdir()
    (tmp_path / "a" / "sub" / "metadata.yaml").write_text("x: 1\n")      # inside a bag: not a bag of its own
    found = fleet.find_bags([str(tmp_path), str(tmp_path / "a")], tmp_path / "out")
    assert found == [tmp_path / "a", tmp_path / "n" / "c"]


def test_bag_names_are_unique() -> None:
    names = fleet.bag_names([Path("/d/m1/rec"), Path("/d/m2/rec"), Path("/d/m3/other")])
    assert names == ["m1_rec", "m2_rec", "other"]
    assert len(set(fleet.bag_names([Path("/a/x/rec"), Path("/b/x/rec")]))) == 2


def test_every_bag_failed_exits_1(tmp_path: Path) -> None:
    """Also the tool's own LocalCluster (--workers 1)."""
    params = fleetsim.machine_params(tmp_path / "p.yaml")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("not: a bag\n")
    rc, _, se = _run([str(bad), "--params-file", str(params), "--out", str(tmp_path / "o"), "--workers", "1",
                      "--no-progress"])
    assert rc == 1 and "bad: failed, skipped" in se and "Traceback" not in se and "on 1 worker(s)" in se
    assert json.loads((tmp_path / "o" / "fleet.json").read_text()) == []
    assert np.size(_rows(tmp_path / "o" / "fleet.csv")) == 0


def test_incremental_run_computes_only_new_or_changed_bags(cluster, tmp_path: Path) -> None:
    """A folder that gained a recording: the second run diagnoses only the new bag and gives the same fleet.csv as
    a run from scratch; a changed params file, or a bag's output folder removed, recomputes what it touches."""
    folder = tmp_path / "m"
    _, params = fleetsim.write_machine_recordings(folder, 3, seed=11)
    out = tmp_path / "out"
    base = [str(folder), "--params-file", str(params), "--out", str(out), "--scheduler", cluster.scheduler_address,
            "--no-report", "--no-progress"]
    rc, so, se = _run(base)
    assert rc == 0 and "3 bag(s) on 2 worker(s)" in se and "(3 computed, 0 reused)" in so, se
    stamps = {p.parent.name: p.stat().st_mtime_ns for p in out.glob("rec_*/summary.json")}
    fleetsim.write_recording(folder / "rec_03", 3, seed=11)               # today's recording
    rc, so, se = _run(base)
    assert rc == 0 and "1 bag(s) on 2 worker(s)" in se and "3 bag(s) unchanged" in se, se
    assert "(1 computed, 3 reused)" in so
    assert {p.parent.name: p.stat().st_mtime_ns for p in out.glob("rec_0[012]/summary.json")} == stamps
    fresh = tmp_path / "fresh"
    rc, _, se = _run([*base[:4], str(fresh), *base[5:]])
    assert rc == 0, se
    assert (out / "fleet.csv").read_bytes() == (fresh / "fleet.csv").read_bytes()
    assert len(_rows(out / "fleet.csv")) == 4 * 2
    shutil.rmtree(out / "rec_01")                                           # an output folder gone: that bag again
    rc, so, se = _run(base)
    assert rc == 0 and "(1 computed, 3 reused)" in so and (out / "rec_01" / "summary.json").is_file(), se
    params.write_text(params.read_text() + "      min_change.gain: 0.2\n")   # a changed params file: every bag
    rc, so, se = _run(base)
    assert rc == 0 and "4 bag(s) on 2 worker(s)" in se and "(4 computed, 0 reused)" in so, se
    rc, so, se = _run([*base, "--recompute"])
    assert rc == 0 and "(4 computed, 0 reused)" in so, se
