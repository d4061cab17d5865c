"""rsrivc_simulate: success path, bag contents against the scenario, and one-line errors without partial bags."""
import shutil
import subprocess

import numpy as np
import pytest

from additive_rsrivc_ros.cli import simulate as cli
from additive_rsrivc_ros.io.bagio import read_signals
from additive_rsrivc_ros.sim.scenarios import build


def _run(argv, capsys):
    rc = cli.main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_writes_the_scenario(tmp_path, capsys, storage):
    out = tmp_path / "bag"
    rc, stdout, err = _run(["--scenario", "beam_fault", "--out", str(out), "--duration", "2", "--seed", "5",
                            "--storage", storage, "--set", "fault_time_s=1.5"], capsys)
    assert rc == 0 and err == "" and "wrote" in stdout
    data = build("beam_fault", duration_s=2.0, seed=5, fault_time_s=1.5)
    sig = read_signals(out, data.config)
    assert sig.storage == storage
    np.testing.assert_array_equal(sig.y, data.y)
    np.testing.assert_array_equal(sig.u, data.u)
    np.testing.assert_array_equal(sig.r, data.r)
    assert sig.truth_fault == data.fault_events and sig.truth_fault[-1]["time_s"] == 1.5
    assert sig.metadata["additive_rsrivc.scenario"] == "beam_fault"
    assert (out / ("bag.mcap" if storage == "mcap" else "bag.db3")).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_list(capsys):
    rc, stdout, _ = _run(["--list"], capsys)
    assert rc == 0 and "beam_fault" in stdout and "sensor_fault" in stdout


@pytest.mark.parametrize("argv,pattern", [
    (["--scenario", "nope"], "unknown scenario"),
    (["--scenario", "beam", "--duration", "-1"], "--duration must be a positive"),
    (["--scenario", "beam", "--duration", "nan"], "--duration must be a positive"),
    (["--scenario", "beam", "--seed", "-3"], "--seed must be non-negative"),
    (["--scenario", "beam", "--storage", "zip"], "invalid choice"),
    (["--scenario", "beam", "--duration", "1", "--set", "nonsense=1"], "no parameter"),
    (["--scenario", "beam"], None),  # --out added below pointing into a missing directory
])
def test_bad_input_is_one_line_and_leaves_nothing(tmp_path, capsys, argv, pattern):
    target = tmp_path / "missing" / "bag" if pattern is None else tmp_path / "bag"
    with pytest.raises(SystemExit) if pattern == "invalid choice" else _nullctx() as exc:
        rc, _, err = _run([*argv, "--out", str(target)], capsys)
    if pattern == "invalid choice":
        rc, err = exc.value.code, capsys.readouterr().err
    assert rc != 0
    assert err.count("\n") == 1 and "Traceback" not in err
    assert (pattern or "does not exist") in err
    assert list(tmp_path.iterdir()) == []


def test_existing_bag_is_not_overwritten(tmp_path, capsys):
    target = tmp_path / "bag"
    target.mkdir()
    (target / "keep.txt").write_text("x")
    rc, _, err = _run(["--scenario", "beam", "--out", str(target), "--duration", "1"], capsys)
    assert rc == 1 and "exists already" in err and err.count("\n") == 1
    assert [p.name for p in target.iterdir()] == ["keep.txt"]


def test_failure_during_writing_leaves_no_partial_bag(tmp_path, capsys, monkeypatch):
    from additive_rsrivc_ros.io import bagio

    real = bagio.write_bag

    def broken(path, *a, **kw):
        real(path, *a, **kw)
        raise OSError("disk full")

    monkeypatch.setattr(bagio, "write_bag", broken)
    rc, _, err = _run(["--scenario", "paper_example", "--out", str(tmp_path / "bag"), "--duration", "10"], capsys)
    assert rc == 1 and "disk full" in err
    assert list(tmp_path.iterdir()) == []


def test_console_script_exit_status(tmp_path):
    exe = shutil.which("rsrivc_simulate")
    assert exe, "console script rsrivc_simulate is not installed (pip install -e .)"
    bad = subprocess.run([exe, "--scenario", "beam", "--out", str(tmp_path / "b"), "--duration", "-5"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr
    ok = subprocess.run([exe, "--scenario", "paper_example", "--out", str(tmp_path / "b"), "--duration", "5"],
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / "b" / "metadata.yaml").exists() and (tmp_path / "b" / "b.mcap").exists()


class _nullctx:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False
