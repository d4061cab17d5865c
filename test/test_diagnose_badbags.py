"""rsrivc_diagnose on bad input: one clear line on stderr, non-zero exit, no traceback."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from additive_rsrivc_ros.cli import diagnose
from additive_rsrivc_ros.io.bagio import write_bag

REPO = Path(__file__).resolve().parents[1]
PARAMS = REPO / "config" / "beam_fault.yaml"   # 4096 Hz, closed loop
RATE = 4096.0


def _signals(n: int = 2048) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return rng.standard_normal(n), rng.standard_normal(n), rng.standard_normal(n)


def _wrong_type_bag(path: Path) -> Path:
    """/reference as std_msgs/msg/String."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    f64, s = ts.types["std_msgs/msg/Float64"], ts.types["std_msgs/msg/String"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cr = w.add_connection("/reference", s.__msgtype__, typestore=ts)
        cu = w.add_connection("/plant_input", f64.__msgtype__, typestore=ts)
        cy = w.add_connection("/plant_output", f64.__msgtype__, typestore=ts)
        for k in range(100):
            t = 1_700_000_000 * 10**9 + k * 244_140
            w.write(cr, t, ts.serialize_cdr(s(data="x"), s.__msgtype__))
            w.write(cu, t, ts.serialize_cdr(f64(data=1.0), f64.__msgtype__))
            w.write(cy, t, ts.serialize_cdr(f64(data=1.0), f64.__msgtype__))
    return path


def _empty_bag(path: Path) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic in ("/reference", "/plant_input", "/plant_output"):
            w.add_connection(topic, "std_msgs/msg/Float64", typestore=ts)
    return path


def _truncated(tmp: Path) -> Path:
    bag = shutil.copytree(REPO / "bags" / "beam_fault", tmp / "truncated")
    f = next(bag.glob("*.mcap"))
    os.truncate(f, f.stat().st_size // 2)
    return bag


def _corrupt(tmp: Path) -> Path:
    bag = shutil.copytree(REPO / "bags" / "beam_fault", tmp / "corrupt")
    f = next(bag.glob("*.mcap"))
    data = bytearray(f.read_bytes())
    third = len(data) // 3
    data[third:third + 5000] = b"\x5a" * 5000
    f.write_bytes(bytes(data))
    return bag


def _cases(tmp: Path) -> dict[str, tuple[Path, str]]:
    """name -> (bag, a word the one-line message must contain)."""
    r, u, y = _signals()
    (tmp / "nometa").mkdir()
    (tmp / "nometa" / "x.mcap").write_bytes(b"")
    return {
        "missing_topic": (write_bag(tmp / "open", RATE, u, y), "/reference"),
        "wrong_type": (_wrong_type_bag(tmp / "wrongtype"), "type"),
        "truncated": (_truncated(tmp), "corrupt"),
        "corrupt": (_corrupt(tmp), "corrupt"),
        "empty": (_empty_bag(tmp / "empty"), "empty"),
        "rate_mismatch": (write_bag(tmp / "rate", 1000.0, u, y, r), "loop_rate_hz"),
        "no_metadata": (tmp / "nometa", "metadata"),
        "not_found": (tmp / "does_not_exist", "not found"),
    }


def test_bad_bags_in_process(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    for name, (bag, word) in _cases(tmp_path).items():
        rc = diagnose.main([str(bag), "--params-file", str(PARAMS), "--out", str(tmp_path / f"out_{name}")])
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert rc == 2, (name, err)
        assert len(lines) == 1 and lines[0].startswith("rsrivc_diagnose: error: "), (name, err)
        assert word in lines[0], (name, lines[0])
        assert not (tmp_path / f"out_{name}" / "estimates.csv").exists()


def test_bad_params_and_options(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    r, u, y = _signals()
    bag = write_bag(tmp_path / "ok", RATE, u, y, r)
    bad_yaml = tmp_path / "bad.yaml"
    bad_yaml.write_text("additive_rsrivc_monitor:\n  ros__parameters:\n    loop_rate_hz: 4096.0\n    nonsense: 1\n")
    not_dir = tmp_path / "file"
    not_dir.write_text("x")
    cases = [
        ([str(bag), "--params-file", str(tmp_path / "missing.yaml")], "not found"),
        ([str(bag), "--params-file", str(bad_yaml)], "nonsense"),
        ([str(bag), "--params-file", str(PARAMS), "--out", str(not_dir)], "not a directory"),
        ([str(bag), "--params-file", str(PARAMS), "--chunk-s", "0"], "chunk"),
    ]
    for argv, word in cases:
        rc = diagnose.main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and word in err[0], (argv, err)
    with pytest.raises(SystemExit) as exc:  # argparse: missing --params-file, still one line
        diagnose.main([str(bag)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--params-file" in err[0]


def test_console_script_no_traceback(tmp_path: Path) -> None:
    """The installed entry point (a fresh interpreter) gives the same single line."""
    bag, _ = _cases(tmp_path)["truncated"]
    res = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.cli.diagnose", str(bag), "--params-file",
                          str(PARAMS), "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert res.stdout == ""


def test_nonfinite_samples_warn_but_run(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """NaNs are not a bad bag: one warning line, the pipeline skips them, exit 0."""
    n = int(6 * RATE)
    rng = np.random.default_rng(5)
    r = np.sign(np.sin(2 * np.pi * 2.0 * np.arange(n) / RATE)) * 0.1
    u = rng.standard_normal(n) * 0.01
    y = rng.standard_normal(n) * 0.01
    y[[100, 5000, 9000]] = np.nan
    bag = write_bag(tmp_path / "nan", RATE, u, y, r)
    rc = diagnose.main([str(bag), "--params-file", str(PARAMS), "--out", str(tmp_path / "o"), "--no-report",
                        "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 0
    assert len(err) == 1 and "warning: 3 non-finite samples (output: 3)" in err[0]
