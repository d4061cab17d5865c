"""``rsrivc_diagnose BAG --params-file YAML [--out DIR]``: offline diagnosis of a rosbag2 (MCAP or sqlite3).

Runs the node's :class:`..core.pipeline.MonitorPipeline`, configured by the node's params file, over the samples of a
bag read and checked by :func:`..bagio.read_signals`. Writes ``estimates.csv``, ``events.csv``, ``summary.json``
(verdict from :mod:`..verdict`), ``report.html`` (:mod:`..report`) and ``modes.svg`` into DIR (default
``./rsrivc_out/<bag name>``; formats in docs/INTERFACE.md "Offline results"). DIR is written all-or-nothing
(:class:`.atomic.AtomicDir`): a temporary sibling folder replaces it only when complete. Prints the verdict and a
per-mode table. Exit status 2 with one line on bad input, 3 for a fault with ``--fail-on-fault``, 130/143 on
SIGINT/SIGTERM (DIR left as it was).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from ..core.vocabulary import (
    BASELINE_KEYS,
    ESTIMATES_HEADER,
    EVENTS_HEADER,
    LEVEL_NAMES,
    MODE_FIELDS,
    QUANTITIES,
    events_csv_cells,
    json_clean,
    num,
    one_line,
)
from ..process_exit import console_entry
from .parser import OneLineParser
from .progress import ProgressBar
from .timerange import add_range_arguments, anchor_pipeline, range_of, range_text, verdict_in_range

if TYPE_CHECKING:
    from ..core.diagnosis.faults import FaultEvent
    from ..core.estimation.estimator import MonitorSettings
    from ..core.monitor.pipeline import MonitorPipeline, Report
    from ..io.bagio import Signals
    from ..outputs.report import DiagnosisSeries, ReportInput

PROG = "rsrivc_diagnose"


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog=PROG, description="Diagnose a rosbag2 offline with the monitor's estimator and fault logic.")
    p.add_argument("bag", help="rosbag2 directory (mcap or sqlite3)")
    p.add_argument("--params-file", required=True, help="the node's params YAML (additive_rsrivc_monitor: ...)")
    p.add_argument("--out", help="output directory (default: ./rsrivc_out/<bag name>)")
    p.add_argument("--node-name", default=None, help="node name whose section of the params file is used")
    prog = p.add_mutually_exclusive_group()
    prog.add_argument("--progress", dest="progress", action="store_true", default=None,
                      help="show a progress bar on stderr (default: only when stderr is a terminal)")
    prog.add_argument("--no-progress", dest="progress", action="store_false", help="never show a progress bar")
    p.add_argument("--no-report", action="store_true", help="skip report.html and modes.svg (CSV/JSON only)")
    p.add_argument("--chunk-s", type=float, default=1.0, help="seconds of data per pipeline call (default 1)")
    p.add_argument("--fail-on-fault", action="store_true", help="exit with status 3 when a fault event was found")
    p.add_argument("--quiet", action="store_true", help="print only the verdict line")
    add_range_arguments(p)
    return p


# ------------------------------------------------------------------------------------------------- progress
def progress_bar(total_s: float, stream: TextIO, enabled: bool) -> ProgressBar:
    """The diagnosis's progress bar over the record's seconds (with the speed in multiples of real time)."""
    def describe(done_s: float, total: float, elapsed: float) -> str:
        speed = done_s / elapsed if elapsed > 0 else 0.0
        return f"{min(max(done_s / total, 0.0), 1.0) * 100:5.1f} % {done_s:8.1f}/{total:.1f} s  {speed:6.1f}x real time"
    return ProgressBar(PROG, total_s, stream, enabled, describe, min_interval_s=0.1)


# ------------------------------------------------------------------------------------------------- running
NOTICES_SHOWN = 5   # automatic-start lines printed (a long record without excitation retries many times)


def _print_notices(reports: Sequence[Report], stderr: TextIO) -> None:
    """The pipeline's automatic-start lines (modes found; windows without modes) on stderr."""
    notes = [n for rep in reports for n in getattr(rep, "notices", [])]
    for note in notes[:NOTICES_SHOWN]:
        print(f"{PROG}: {'' if note.startswith('no mode guesses') else 'warning: '}{note}", file=stderr)
    if len(notes) > NOTICES_SHOWN:
        print(f"{PROG}: warning: {len(notes) - NOTICES_SHOWN} more automatic-start line(s) in summary.json health",
              file=stderr)


