"""``rsrivc_evaluate``: score the fault diagnosis (core/monitor/pipeline.py) on simulated scenarios with known truth.

For every case the scenario is simulated (core/scenarios.py), streamed through :class:`MonitorPipeline`
in 0.1 s blocks (as the node does) and scored against the injected faults:

* **detection delay** per injected structural fault: first event with the right mode, quantity and
  direction confirmed after the change started (s and memory lengths of that mode); onset error;
* **isolation**: events after a change started that name another mode/quantity/direction;
* **false alarms per hour** of healthy monitored data (monitoring phase, before any structural change);
* **sensor faults**: reported as estimator/data health during their window, never as structural faults.

Exit status 0 when every detection target holds, 1 otherwise; 2 on bad arguments.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.diagnosis.faults import FaultEvent
from ..core.monitor.pipeline import MonitorPipeline
from ..core.vocabulary import quantity_of, sim_quantity_of
from ..process_exit import console_entry
from .parser import OneLineParser

DRIFT_OFF = {"drift1_start_s": 1e9, "drift1_end_s": 1e9 + 1.0, "drift2_start_s": 1e9, "drift2_end_s": 1e9 + 1.0}


@dataclass(frozen=True)
class Case:
    """One simulated run: scenario name, duration, seed and overrides (or a custom paper-plant change)."""

    label: str
    scenario: str
    duration_s: float
    seed: int = 0
    overrides: dict[str, Any] = field(default_factory=dict)
    paper_change: tuple[int, str, float, float] | None = None   # (mode 0-based, quantity, relative, start_s)
    beam_change: tuple[int, str, float, float] | None = None    # the same on the beam plant (beam_healthy config)
    known_limit: str = ""   # non-empty: a measured limitation, reported but not counted in the issue-7 targets




def full_cases() -> list[Case]:
    return [
        Case("beam_fault/seed0", "beam_fault", 60.0, 0),
        Case("beam_fault/seed1", "beam_fault", 60.0, 1),
        Case("beam_fault/ramp", "beam_fault", 60.0, 2, {"fault_ramp_s": 0.5}),
        Case("beam_healthy", "beam_healthy", 300.0, 0),
        Case("paper_healthy/seed0", "paper_example", 3600.0, 0, dict(DRIFT_OFF)),
        Case("paper_damping_-30%", "paper_example", 1500.0, 1, paper_change=(1, "damping", -0.30, 900.0)),
        Case("beam_gain2_-20%", "beam_healthy", 60.0, 5, beam_change=(1, "gain", -0.20, 30.0)),
        Case("beam_gain1_-20%", "beam_healthy", 60.0, 6, beam_change=(0, "gain", -0.20, 30.0)),
        Case("paper_gain_-20%", "paper_example", 1500.0, 2, paper_change=(0, "gain", -0.20, 900.0)),
        Case("paper_gain2_-20%", "paper_example", 1500.0, 4, paper_change=(1, "gain", -0.20, 900.0)),
        Case("paper_healthy_dithered", "paper_example", 1500.0, 3, paper_change=(0, "gain", 0.0, 1e9)),
        Case("sensor_fault", "sensor_fault", 1100.0, 0, {"fault_time_s": 600.0}),
    ]


def quick_cases() -> list[Case]:
    return [
        Case("beam_fault/seed0", "beam_fault", 60.0, 0),
        Case("paper_healthy/seed0", "paper_example", 1200.0, 0, dict(DRIFT_OFF)),
        Case("paper_damping_-30%", "paper_example", 1500.0, 1, paper_change=(1, "damping", -0.30, 900.0)),
        Case("sensor_fault", "sensor_fault", 1100.0, 0, {"fault_time_s": 600.0}),
    ]


def simulate_case(case: Case) -> Any:
    """The :class:`ScenarioData` of a case (a paper-plant change is built on the [RA-SRIVC] §5 plant and config)."""
    from ..sim import scenarios as sc

    if case.beam_change is not None:
        return _beam_change_case(case)
    if case.paper_change is None:
        return sc.build(case.scenario, case.duration_s, case.seed, **case.overrides)
    from ..config import load_config
    from ..sim import plants
    from ..sim.simulate import ModalChange, simulate_modes, sum_of_sines, time_vector, white_noise

    cfg_path = sc.config_dir() / "paper_example.yaml"
    cfg = load_config(cfg_path)
    mode, quantity, rel, start = case.paper_change
    changes = [ModalChange(mode, sim_quantity_of(quantity), rel, start)] if rel != 0.0 else []
    rng = np.random.default_rng([case.seed, 7])
    t = time_vector(cfg.loop_rate_hz, case.duration_s)
    # the paper's four sines plus a white dither (std 1, as the [A-SRIVC] §5.2 reference): with the sines alone each
    # mode is excited at one line, and a gain change cannot be told from a frequency change
    r = sum_of_sines(t, [3.0, 1.0, 1.0, 1.0], [0.005, 2.0, 5.0, 17.5]) + white_noise(t.size, 1.0, rng)
    v = white_noise(t.size, 0.1, rng)
    sim = simulate_modes(plants.PAPER_MODES, cfg.loop_rate_hz, changes=changes, r=r, controller=cfg.controller,
                         noise=v, rng=rng)
    return _case_data(case, cfg_path, cfg, sim, changes)


def _case_data(case: Case, cfg_path: Any, cfg: Any, sim: Any, changes: list) -> Any:
    """A :class:`ScenarioData` for a custom (not named-scenario) simulation of a case."""
    from ..sim import scenarios as sc

    return sc.ScenarioData(
        name=case.label, seed=case.seed, t=sim.t, r=sim.r, u=sim.u, y=sim.y, x=sim.x, truth=sim.modal[:cfg.K],
        truth_all=sim.modal, fault_events=sc.fault_events(changes, [], case.duration_s), changes=changes,
        sensor_faults=[], config_path=cfg_path, config=cfg, sim=sim, parameters={})


def _beam_change_case(case: Case) -> Any:
    """The beam plant (scenario ``beam_healthy``'s signals and params) with one modal change of a step."""
    from ..config import load_config
    from ..sim import plants
    from ..sim import scenarios as sc
    from ..sim.simulate import ModalChange, simulate_modes, square_wave, time_vector, white_noise

    cfg_path = sc.config_dir() / "beam_healthy.yaml"
    cfg = load_config(cfg_path)
    if case.beam_change is None:
        raise ValueError(f"case {case.label} has no beam change")
    mode, quantity, rel, start = case.beam_change
    changes = [ModalChange(mode, sim_quantity_of(quantity), rel, start)]
    rng = np.random.default_rng([case.seed, 11])
    t = time_vector(cfg.loop_rate_hz, case.duration_s)
    r = square_wave(t, 2.0, 0.1)
    v = white_noise(t.size, plants.BEAM_NOISE_STD, rng)
    sim = simulate_modes(plants.BEAM_MODES, cfg.loop_rate_hz, changes=changes, r=r, controller=cfg.controller,
                         input_delay=cfg.input_delay_samples, noise=v, rng=rng)
    return _case_data(case, cfg_path, cfg, sim, changes)


def _report_row(rep: Any) -> dict[str, Any]:
    joint = rep.health.get("joint_check") or {}
    return {"time_s": rep.time_s, "phase": rep.phase, "health_level": int(rep.health["level"]),
            "hold": bool(rep.health["hold"]), "issues": list(rep.health.get("issues", [])),
            "peaks": list(joint.get("peak_changes", [])) if joint.get("armed") else []}


def run_pipeline(data: Any, block_s: float = 0.1) -> tuple[list[FaultEvent], list[dict[str, Any]], float]:
    """Stream the data through a fresh pipeline; returns (events, report summaries, wall time)."""
    cfg = data.config
    pipe = MonitorPipeline(cfg)
    n = max(1, int(round(block_s * cfg.loop_rate_hz)))
    reports: list[dict[str, Any]] = []
    t_wall = time.perf_counter()
    r = data.r
    for k in range(0, data.t.size, n):
        for rep in pipe.push(data.t[k:k + n], None if r is None else r[k:k + n], data.u[k:k + n], data.y[k:k + n]):
            reports.append(_report_row(rep))
    for rep in pipe.flush():
        reports.append(_report_row(rep))
    assert pipe.faults is not None   # the cases give the modes: the fault monitor exists from the start
    return list(pipe.faults.events), reports, time.perf_counter() - t_wall


def _peak_report(reports: list[dict[str, Any]], change: Any, want: tuple[int, str, str]) -> float:
    """Delay of the first report naming the changed mode's resonance peak in the right direction (a gain change
    moves g/(2 zeta) with it, a damping change against it); inf when none does."""
    if want[1] not in ("gain", "damping"):
        return math.inf
    up = (want[2] == "up") == (want[1] == "gain")
    for rp in reports:
        if rp["time_s"] < change.start_s:
            continue
        for line in rp.get("peaks", []):
            if line.startswith(f"mode {want[0]} resonance peak") and ("% (std" in line) and \
                    (" +" in line.split("damping)")[1]) == up:
                return rp["time_s"] - change.start_s
    return math.inf


def score(data: Any, events: list[FaultEvent], reports: list[dict[str, Any]]) -> dict[str, Any]:
    """Detection, isolation, false alarms and sensor-fault handling of one run (see module docstring)."""
    memory = [m.memory_s for m in data.config.modes]
    changes = [c for c in data.changes if c.mode < data.config.K and c.start_s < data.t[-1]]
    first_change = min((c.start_s for c in changes), default=math.inf)
    injected = []
    matched: set[int] = set()
    for c in changes:
        want = (c.mode + 1, quantity_of(c.quantity), "down" if c.relative_change < 0 else "up")
        hit = next((j for j, e in enumerate(events) if (e.mode, e.quantity, e.direction) == want
                    and e.alarm_time_s >= c.start_s), None)
        rec: dict[str, Any] = {"mode": want[0], "quantity": want[1], "direction": want[2],
                               "relative_change": c.relative_change, "start_s": c.start_s, "detected": hit is not None}
        peak = _peak_report(reports, c, want)
        rec["resonance_peak_delay_s"] = peak
        if hit is None and math.isfinite(peak):     # gain and damping not separable: the combination is named
            rec.update(detected=True, via="resonance peak (health)", delay_s=peak,
                       delay_memory_lengths=peak / memory[c.mode], onset_error_s=math.nan)
        if hit is not None:
            rec["via"] = "event"
            matched.add(hit)
            e = events[hit]
            rec.update(delay_s=e.alarm_time_s - c.start_s, delay_memory_lengths=(e.alarm_time_s - c.start_s)
                       / memory[c.mode], onset_error_s=e.onset_time_s - c.start_s)
        injected.append(rec)
    first_sensor = min((f.start_s for f in data.sensor_faults), default=math.inf)
    healthy_end = min(first_change, first_sensor)
    false_alarms = [e for e in events if e.alarm_time_s < healthy_end]
    # a resonance-peak change on health (joint confirmation) before any change is a false alarm too
    false_peaks = sorted({line.split(" resonance")[0] for rp in reports if rp["time_s"] < healthy_end
                          for line in rp.get("peaks", [])})
    misisolated = [e for j, e in enumerate(events) if first_change <= e.alarm_time_s and j not in matched]
    # healthy monitored exposure: monitoring phase before the first structural change and outside sensor faults
    sensor_windows = [(f.start_s, f.start_s + f.duration_s) for f in data.sensor_faults]
    times = np.array([rp["time_s"] for rp in reports])
    period = float(np.median(np.diff(times))) if times.size > 1 else 0.0
    healthy = sum(period for rp in reports if rp["phase"] == "monitoring" and rp["time_s"] < first_change
                  and not any(a <= rp["time_s"] < b for a, b in sensor_windows))
    sensor = []
    for f in data.sensor_faults:
        end = min(f.start_s + f.duration_s, float(data.t[-1]))
        inside = [rp for rp in reports if f.start_s <= rp["time_s"] < end]
        flagged = [rp for rp in inside if rp["health_level"] > 0]
        first = min((rp["time_s"] for rp in flagged), default=math.nan)
        structural = [e for e in events if f.start_s <= e.alarm_time_s]
        sensor.append({"type": f.kind, "start_s": f.start_s, "end_s": end, "health_flagged": bool(flagged),
                       "health_flag_delay_s": first - f.start_s, "fraction_flagged": len(flagged) / max(len(inside), 1),
                       "structural_alarms": len(structural)})
    return {"injected": injected, "false_alarms": len(false_alarms) + len(false_peaks),
            "false_peak_modes": false_peaks, "healthy_hours": healthy / 3600.0,
            "misisolated": len(misisolated),
            "misisolated_events": [(e.mode, e.quantity, e.direction, round(e.alarm_time_s, 3)) for e in misisolated],
            "sensor": sensor, "events": [e.csv_row() for e in events]}


def evaluate(cases: list[Case], progress: bool = True, require_hour: bool = True) -> dict[str, Any]:
    """Run and score every case; totals and the issue-7 targets."""
    out: dict[str, Any] = {"cases": {}}
    for case in cases:
        t0 = time.perf_counter()
        data = simulate_case(case)
        events, reports, wall = run_pipeline(data)
        res = score(data, events, reports)
        res.update(simulated_s=float(data.t[-1] + 1.0 / data.config.loop_rate_hz), pipeline_s=wall,
                   total_s=time.perf_counter() - t0)
        res["known_limit"] = case.known_limit
        out["cases"][case.label] = res
        if progress:
            print(f"  {case.label}: {len(events)} event(s), {res['total_s']:.1f} s", file=sys.stderr)
    cs = out["cases"].values()
    hours = sum(c["healthy_hours"] for c in cs)
    fas = sum(c["false_alarms"] for c in cs)
    inj = [i for c in cs if not c["known_limit"] for i in c["injected"]]
    # the issue-7 target is the step drop (the ramp case spreads the change over 2 memory lengths)
    beam = [i for k, c in out["cases"].items() if k.startswith("beam_fault/seed") for i in c["injected"]]
    sensor = [s for c in cs for s in c["sensor"]]
    out["totals"] = {
        "healthy_hours": hours, "false_alarms": fas, "false_alarms_per_hour": fas / hours if hours > 0 else math.nan,
        "injected": len(inj), "detected": sum(i["detected"] for i in inj),
        "misisolated": sum(c["misisolated"] for c in cs if not c["known_limit"]),
        "known_limit_cases": sum(bool(c["known_limit"]) for c in cs),
        "sensor_faults": len(sensor), "sensor_faults_health_flagged": sum(s["health_flagged"] for s in sensor),
        "sensor_structural_alarms": sum(s["structural_alarms"] for s in sensor),
    }
    t = out["totals"]
    out["targets"] = {
        "beam_fault_within_3_memory_lengths": bool(beam) and all(
            i["detected"] and i["delay_memory_lengths"] <= 3.0 for i in beam),
        "all_injected_detected_and_isolated": t["detected"] == t["injected"] and t["misisolated"] == 0,
        **{f"{q}_{pct}_detected_and_isolated": any(
            i["quantity"] == q and round(100 * i["relative_change"]) == pct and i["detected"]
            and not c["misisolated"] for c in cs if not c["known_limit"] for i in c["injected"])
           for q, pct in (("damping", -30), ("gain", -20)) if any(
               i["quantity"] == q and round(100 * i["relative_change"]) == pct for c in cs for i in c["injected"])},
        "zero_false_alarms": fas == 0,
        **({"at_least_one_healthy_hour": hours >= 1.0} if require_hour else {}),
        "sensor_faults_health_only": t["sensor_faults_health_flagged"] == t["sensor_faults"]
        and t["sensor_structural_alarms"] == 0,
    }
    return out


def format_table(res: dict[str, Any]) -> str:
    lines = [f"{'case':24s} {'fault':34s} {'detected':>8s} {'delay s':>8s} {'delay T':>8s} {'onset err s':>11s}"]
    for label, c in res["cases"].items():
        for i in c["injected"]:
            what = f"mode {i['mode']} {i['quantity']} {i['direction']} {i['relative_change']:+.0%}"
            if i["detected"]:
                how = "yes" if i.get("via") == "event" else "peak"
                lines.append(f"{label:24s} {what:34s} {how:>8s} {i['delay_s']:8.2f} {i['delay_memory_lengths']:8.2f} "
                             f"{i['onset_error_s']:11.2f}")
            else:
                lines.append(f"{label:24s} {what:34s} {'NO':>8s}")
        for s in c["sensor"]:
            lines.append(f"{label:24s} {'sensor ' + s['type']:34s} {'health' if s['health_flagged'] else 'MISSED':>8s} "
                         f"{s['health_flag_delay_s']:8.2f} {'':8s} structural alarms {s['structural_alarms']}")
        if c["misisolated"] or c["false_alarms"]:
            lines.append(f"{label:24s} false alarms {c['false_alarms']}, mis-isolated {c['misisolated_events']}")
        if c.get("known_limit"):
            lines.append(f"{label:24s} known limit (not counted in the targets): {c['known_limit']}")
    t = res["totals"]
    lines += ["", f"healthy monitored data: {t['healthy_hours']:.2f} h, false alarms: {t['false_alarms']} "
              f"({t['false_alarms_per_hour']:.3g} per hour)",
              f"injected structural faults detected: {t['detected']}/{t['injected']}, mis-isolated events: "
              f"{t['misisolated']}",
              f"sensor faults flagged as health: {t['sensor_faults_health_flagged']}/{t['sensor_faults']}, structural "
              f"alarms during sensor faults: {t['sensor_structural_alarms']}", "",
              "targets:"]
    lines += [f"  {'PASS' if ok else 'FAIL'}  {name}" for name, ok in res["targets"].items()]
    lines.append("('peak': gain and damping not separately identifiable; the mode's resonance peak g/(2 zeta) was "
                 "reported on health instead of an event)")
    return "\n".join(lines)


@console_entry
def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="rsrivc_evaluate", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small run (about a minute)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    ap.add_argument("--case", action="append", default=[], help="run only the named case(s) (see --list)")
    ap.add_argument("--list", action="store_true", help="list the case labels and exit")
    args = ap.parse_args(argv)
    cases = quick_cases() if args.quick else full_cases()
    if args.list:
        print("\n".join(c.label for c in cases))
        return 0
    if args.case:
        known = {c.label: c for c in cases}
        bad = [c for c in args.case if c not in known]
        if bad:
            print(f"rsrivc_evaluate: error: unknown case(s) {', '.join(bad)} (see --list)", file=sys.stderr)
            return 2
        cases = [known[c] for c in args.case]
    try:
        res = evaluate(cases, progress=not args.json, require_hour=not (args.quick or args.case))
    except (ValueError, OSError) as exc:
        print(f"rsrivc_evaluate: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(res, default=float, indent=1) if args.json else format_table(res))
    return 0 if all(res["targets"].values()) or args.case else 1


if __name__ == "__main__":
    sys.exit(main())
