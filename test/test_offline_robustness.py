"""The offline tools are never confidently wrong (issue 13):

* rsrivc_identify on damaged records (duplicated sample, held sample, NaNs, a 1e300 sample): one warning line
  per category, the bad samples never fitted over (the truth stays within 5 reported std), strict JSON, no
  traceback; a record with no clean stretch is refused with one line;
* rsrivc_diagnose replaces an older output folder whole (never a mix of two runs) and leaves it as it was when
  interrupted by SIGTERM or SIGINT (exit 143/130, one line, no traceback, no temporary folder left);
* the verdict of a bag with a 2 s pause says where the fault tests were blind, never "OK".
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from bag_variants import damage, write_stamped_bag

from additive_rsrivc_ros.cli import diagnose, identify
from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.core.vocabulary import json_clean
from additive_rsrivc_ros.io.bagio import DEFAULT_T0_NS, read_signals, write_bag
from additive_rsrivc_ros.sim.independent import MODE, PAPER_THETAS, PID_DEN, PID_NUM, simulate

REPO = Path(__file__).resolve().parents[1]
BEAM_PARAMS = REPO / "config" / "beam_fault.yaml"
RATE = 20.0
PARAMS_20HZ = """additive_rsrivc_monitor:
  ros__parameters:
    loop_rate_hz: 20.0
    closed_loop: true
    controller.numerator: [0.02329, -0.02058, 0.00454]
    controller.denominator: [1.0, -1.0, 0.0]
    modes.natural_frequency_hz: [0.33, 0.76]
    modes.damping_ratio: [0.27, 0.022]
    modes.gain: [3.1, 0.95]
"""


def strict_json(text: str) -> object:
    """json.loads that refuses NaN/Infinity tokens (what strict parsers in other languages do)."""
    def no_constant(tok: str) -> None:
        raise ValueError(f"non-standard JSON token {tok}")
    return json.loads(text, parse_constant=no_constant)


# ------------------------------------------------------------------------------------------------ identify
@pytest.fixture(scope="module")
def sim20(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """200 s of the 001 §5.2 closed loop at 20 Hz (truth PAPER_THETAS, noise variance 0.01)."""
    d = tmp_path_factory.mktemp("sim20")
    rng = np.random.default_rng(11)
    n = 4000
    r = rng.standard_normal(n)
    u, y = simulate(PAPER_THETAS, [MODE, MODE], 1 / RATE, r=r, controller=(PID_NUM, PID_DEN),
                    noise=0.1 * rng.standard_normal(n))
    params = d / "params.yaml"
    params.write_text(PARAMS_20HZ)
    t_ns = DEFAULT_T0_NS + np.arange(n, dtype=np.int64) * 50_000_000
    return {"dir": d, "params": str(params), "t_ns": t_ns, "r": r, "u": u, "y": y}


@pytest.mark.parametrize("kind,word,count_key,count", [
    ("duplicate_stamp", "duplicate time stamp", "duplicate_stamps", 1),
    ("held", "held output sample", "held_outputs", 1),
    ("nan40", "non-finite sample", "nonfinite", {"output": 40}),
    ("huge", "absurd magnitude", "absurd_magnitude", {"output": 1}),
])
def test_identify_excludes_bad_samples_with_a_warning(sim20: dict, tmp_path: Path, capsys: pytest.CaptureFixture,
                                                       kind: str, word: str, count_key: str, count: object) -> None:
    s = sim20
    bag = write_stamped_bag(tmp_path / kind, *damage(kind, s["t_ns"], s["r"], s["u"], s["y"], RATE, at_s=80.0))
    out = tmp_path / "model.json"
    rc = identify.main([str(bag), "--params-file", s["params"], "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "Traceback" not in cap.err
    warnings = [ln for ln in cap.err.splitlines() if ln.startswith("rsrivc_identify: warning:")]
    assert warnings and len(warnings) == len(cap.err.strip().splitlines())
    assert sum(word in ln for ln in warnings) == 1, warnings      # one line for the category, with the count
    doc = strict_json(out.read_text())
    assert doc["screening"][count_key] == count
    if kind != "duplicate_stamp":       # the record was split at the bad sample: only the longer side is fitted
        assert doc["screening"]["samples_used"] < 4000 and "longest gap-free segment" in doc["message"]
    else:                               # the duplicate is dropped: every original sample is used
        assert doc["screening"]["samples_used"] == 4000
    for mode, truth in zip(doc["modes"], PAPER_THETAS, strict=True):
        th, sd = np.array(mode["theta"]), np.array(mode["theta_std"])
        assert np.all(np.abs(th - truth) <= 5 * sd), (kind, th, truth, sd)   # 5-sigma: p ~ 6e-7 per value


def test_identify_refuses_a_record_without_a_clean_stretch(sim20: dict, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    """A NaN every 50 samples (2.5 s) leaves no stretch of init_duration_s (5 s): refused, nothing written."""
    s = sim20
    y = s["y"].copy()
    y[::50] = np.nan
    bag = write_stamped_bag(tmp_path / "holes", s["t_ns"], s["r"], s["u"], y)
    out = tmp_path / "model.json"
    rc = identify.main([str(bag), "--params-file", s["params"], "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("rsrivc_identify: error: no clean stretch") and not out.exists()
    assert "warning: 80 non-finite sample(s) (output: 80) excluded" in err[0]


def test_identify_json_is_strict_when_numbers_are_not_finite() -> None:
    doc = json_clean({"a": float("nan"), "b": np.float64(np.inf), "c": np.array([1.0, np.nan]),
                              "d": [np.int64(3), -np.inf]})
    assert strict_json(json.dumps(doc, allow_nan=False)) == {"a": None, "b": None, "c": [1.0, None], "d": [3, None]}


# ------------------------------------------------------------------------------------------------ diagnose output
@pytest.fixture(scope="module")
def short_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 8 s of beam_fault (enough for a first estimate: init_duration_s is 4 s)."""
    cfg = load_config(BEAM_PARAMS)
    sig = read_signals(REPO / "bags" / "beam_fault", cfg)
    n = int(8 * cfg.loop_rate_hz)
    return write_bag(tmp_path_factory.mktemp("short") / "beam8", cfg.loop_rate_hz, sig.u[:n], sig.y[:n], sig.r[:n])