def run_pipeline(sig: Signals, cfg: MonitorSettings, *, chunk_s: float = 1.0, progress: ProgressBar | None = None,
                 pipeline: MonitorPipeline | None = None) -> tuple[list[Report], list[FaultEvent]]:
    """Feed the bag's samples through a fresh :class:`MonitorPipeline` (or ``pipeline``); return
    ``(reports, events)``. Without mode guesses the pipeline finds the modes first
    (``core/identification/autostart.py``);
    ``pipeline.cfg`` then holds the modes found.

    Events are collected from the reports' ``events_opened``/``events_closed`` (as the node sees them),
    keyed by (mode, quantity, alarm time), in order of onset.
    """
    from ..core.monitor.pipeline import MonitorPipeline
    from .atomic import raise_if_interrupted

    pipe = pipeline if pipeline is not None else MonitorPipeline(cfg)
    n = sig.t.size
    step = max(1, int(round(chunk_s * cfg.loop_rate_hz)))
    reports: list[Report] = []
    events: dict[tuple, FaultEvent] = {}
    r = sig.r if cfg.closed_loop else None
    for a in range(0, n, step):
        b = min(a + step, n)
        for rep in pipe.push(sig.t[a:b], None if r is None else r[a:b], sig.u[a:b], sig.y[a:b]):
            reports.append(rep)
            for e in (*rep.events_opened, *rep.events_closed):
                events[(e.mode, e.quantity, e.alarm_time_s)] = e
        raise_if_interrupted()       # an interrupt that landed in a C callback (numba compilation) stops here
        if progress is not None:
            progress.update(float(sig.t[b - 1] - sig.t[0]))     # a range: from its start
    for rep in pipe.flush():       # the end of the record: samples the stream aligner held back
        reports.append(rep)
        for e in (*rep.events_opened, *rep.events_closed):
            events[(e.mode, e.quantity, e.alarm_time_s)] = e
    ordered = sorted(events.values(), key=lambda e: (e.onset_time_s, e.mode, e.quantity))
    return reports, ordered


def write_estimates_csv(path: Path, reports: Sequence[Report]) -> int:
    """estimates.csv (docs/INTERFACE.md); one row per mode per report with an estimate. Returns the row count."""
    import numpy as np

    rows = 0
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(ESTIMATES_HEADER)
        for rep in reports:
            if not rep.estimating:
                continue
            m = np.asarray(rep.modal, float)
            fl = np.asarray(rep.flags, bool)
            for i in range(m.shape[0]):
                w.writerow([num(rep.time_s), i + 1, *(num(v) for v in m[i, :6]), *(int(x) for x in fl[i, :3])])
                rows += 1
    return rows


def event_dict(e: FaultEvent) -> dict[str, Any]:
    """An event as plain data: the events.csv columns plus alarm time and z."""
    return {"onset_time_s": float(e.onset_time_s), "clear_time_s": None if e.clear_time_s is None else
            float(e.clear_time_s), "mode": int(e.mode), "quantity": str(e.quantity), "direction": str(e.direction),
            "baseline": float(e.baseline), "value": float(e.value), "alarm_time_s": float(e.alarm_time_s),
            "z": float(getattr(e, "z", math.nan))}


