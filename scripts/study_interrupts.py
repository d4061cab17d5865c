#!/usr/bin/env python3
"""Interrupt rsrivc_diagnose at random moments and check that its output folder is never a mix of two runs.

    python scripts/study_interrupts.py [--trials 50] [--bag bags/beam_fault] [--params config/beam_fault.yaml]

First one uninterrupted run of ``--old-bag`` (default bags/beam) makes the "older run" folder, and one of
``--bag`` measures the full run time T. Then each trial starts ``rsrivc_diagnose BAG --out DIR`` (half of the
trials with DIR holding the older run's output, half with no DIR), sends SIGTERM or SIGINT (alternating) at a
moment drawn uniformly from [0, 1.1 T], and classifies what is left:

* ``complete``: every output file of the new run (summary.json names BAG, CSV headers as in the contract);
* ``old intact``: the older run's folder, byte for byte;
* ``no folder``: DIR absent (only possible when it was absent before);
* ``MIXED``: anything else (files of both runs, missing files, a half-written file).

It also counts tracebacks on stderr, temporary folders left next to DIR, interrupted runs whose stderr is not
exactly one line, and the exit codes. Prints one table; exit status 1 if any trial was MIXED, left a temporary
folder or printed a traceback.
"""

from __future__ import annotations

import argparse
import collections
import filecmp
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from additive_rsrivc_ros.cli.diagnose import OUTPUT_FILES  # noqa: E402
from additive_rsrivc_ros.core.vocabulary import ESTIMATES_HEADER, EVENTS_HEADER  # noqa: E402


def _cmd(bag: Path, params: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "additive_rsrivc_ros.cli.diagnose", str(bag), "--params-file", str(params),
            "--out", str(out), "--no-progress", "--quiet"]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _complete(out: Path, bag: Path) -> bool:
    if sorted(p.name for p in out.iterdir()) != sorted(OUTPUT_FILES):
        return False
    try:
        summary = json.loads((out / "summary.json").read_text())
        est = (out / "estimates.csv").read_text().splitlines()
        ev = (out / "events.csv").read_text().splitlines()
    except (OSError, ValueError):
        return False
    return (summary.get("bag") == str(bag) and "verdict" in summary and est[0] == ",".join(ESTIMATES_HEADER)
            and ev[0] == ",".join(EVENTS_HEADER) and (out / "report.html").read_text().rstrip().endswith("</html>"))


def _same_tree(a: Path, b: Path) -> bool:
    cmp = filecmp.dircmp(a, b)
    if cmp.left_only or cmp.right_only:
        return False
    _, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    return not mismatch and not errors