def _old_run(out: Path) -> dict[str, bytes]:
    """An output folder of an older run (recognizable contents)."""
    out.mkdir(parents=True)
    files = {"estimates.csv": b"old estimates\n", "events.csv": b"old events\n",
             "summary.json": b'{"bag": "an older run"}\n', "report.html": b"<html>old</html>\n",
             "modes.png": b"old png"}   # the figure of versions before modes.svg: still ours to replace
    for k, v in files.items():
        (out / k).write_bytes(v)
    return files


def _siblings(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.iterdir() if p.name != out.name)


def test_existing_folder_is_replaced_whole(short_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run" / "out"
    _old_run(out)
    rc = diagnose.main([str(short_bag), "--params-file", str(BEAM_PARAMS), "--out", str(out), "--no-report",
                        "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["estimates.csv", "events.csv", "summary.json"]  # no old report
    summary = strict_json((out / "summary.json").read_text())
    assert summary["bag"] == str(short_bag) and summary["verdict"] in ("DEGRADED", "NO ESTIMATE")
    assert summary["monitored_s"] == 0.0      # 8 s is too short for settling + a baseline: never "OK"
    assert (out / "estimates.csv").read_text().startswith("time_s,mode,natural_frequency_hz,")
    assert _siblings(out) == []               # no temporary folder left behind


def test_folder_with_foreign_files_is_refused(short_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    rc = diagnose.main([str(short_bag), "--params-file", str(BEAM_PARAMS), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "not rsrivc outputs" in err[0]
    assert [p.name for p in out.iterdir()] == ["thesis.tex"]


def _diagnose_proc(bag: Path, out: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", "additive_rsrivc_ros.cli.diagnose", str(bag), "--params-file",
                             str(BEAM_PARAMS), "--out", str(out), "--no-progress"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def handlers_installed(pid: int) -> bool:
    """True once the process catches SIGTERM (Linux /proc SigCgt mask): rsrivc's handlers are active; Python catches
    only SIGINT by default. Before that (interpreter start-up) a signal gets Python's default behaviour."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    except OSError:
        pass
    return False


def _wait_for_handlers(p: subprocess.Popen) -> None:
    deadline = time.monotonic() + 60
    while p.poll() is None and not handlers_installed(p.pid) and time.monotonic() < deadline:
        time.sleep(0.002)


def _check_outcome(out: Path, old: dict[str, bytes], bag: Path, rc: int, err: str, sig: int) -> str:
    """Old folder intact (and an interrupt exit code) or the complete new one; nothing else next to it."""
    assert "Traceback" not in err, err
    assert _siblings(out) == [], _siblings(out)
    names = sorted(p.name for p in out.iterdir())
    if all((out / k).exists() and (out / k).read_bytes() == v for k, v in old.items()) and len(names) == len(old):
        assert rc == 128 + sig, (rc, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("rsrivc_diagnose: interrupted"), err
        return "old"
    assert names == sorted(diagnose.OUTPUT_FILES), names           # complete: every file of the new run
    assert strict_json((out / "summary.json").read_text())["bag"] == str(bag)
    assert rc in (0, 128 + sig), (rc, err)
    return "new"


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc to see the signal handlers")
@pytest.mark.parametrize("sig,delay", [(signal.SIGTERM, 0.5), (signal.SIGTERM, 1.5), (signal.SIGTERM, 3.0),
                                       (signal.SIGINT, 1.0), (signal.SIGINT, 3.0)])
def test_interrupt_leaves_old_or_complete_output(short_bag: Path, tmp_path: Path, sig: int, delay: float) -> None:
    out = tmp_path / "out"
    old = _old_run(out)
    p = _diagnose_proc(short_bag, out)
    _wait_for_handlers(p)        # the delay counts from there (a signal during interpreter start-up: see below)
    try:
        p.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    _check_outcome(out, old, short_bag, p.returncode, err, sig)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_interrupt_while_writing_the_output(short_bag: Path, tmp_path: Path, sig: int) -> None:
    """Signal sent as soon as the temporary output folder appears (CSV/report being written)."""
    out = tmp_path / "out"
    old = _old_run(out)
    p = _diagnose_proc(short_bag, out)
    seen = False
    deadline = time.monotonic() + 120
    while p.poll() is None and time.monotonic() < deadline:
        if any(n.startswith(".out.partial-") for n in os.listdir(tmp_path)):
            seen = True
            p.send_signal(sig)
            break
        time.sleep(0.005)
    _, err = p.communicate(timeout=120)
    assert seen, "the run finished before its temporary folder was seen"
    assert _check_outcome(out, old, short_bag, p.returncode, err, sig) == "old"


# ------------------------------------------------------------------------------------------------ verdict e2e
def test_pause_gives_a_blind_interval_not_ok(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """beam_fault with a 2 s pause at 12 s (during the baseline window): the fault tests are blind from the pause
    until a new baseline is learned; the verdict must say so (FAULT or DEGRADED), never 'OK'."""
    cfg = load_config(BEAM_PARAMS)
    sig = read_signals(REPO / "bags" / "beam_fault", cfg)
    t_ns = sig.t0_ns + np.round(sig.t * 1e9).astype(np.int64)
    bag = write_stamped_bag(tmp_path / "pause", *damage("pause", t_ns, sig.r, sig.u, sig.y, cfg.loop_rate_hz,
                                                         at_s=12.0))
    out = tmp_path / "out"
    rc = diagnose.main([str(bag), "--params-file", str(BEAM_PARAMS), "--out", str(out), "--no-report", "--quiet"])
    line = capsys.readouterr().out.strip()
    assert rc == 0
    summary = strict_json((out / "summary.json").read_text())
    assert summary["verdict"] in ("FAULT", "DEGRADED") and line.startswith(summary["verdict"] + ":")
    duration = summary["duration_s"]
    assert duration == pytest.approx(32.0, abs=0.01)
    blind = [b for b in summary["blind_intervals"] if not b["startup"]]
    gap = [b for b in blind if b["kind"] == "no_data"]
    assert len(gap) == 1 and gap[0]["start_s"] == pytest.approx(12.0, abs=0.11) and \
        gap[0]["end_s"] == pytest.approx(14.0, abs=0.11)
    assert any("data gap" in b["reason"] for b in blind)
    blind_s = sum(b["end_s"] - b["start_s"] for b in summary["blind_intervals"])
    assert summary["monitored_s"] + blind_s == pytest.approx(duration, abs=1e-3)
    assert "data gap" in line and f"of {duration:.1f} s" in line


@pytest.mark.parametrize("exchange", [True, False])
def test_atomic_dir_commit_and_discard(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, exchange: bool) -> None:
    """Both commit paths (renameat2 exchange, and the two-rename fallback) replace the folder whole."""
    from additive_rsrivc_ros.cli import atomic

    if not exchange:
        monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    out = tmp_path / "out"
    _old_run(out)
    d = atomic.AtomicDir(out, diagnose.OWNED_FILES)
    (d.open() / "summary.json").write_text("new")
    d.discard()                                  # abandoned: the old folder stays, the temporary one is gone
    assert (out / "summary.json").read_bytes() == b'{"bag": "an older run"}\n' and _siblings(out) == []
    d = atomic.AtomicDir(out, diagnose.OWNED_FILES)
    (d.open() / "summary.json").write_text("new")
    d.commit()
    d.discard()                                  # no-op after a commit
    assert [p.name for p in out.iterdir()] == ["summary.json"] and (out / "summary.json").read_text() == "new"
    assert _siblings(out) == []


def test_interrupt_inside_a_c_callback_is_kept_not_printed(capsys: pytest.CaptureFixture) -> None:
    """Measured in scripts/study_interrupts.py: a SIGINT landing in numba's llvmlite cache callback was printed as
    a traceback and then lost (the run completed with exit 0). Now it is kept and raised at the next safe point."""
    import ctypes

    from additive_rsrivc_ros.cli import atomic

    def callback() -> None:
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):       # the Python handler runs between these bytecodes, inside the callback
            time.sleep(0.001)

    with atomic.interrupts():
        ctypes.CFUNCTYPE(None)(callback)()          # the Interrupted cannot propagate through C
        assert atomic.received() == signal.SIGTERM
        with pytest.raises(atomic.Interrupted) as exc:
            atomic.raise_if_interrupted()
    assert exc.value.exit_code == 143
    assert "Traceback" not in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) is not atomic._raise   # handlers restored