def write_events_csv(path: Path, events: Sequence[FaultEvent]) -> None:
    """events.csv (docs/INTERFACE.md) (empty clear time while open)."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(EVENTS_HEADER)
        for e in events:
            w.writerow(events_csv_cells(e.csv_row()))


def _out_dir(bag: Path, out: str | None) -> Path:
    if out:
        return Path(out)
    name = bag.name if bag.is_dir() or bag.suffix == "" else (bag.parent.name if bag.name == "metadata.yaml"
                                                                 else bag.stem)
    return Path("rsrivc_out") / (name or "bag")


# ------------------------------------------------------------------------------------------------- table
def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """Plain-text per-mode summary (rows from :func:`..report.summary_rows`)."""
    def short(v: Any, d: int = 6) -> str:
        return "-" if v is None or not math.isfinite(float(v)) else f"{float(v):.{d}g}"

    head = ("mode", "quantity", "final", "± std", "baseline", "change", "truth", "fault")
    body = [(str(r["mode"]), r["quantity"], short(r["final"]), short(r["std"], 3), short(r["baseline"]),
             "-" if r["change_pct"] is None else f"{r['change_pct']:+.2f} %", short(r["truth"]), r["fault"])
            for r in rows]
    widths = [max(len(h), *(len(b[j]) for b in body)) if body else len(h) for j, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.rjust(w) if j in (2, 3, 4, 5, 6) else c.ljust(w) for j, (c, w) in
                        enumerate(zip(b, widths, strict=True))) for b in body]
    return "\n".join(ln.rstrip() for ln in lines)


# ------------------------------------------------------------------------------------------------- main
OUTPUT_FILES = ("estimates.csv", "events.csv", "summary.json", "report.html", "modes.svg")
OWNED_FILES = (*OUTPUT_FILES, "modes.png")   # modes.png: the figure of earlier versions (an old --out is replaced)


def _warn_bad_samples(sig: Signals, stderr: TextIO) -> None:
    """One warning line per category of bad samples the reader found (the pipeline handles them)."""
    import numpy as np

    if sig.nonfinite:
        by = ", ".join(f"{k}: {v}" for k, v in sig.nonfinite_by_signal.items() if v)
        print(f"{PROG}: warning: {sig.nonfinite} non-finite samples ({by}); the estimator skips them", file=stderr)
    from ..core.input.screening import ABSURD_ABS, ABSURD_REL, absurd_mask

    absurd = {name: absurd_mask(x) for name, x in (("reference", sig.r), ("input", sig.u), ("output", sig.y))
              if x is not None}
    absurd = {k: m for k, m in absurd.items() if m.any()}
    if absurd:
        first = min(float(sig.t[np.argmax(m)]) for m in absurd.values())
        by = ", ".join(f"{k}: {int(m.sum())}" for k, m in absurd.items())
        print(f"{PROG}: warning: {sum(int(m.sum()) for m in absurd.values())} sample(s) of absurd magnitude ({by}; "
              f"|x| > {ABSURD_ABS:g} or more than {ABSURD_REL:g} robust scales from the median), first at "
              f"{first:.6g} s; see the verdict for what they cost", file=stderr)
    lost = {k: v for k, v in sig.unmatched_by_signal.items() if v}
    if lost:
        by = ", ".join(f"{k}: {v}" for k, v in lost.items())
        print(f"{PROG}: warning: message counts differ between topics; samples paired by log time, a lost message "
              f"is a skipped sample on a kept grid, a surplus one is left out ({by})", file=stderr)


def _frf_estimates(inp: ReportInput, sig: Signals, cfg: MonitorSettings) -> None:
    """Nonparametric FRFs of the first and last data windows for the report (None where too short)."""
    from ..outputs import report as rp

    w0, w1 = rp.frf_windows(sig.t.size, cfg.loop_rate_hz, cfg.init_duration_s)
    for attr, w in (("frf_start", w0), ("frf_end", w1)):
        try:
            est = rp.nonparametric_frf(sig.u[w], sig.y[w], cfg.loop_rate_hz,
                                       sig.r[w] if cfg.closed_loop and sig.r is not None else None,
                                       t_start_s=float(sig.t[w][0]))
        except ValueError:
            est = None
        setattr(inp, attr, est)


def _mode_summaries(series: DiagnosisSeries, rows: Sequence[dict], sig: Signals, K: int) -> list[dict[str, Any]]:
    j = series.last_estimate()
    modes = []
    for i in range(K):
        mr = [r for r in rows if r["mode"] == i + 1]
        modes.append({
            "mode": i + 1,
            "final": {k: (float(series.modal[j, i, q]) if j is not None else None)
                      for q, k in enumerate(MODE_FIELDS)},
            "baseline": {k: float(series.baseline[-1, i, q]) if series.n else None
                         for q, k in enumerate(BASELINE_KEYS)},
            "truth_final": ({k: float(sig.truth_modes[-1, i, q]) for q, k in enumerate(BASELINE_KEYS)}
                            if sig.truth_modes is not None and i < sig.truth_modes.shape[1] else None),
            "fault": {q: bool(series.flags[-1, i, k]) if series.n else False for k, q in enumerate(QUANTITIES)},
            "change_percent": {r["quantity"]: r["change_pct"] for r in mr},
        })
    return modes


def _mode_finding(pipe: Any) -> Any:
    """The automatic start's evidence (``core.modefind.ModeFindResult``: order table, FRF) when the modes in use are
    the ones it found (not after a restart from the data, whose evidence the pipeline does not keep)."""
    search = pipe.search
    if search is None or search.found is None or search.evidence is None:
        return None
    return search.evidence if search.found.message == search.evidence.message else None


def diagnose(args: argparse.Namespace, stdout: TextIO, stderr: TextIO, state: dict | None = None) -> int:
    """The work behind :func:`main`; raises the tools' one-line errors.

    Everything is written into a temporary sibling of the output folder, which replaces the folder only when
    complete (:class:`.atomic.AtomicDir`); ``state['out']`` holds the :class:`AtomicDir` while it is open.
    """
    import numpy as np

    from ..config import DEFAULT_NODE_NAME, load_config, param_table
    from ..core.monitor.pipeline import MonitorPipeline
    from ..io.bagio import read_signals
    from ..outputs import report as rp
    from ..outputs.verdict import assess
    from .atomic import AtomicDir, check_replaceable

    state = {} if state is None else state
    t_start = time.monotonic()
    if not (math.isfinite(args.chunk_s) and args.chunk_s > 0):
        raise ValueError(f"--chunk-s must be > 0, got {args.chunk_s}")
    cfg: MonitorSettings = load_config(args.params_file, args.node_name or DEFAULT_NODE_NAME)
    bag = Path(args.bag)
    out = _out_dir(bag, args.out)
    check_replaceable(out, OWNED_FILES)            # fail before the long work, not after it
    sig = read_signals(bag, cfg, range_of(getattr(args, "start", None), getattr(args, "end", None)))
    state["t0_ns"] = int(sig.t0_ns)                 # the first sample's absolute time (rsrivc_fleet orders by it)
    t_read = time.monotonic()
    _warn_bad_samples(sig, stderr)
    n = sig.t.size
    duration = float(sig.t[-1]) + 1.0 / cfg.loop_rate_hz if n else 0.0   # a range: its end, in the record's time
    t_first = float(sig.t[0]) if sig.time_range and n else 0.0
    show = args.progress if args.progress is not None else stderr.isatty()
    bar = progress_bar(float(sig.t[-1] - sig.t[0]) if n else 0.0, stderr, bool(show))
    pipe = MonitorPipeline(cfg)   # no guesses: it finds the modes on the first max(init_duration_s, 2 s) itself
    anchor_pipeline(pipe, sig)    # a range: report times stay the record's
    reports, ev_objs = run_pipeline(sig, cfg, chunk_s=args.chunk_s, progress=bar, pipeline=pipe)
    bar.close(bar.total)
    _print_notices(reports, stderr)
    cfg = pipe.cfg                # with the modes found by the automatic start
    t_est = time.monotonic()
    events = [event_dict(e) for e in ev_objs]
    verdict = verdict_in_range(assess(reports, duration, events), sig.time_range)
    tmp = state["out"] = AtomicDir(out, OWNED_FILES)
    tmp.open()
    n_rows = write_estimates_csv(tmp.tmp / "estimates.csv", reports)
    write_events_csv(tmp.tmp / "events.csv", ev_objs)

    series = rp.DiagnosisSeries.from_reports(reports, cfg.K)
    truth = rp.TruthData(sig.truth_t, sig.truth_modes, sig.truth_fault)
    table = param_table()
    info = {"bag": str(bag), "storage": sig.storage or "?", "params file": str(args.params_file),
            "samples": n, "duration [s]": f"{duration - t_first:.6g}", "loop rate [Hz]": f"{cfg.loop_rate_hz:g}",
            "loop": "closed" if cfg.closed_loop else "open", "modes (K)": cfg.K, "reports": len(reports),
            "non-finite samples": sig.nonfinite, "unmatched messages left out": sum(sig.unmatched_by_signal.values()),
            **{k.replace("additive_rsrivc.", "bag "): v for k, v in sig.metadata.items()
               if k != "additive_rsrivc.parameters"}}
    if sig.time_range:
        info["time range [s]"] = range_text(sig.time_range).strip(" ()")
    if pipe.search is not None and pipe.search.found is not None:   # the evidence of the automatic start
        info["modes found from the data"] = pipe.search.found.describe()
    if pipe.counters.data_starts:
        info["start"] = "the mode guesses gave no valid model: started from the modes found in the data"
    identifiability = identifiability_timeline(reports)
    if identifiability:
        info.update(identifiability_info(identifiability))
    inp = rp.ReportInput(title=_out_dir(bag, None).name, series=series, events=events, structures=cfg.structures,
                         rate_hz=cfg.loop_rate_hz, closed_loop=cfg.closed_loop,
                         input_delay_samples=cfg.input_delay_samples, duration_s=duration, params=dict(cfg.params),
                         info=info, truth=truth, param_help={k: p.description for k, p in table.items()},
                         verdict=verdict, mode_finding=_mode_finding(pipe))
    rows = rp.summary_rows(inp)
    t_report = t_est
    if not args.no_report and n:
        _frf_estimates(inp, sig, cfg)
        info["processing [s]"] = f"read {t_read - t_start:.2f}, estimate {t_est - t_read:.2f}"
        rp.write_report(inp, tmp.tmp)
        t_report = time.monotonic()
    timings = {"read_s": t_read - t_start, "estimate_s": t_est - t_read, "report_s": t_report - t_est,
               "total_s": time.monotonic() - t_start}
    last = reports[-1] if reports else None
    summary = {
        "bag": str(bag), "params_file": str(args.params_file), "storage": sig.storage, **verdict.to_dict(),
        "samples": n, "duration_s": duration - t_first, "time_range": sig.time_range,
        "loop_rate_hz": cfg.loop_rate_hz,
        "closed_loop": cfg.closed_loop, "K": cfg.K, "reports": len(reports), "estimate_rows": n_rows,
        "first_estimate_time_s": float(series.time_s[series.first_estimate()]) if series.first_estimate() is not None
        else None,
        "modes": _mode_summaries(series, rows, sig, cfg.K), "events": events, "nonfinite_samples": sig.nonfinite,
        "unmatched_messages": dict(sig.unmatched_by_signal),
        "health": {"final": last.health if last is not None else None,
                   "level_counts": {LEVEL_NAMES[k]: int(np.sum(series.health_level == k)) for k in range(4)}},
        "phase_final": last.phase if last is not None else None,
        "timings_s": timings,
        "realtime_factor": (duration - t_first) / timings["estimate_s"] if timings["estimate_s"] > 0 else None,
        "truth_fault": sig.truth_fault, "bag_metadata": sig.metadata, "parameters": dict(cfg.params),
        "files": {k: str(out / k) for k in OUTPUT_FILES
                  if k in ("estimates.csv", "events.csv", "summary.json") or not args.no_report},
    }
    summary["alignment"] = _alignment_summary(last)
    summary["identifiability"] = identifiability
    summary["mode_finding"] = inp.mode_finding.to_dict() if inp.mode_finding is not None else None
    (tmp.tmp / "summary.json").write_text(json.dumps(json_clean(summary), indent=2, allow_nan=False) + "\n",
                                          encoding="utf-8")
    tmp.commit()
    al = summary["alignment"]
    if al.get("realignments"):
        print(f"{PROG}: warning: {al['realignments']} re-alignment(s) of r, u, y by the controller invariant (lost "
              f"or repeated messages): {al['refilled']} lost sample(s) refilled from u = C_d(q)(r - y), "
              f"{al['surplus']} surplus dropped, {al['set_aside']} set aside", file=stderr)
    print(verdict.line, file=stdout)
    if not args.quiet:
        print(f"\n{bag}: {duration - t_first:.4g} s{range_text(sig.time_range)}, {n} samples at "
              f"{cfg.loop_rate_hz:g} Hz, {'closed' if cfg.closed_loop else 'open'} loop, K = {cfg.K}\n", file=stdout)
        print(format_table(rows), file=stdout)
        print(f"\ntime: read {timings['read_s']:.2f} s, estimate+diagnose {timings['estimate_s']:.2f} s "
              f"({(duration - t_first) / max(timings['estimate_s'], 1e-9):.0f}x real time), "
              f"report {timings['report_s']:.2f} s, total {timings['total_s']:.2f} s", file=stdout)
        print(f"wrote {out}/: estimates.csv ({n_rows} rows), events.csv ({len(events)} events), summary.json"
              f"{'' if args.no_report else ', report.html, modes.svg'}", file=stdout)
    return 3 if (args.fail_on_fault and events) else 0


def diagnose_bag(bag: str | Path, params_file: str | Path, out_dir: str | Path, *, node_name: str | None = None,
                 report: bool = True, stdout: TextIO | None = None, stderr: TextIO | None = None,
                 start: str | float | None = None, end: str | float | None = None) -> dict[str, Any]:
    """``rsrivc_diagnose BAG --params-file P --out DIR --no-progress`` as a function (``rsrivc_fleet``'s task):
    the same code and the same files; returns summary.json's content plus ``start_time_ns`` (the first sample,
    Unix ns). Raises the tool's one-line errors (BagError, ParamError, PipelineError, OSError, ValueError)."""
    import io

    argv = ["--params-file", str(params_file), "--out", str(out_dir), "--no-progress", "--quiet"]
    argv += ["--node-name", node_name] if node_name else []
    argv += [] if report else ["--no-report"]
    argv += [] if start is None else ["--start", str(start)]
    argv += [] if end is None else ["--end", str(end)]
    args = _parser().parse_args([*argv, "--", str(bag)])
    state: dict[str, Any] = {}
    try:
        diagnose(args, stdout or io.StringIO(), stderr or io.StringIO(), state)
    finally:
        if state.get("out") is not None:
            state["out"].discard()
    summary = json.loads((Path(out_dir) / "summary.json").read_text(encoding="utf-8"))
    summary["start_time_ns"] = state["t0_ns"]
    return summary