def _catches_sigterm(pid: int) -> bool:
    """Whether rsrivc's handlers are installed (Linux /proc SigCgt: Python itself catches only SIGINT)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    except OSError:
        pass
    return False


def classify(out: Path, old: Path | None, bag: Path) -> str:
    if not out.exists():
        return "no folder"
    if old is not None and _same_tree(out, old):
        return "old intact"
    return "complete" if _complete(out, bag) else "MIXED"


def trial(k: int, bag: Path, params: Path, work: Path, old: Path, t_full: float, rng: random.Random) -> dict:
    sig = signal.SIGTERM if k % 2 == 0 else signal.SIGINT
    with_old = (k // 2) % 2 == 0
    out = work / f"t{k:03d}" / "out"
    out.parent.mkdir(parents=True)
    if with_old:
        shutil.copytree(old, out)
    delay = rng.uniform(0.0, 1.1 * t_full)
    p = subprocess.Popen(_cmd(bag, params, out), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         env=_env())
    sent = early = False
    try:
        p.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        early = not _catches_sigterm(p.pid)
        p.send_signal(sig)
        sent = True
    _, err = p.communicate(timeout=600)
    left = sorted(x.name for x in out.parent.iterdir() if x.name != "out")
    outcome = classify(out, old if with_old else None, bag)
    interrupted = p.returncode in (130, 143)
    return {"signal": sig.name, "delay_s": delay, "sent": sent, "early": early, "with_old": with_old,
            "rc": p.returncode, "outcome": outcome, "traceback": "Traceback" in err, "leftovers": left,
            "bad_stderr": interrupted and len(err.strip().splitlines()) != 1, "stderr": err.strip()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--bag", default=str(REPO / "bags" / "beam_fault"))
    ap.add_argument("--old-bag", default=str(REPO / "bags" / "beam"))
    ap.add_argument("--params", default=str(REPO / "config" / "beam_fault.yaml"))
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    bag, params = Path(args.bag).resolve(), Path(args.params).resolve()
    work = Path(tempfile.mkdtemp(prefix="study_interrupts_"))
    try:
        old = work / "old"
        subprocess.run(_cmd(Path(args.old_bag).resolve(), params, old), check=True, env=_env())
        t0 = time.monotonic()
        subprocess.run(_cmd(bag, params, work / "reference"), check=True, env=_env())
        t_full = time.monotonic() - t0
        print(f"uninterrupted run: {t_full:.1f} s; {args.trials} trials, signal at U(0, {1.1 * t_full:.1f}) s")
        rng = random.Random(args.seed)
        rows = []
        for k in range(args.trials):
            rows.append(trial(k, bag, params, work, old, t_full, rng))
            r = rows[-1]
            flags = ("  TRACEBACK" if r["traceback"] else "") + ("  (during start-up)" if r["early"] else "") + \
                (f"  LEFTOVERS {r['leftovers']}" if r["leftovers"] else "")
            print(f"  trial {k:3d}: {r['signal']:7s} at {r['delay_s']:5.1f} s "
                  f"{'(old folder)' if r['with_old'] else '(no folder)':13s} -> {r['outcome']:10s} rc={r['rc']}{flags}",
                  flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print("\noutcome by starting state and signal")
    table = collections.Counter((r["with_old"], r["signal"], r["outcome"]) for r in rows)
    print(f"  {'start':12s} {'signal':8s} {'complete':>9s} {'no folder':>10s} {'old intact':>11s} {'MIXED':>6s}")
    for with_old in (True, False):
        for s in ("SIGTERM", "SIGINT"):
            c = [table[(with_old, s, o)] for o in ("complete", "no folder", "old intact", "MIXED")]
            print(f"  {'old folder' if with_old else 'no folder':12s} {s:8s} {c[0]:9d} {c[1]:10d} {c[2]:11d} {c[3]:6d}")
    codes = collections.Counter(r["rc"] for r in rows)
    print("exit codes: " + ", ".join(f"{c}: {n}" for c, n in sorted(codes.items())))
    n_tb = sum(r["traceback"] for r in rows)
    n_left = sum(bool(r["leftovers"]) for r in rows)
    n_bad = sum(r["bad_stderr"] for r in rows)
    n_done_sig = sum(r["outcome"] == "complete" and (r["rc"] in (130, 143) or r["rc"] < 0) for r in rows)
    print(f"tracebacks: {n_tb}; temporary folders left: {n_left}; interrupted runs without exactly one stderr line: "
          f"{n_bad}; complete output but an interrupt exit code (signal after the rename; negative: killed by it "
          f"during interpreter exit, after main returned): {n_done_sig}; "
          f"signal not sent (run had finished): {sum(not r['sent'] for r in rows)}; signal during interpreter start-up "
          f"(before rsrivc's handlers; Python's default behaviour): {sum(r['early'] for r in rows)}")
    for r in rows:
        if r["traceback"] or r["bad_stderr"] or r["outcome"] == "MIXED":
            print(f"  example: {r['signal']} at {r['delay_s']:.2f} s -> {r['outcome']}, rc {r['rc']}: "
                  f"{r['stderr'][-300:]!r}")
            break
    mixed = sum(r["outcome"] == "MIXED" for r in rows)
    return 1 if (mixed or n_tb or n_left) else 0


if __name__ == "__main__":
    sys.exit(main())