def identifiability_timeline(reports: list[Report]) -> list[dict[str, Any]]:
    """summary.json ``identifiability``: every joint check (core/diagnosis/joint_check.py) once: its time, whether it
    armed
    the joint confirmation, what the excitation did not identify jointly and the resonance-peak changes it saw."""
    out: list[dict[str, Any]] = []
    for rep in reports:
        jc = rep.health.get("joint_check")
        if jc and (not out or out[-1]["t"] != jc["t"]):
            out.append({"t": jc["t"], "armed": jc["armed"], "converged": jc["converged"],
                        "not_identifiable": list(jc["not_identifiable"]), "peak_changes": list(jc["peak_changes"])})
    return out


def identifiability_info(timeline: list[dict[str, Any]]) -> dict[str, str]:
    """The report's rows for the joint checks: what was not identifiable, when, and the peak changes."""
    first = timeline[0]
    if not any(c["armed"] for c in timeline):
        return {"identifiability (joint fit)": f"every quantity identifiable at t={first['t']:.1f} s "
                "(joint confirmation not needed)"}
    spans: dict[str, list[float]] = {}
    for c in timeline:
        for q in c["not_identifiable"]:
            spans.setdefault(q, []).append(c["t"])
    rows = {"identifiability (joint fit)": f"{len(timeline)} joint checks from t={first['t']:.1f} s; not "
            "identifiable: " + "; ".join(f"{q} ({len(ts)} of {len(timeline)} checks, t={ts[0]:.0f}-{ts[-1]:.0f} s)"
                                         for q, ts in spans.items())}
    peaks = [f"t={c['t']:.0f} s: {line}" for c in timeline for line in c["peak_changes"]]
    if peaks:
        rows["resonance-peak changes"] = f"{peaks[0]}; ... {peaks[-1]} ({len(peaks)} checks)" if len(peaks) > 2 \
            else "; ".join(peaks)
    return rows


def _alignment_summary(last: Report | None) -> dict[str, Any]:
    """summary.json ``alignment``: what the pipeline's stream aligner verified and corrected
    (core/input/alignment.py)."""
    al = (last.health.get("alignment") if last is not None else None) or {"mode": "off"}
    if al.get("mode") != "invariant":
        return {"mode": al.get("mode", "off")}
    return {"mode": "controller invariant", "verified": bool(al.get("verified")),
            "relative_residual": al.get("relative_residual"), "realignments": int(al.get("realignments", 0)),
            "refilled": int(al.get("reconstructed", 0)), "surplus": int(al.get("surplus", 0)),
            "set_aside": int(al.get("invalidated", 0)) + int(al.get("late", 0)),
            "undecided_samples": int(al.get("undecided", 0)), "late_samples": int(al.get("late", 0))}


@console_entry
def main(argv: list[str] | None = None) -> int:
    """Console entry point: 0 on success, 2 on bad input (one line on stderr), 3 with --fail-on-fault,
    130/143 when interrupted by SIGINT/SIGTERM (one line on stderr; the output folder is left as it was)."""
    from .atomic import exit_code, interrupts

    state: dict[str, Any] = {}
    with interrupts(final=argv is None):   # a console script's run: no death by signal after it
        try:
            return _run(argv, state)
        except KeyboardInterrupt as exc:
            return _interrupted(exc, state, exit_code(exc))
        finally:
            if state.get("out") is not None:
                state["out"].discard()


def _interrupted(exc: BaseException, state: dict[str, Any], code: int) -> int:
    out = state.get("out")
    name = getattr(exc, "name", "SIGINT")
    if out is not None and out.committed:
        where = f"after {out.target} was written completely"
    elif out is not None:
        where = f"before the output was complete; {out.target} left as it was"
    else:
        where = "before any output was written"
    try:
        print(f"{PROG}: interrupted ({name}) {where}", file=sys.stderr)
    except (OSError, ValueError):   # stderr gone (closed pipe): the exit status still tells
        pass
    return code


def _run(argv: list[str] | None, state: dict[str, Any]) -> int:
    return _diagnose_or_error(_parser().parse_args(argv), state)


def _diagnose_or_interrupt(args: argparse.Namespace, state: dict[str, Any]) -> int:
    from .atomic import Interrupted, received

    try:
        return diagnose(args, sys.stdout, sys.stderr, state)
    except Exception:
        signum = received()
        if signum is not None:   # a library turned the interrupt into its own exception
            raise Interrupted(signum) from None
        raise


def _diagnose_or_error(args: argparse.Namespace, state: dict[str, Any]) -> int:
    from ..config import ParamError
    from ..core.monitor.pipeline import PipelineError
    from ..io.bagio import BagError

    try:
        return _diagnose_or_interrupt(args, state)
    except (BagError, ParamError, PipelineError) as exc:
        print(f"{PROG}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as exc:
        print(f"{PROG}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - never a traceback for users; RSRIVC_DEBUG=1 shows it
        if os.environ.get("RSRIVC_DEBUG"):
            raise
        print(f"{PROG}: internal error: {type(exc).__name__}: {one_line(exc)} (set RSRIVC_DEBUG=1 for a traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
