"""Human report of an offline diagnosis: one self-contained HTML file with inline SVG figures (:mod:`.svgplot`).

``rsrivc_diagnose`` writes it as ``DIR/report.html`` (and ``DIR/modes.svg``). Top to bottom: the verdict line
(:mod:`.verdict`: faults found or not, how long the tests ran, where and why they were blind) and a per-mode table; per
mode the frequency, damping and gain over time with ±2σ bands (delta method, :func:`.core.model.modal_std`), the
baseline, the truth when the bag has ``/truth/modes`` and the fault intervals; a fault timeline with the estimator's
health; the model's frequency response at the start and the end over the nonparametric estimate (as in [RA-SRIVC] Figs.
7 and 12: closed loop ``S_ry / S_ru``, open loop ``S_uy / S_uu``); the health over time and the parameters.
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.model import SubmodelStructure, theta_from_modal
from ..core.vocabulary import LEVEL_NAMES, QUANTITIES
from .svgplot import Axes, Figure, LegendEntry, as_file
from .verdict import Verdict, assess, relative_change

QUANTITY_LABELS = ("natural frequency [Hz]", "damping ratio [-]", "gain (DC) [y/u]")
QUANTITY_SHORT = ("f", "zeta", "gain")
LEVEL_COLORS = ("#2e7d32", "#f9a825", "#c62828", "#757575")
HEALTH_KEYS = ("residual_var", "condition", "max_relative_std", "projection_fraction", "residual_ratio")


# ------------------------------------------------------------------------------------------------- data
@dataclass
class DiagnosisSeries:
    """The pipeline's reports as arrays over output instants (one row per report)."""

    time_s: np.ndarray                  # (N,)
    modal: np.ndarray                   # (N, K, 6): f, zeta, gain, and their std (NaN before init)
    baseline: np.ndarray                # (N, K, 3), NaN while not learned
    flags: np.ndarray                   # (N, K, 3) bool
    estimating: np.ndarray              # (N,) bool
    health_level: np.ndarray            # (N,) int (0 OK, 1 WARN, 2 ERROR, 3 STALE)
    health: dict[str, np.ndarray]       # HEALTH_KEYS -> (N,) float (NaN where not reported)
    phase: list[str]
    reasons: list[list[str]]
    hold: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))      # (N,) health hold
    issues: list[list[str] | None] = field(default_factory=list)             # health issue kinds (None: unknown)
    model_order: list[dict[str, str]] = field(default_factory=list)         # model-order check: state, message
    decisions: list[list[dict[str, Any]]] = field(default_factory=list)     # per report: the modes' decision states
    alignment_residual: list[float] = field(default_factory=list)           # controller invariant, relative

    @property
    def K(self) -> int:
        return int(self.modal.shape[1])

    @property
    def n(self) -> int:
        return int(self.time_s.size)

    @classmethod
    def from_reports(cls, reports: Sequence[Any], K: int) -> DiagnosisSeries:
        """Stack :class:`..core.pipeline.Report` objects (any object with the same attributes)."""
        n = len(reports)
        out = cls(time_s=np.zeros(n), modal=np.full((n, K, 6), np.nan), baseline=np.full((n, K, 3), np.nan),
                  flags=np.zeros((n, K, 3), bool), estimating=np.zeros(n, bool), health_level=np.zeros(n, int),
                  health={k: np.full(n, np.nan) for k in HEALTH_KEYS}, phase=[], reasons=[],
                  hold=np.zeros(n, bool), issues=[])
        for j, rep in enumerate(reports):
            out.time_s[j] = rep.time_s
            if np.size(rep.modal) == 6 * K:   # else a report before the automatic start found the modes (K = 0)
                out.modal[j] = np.asarray(rep.modal, float).reshape(K, 6)
                out.baseline[j] = np.asarray(rep.baseline, float).reshape(K, 3)
                out.flags[j] = np.asarray(rep.flags, bool).reshape(K, 3)
            out.estimating[j] = bool(rep.estimating)
            h = rep.health or {}
            out.health_level[j] = int(h.get("level", 0))
            for k in HEALTH_KEYS:
                v = h.get(k)
                if isinstance(v, int | float) and not isinstance(v, bool):
                    out.health[k][j] = float(v)
            out.phase.append(str(rep.phase))
            out.reasons.append([str(x) for x in h.get("reasons", [])])
            out.hold[j] = bool(h.get("hold", False))
            iss = h.get("issues")
            out.issues.append(None if iss is None else [str(x) for x in iss])
            mo = h.get("model_order") or {}
            out.model_order.append({k: str(mo[k]) for k in ("state", "message") if k in mo})
            al = h.get("alignment") or {}
            rel = al.get("relative_residual") if isinstance(al, Mapping) else None
            out.alignment_residual.append(float(rel) if isinstance(rel, int | float) else math.nan)
            out.decisions.append([{k: d.get(k) for k in ("mode", "state", "reason", "holds")}
                                  for d in h.get("modes") or ()])
        return out

    def records(self) -> list[Any]:
        """The per-report fields :func:`..verdict.assess` reads, as light objects."""
        from types import SimpleNamespace

        out = []
        for j in range(self.n):
            h: dict[str, Any] = {"hold": bool(self.hold[j]) if self.hold.size == self.n else False,
                                 "reasons": self.reasons[j] if j < len(self.reasons) else []}
            if j < len(self.issues) and self.issues[j] is not None:
                h["issues"] = self.issues[j]
            if j < len(self.model_order) and self.model_order[j]:
                h["model_order"] = self.model_order[j]
            if j < len(self.alignment_residual) and math.isfinite(self.alignment_residual[j]):
                h["alignment"] = {"relative_residual": float(self.alignment_residual[j])}
            if j < len(self.decisions) and self.decisions[j]:
                h["modes"] = self.decisions[j]
            out.append(SimpleNamespace(time_s=float(self.time_s[j]), phase=self.phase[j],
                                       estimating=bool(self.estimating[j]), health=h))
        return out

    def first_estimate(self) -> int | None:
        idx = np.flatnonzero(self.estimating & np.all(np.isfinite(self.modal[:, :, :3]), axis=(1, 2)))
        return int(idx[0]) if idx.size else None

    def last_estimate(self) -> int | None:
        idx = np.flatnonzero(self.estimating & np.all(np.isfinite(self.modal[:, :, :3]), axis=(1, 2)))
        return int(idx[-1]) if idx.size else None


@dataclass
class TruthData:
    """``/truth/modes`` (times, (n, K_plant, 6)) and ``/truth/fault`` messages of a simulated bag."""

    t: np.ndarray | None = None
    modes: np.ndarray | None = None
    fault: list[dict] | None = None

    @property
    def has_modes(self) -> bool:
        return self.t is not None and self.modes is not None and len(self.t) > 0

    def mode_rows(self) -> np.ndarray | None:
        """``modes`` when the bag has truth modes (:attr:`has_modes`), else None."""
        return self.modes if self.has_modes else None

    def fault_intervals(self, end_s: float) -> list[dict]:
        """Active intervals of each truth fault: ``{start, end, kind, mode, quantity, direction, label}``."""
        out: list[dict] = []
        open_: dict[str, dict] = {}
        for msg in self.fault or []:
            f = msg.get("fault")
            if not isinstance(f, Mapping):
                continue
            key = repr(sorted((k, repr(v)) for k, v in f.items()))
            t = float(msg.get("time_s", math.nan))
            if msg.get("event") == "onset":
                d = {"start": t, "end": end_s, "kind": f.get("kind", ""), "mode": f.get("mode"),
                     "quantity": f.get("quantity"), "direction": f.get("direction", ""), "label": _fault_label(f)}
                open_[key] = d
                out.append(d)
            elif msg.get("event") == "end" and key in open_:
                open_.pop(key)["end"] = t
        return out


def _fault_label(f: Mapping[str, Any]) -> str:
    if f.get("kind") == "structural":
        rc = f.get("relative_change")
        size = f" {rc * 100:+.3g} %" if isinstance(rc, int | float) else ""
        return f"mode {f.get('mode')} {f.get('quantity')}{size} ({f.get('shape', '')})"
    return f"sensor {f.get('type', f.get('kind', ''))}"


@dataclass
class FrfEstimate:
    """A nonparametric FRF on the excited frequency bins of one data window."""

    freqs_hz: np.ndarray
    g: np.ndarray
    coherence: np.ndarray
    t_start_s: float
    t_end_s: float
    uncertainty: np.ndarray | None = None    # |G| error bound per bin (noise and window leakage; core.frf)


@dataclass
class ReportInput:
    """Everything :func:`write_report` needs; :mod:`.cli.diagnose` fills it."""

    title: str
    series: DiagnosisSeries
    events: list[dict]                       # events.csv rows + alarm_time_s (floats; clear None if open)
    structures: list[SubmodelStructure]
    rate_hz: float
    closed_loop: bool
    input_delay_samples: int
    duration_s: float
    params: dict[str, Any]
    info: dict[str, Any] = field(default_factory=dict)     # bag, params file, timings ... (shown as a table)
    truth: TruthData = field(default_factory=TruthData)
    frf_start: FrfEstimate | None = None
    frf_end: FrfEstimate | None = None
    param_help: dict[str, str] = field(default_factory=dict)
    verdict: Verdict | None = None           # from the reports (..verdict.assess); None: from ``series``
    mode_finding: Any = None                 # the automatic start's core.modefind.ModeFindResult (None: guesses)

    def get_verdict(self) -> Verdict:
        return self.verdict if self.verdict is not None else assess_series(self.events, self.series,
                                                                             self.duration_s)


# ------------------------------------------------------------------------------------------------- numerics
def thetas_from_modal(modal: np.ndarray, structures: Sequence[SubmodelStructure]) -> list[np.ndarray] | None:
    """Rebuild theta ([RA-SRIVC] eq. 7) from ``[f, zeta, gain]`` per mode; None if a mode is not representable."""
    out = []
    for row, s in zip(np.asarray(modal, float), structures, strict=True):
        f, z, g = (float(v) for v in row[:3])
        if not all(math.isfinite(v) for v in (f, z, g)):
            return None
        if s.n == 0 and s.m == 0:
            out.append(np.array([g]))
        elif s.n == 2 and s.m == 0 and f > 0:
            out.append(theta_from_modal(f, z, g))
        elif s.n == 1 and s.m == 0 and f > 0:
            out.append(np.array([1.0 / (2 * math.pi * f), g]))
        else:
            return None
    return out


def model_frf(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], freqs_hz: np.ndarray,
              rate_hz: float, delay_samples: int = 0) -> np.ndarray:
    """Frequency response of the sampled additive model ``sum_i ZOH{B_i/(p^l_i A_i)}(e^{jwh}) q^-d``: the exact
    ZOH discretization of :func:`..core.frf.discrete_model_frf`, which is what a nonparametric estimate from
    sampled data measures."""
    from ..core.identification.frf import discrete_model_frf

    return discrete_model_frf(thetas, structures, rate_hz, np.asarray(freqs_hz, float), delay_samples)


def nonparametric_frf(u: np.ndarray, y: np.ndarray, rate_hz: float, r: np.ndarray | None = None,
                      t_start_s: float = 0.0, nperseg: int | None = None) -> FrfEstimate:
    """The data's FRF for the report: :func:`..core.frf.estimate_frf` (the one estimate in the code; closed loop
    ``G = S_yr / S_ur`` through the reference, open loop ``S_yu / S_uu``) on the longest finite stretch of the
    window, restricted to its valid bins (excited, coherent, informative) that are not a periodic excitation's
    leakage (there ``G`` leans towards a neighbouring line's value beyond the stated uncertainty)."""
    from ..core.identification.frf import estimate_frf, longest_finite

    u = np.asarray(u, float)
    y = np.asarray(y, float)
    x = None if r is None else np.asarray(r, float)
    sl = longest_finite(x, u, y)
    n = sl.stop - sl.start
    if n < 64:
        raise ValueError(f"window too short for a spectral estimate ({n} finite samples)")
    est = estimate_frf(u[sl], y[sl], rate_hz, None if x is None else x[sl], nperseg=nperseg)
    v = est.valid if est.leakage is None else est.valid & ~est.leakage
    t0 = t_start_s + sl.start / rate_hz
    return FrfEstimate(est.freqs_hz[v], est.G[v], est.coherence[v], t0, t0 + n / rate_hz, est.uncertainty[v])


def frf_windows(n: int, rate_hz: float, init_duration_s: float = 0.0) -> tuple[slice, slice]:
    """Data windows for the start and end estimates: the first and the last quarter of the bag
    (at least the initialization window, at most half of the bag each)."""
    q = max(n // 4, min(int(init_duration_s * rate_hz), n // 2))
    return slice(0, q), slice(n - q, n)


def assess_series(events: Sequence[Mapping[str, Any]], series: DiagnosisSeries, duration_s: float) -> Verdict:
    """:func:`..verdict.assess` over a :class:`DiagnosisSeries` (the same rules as over the reports)."""
    return assess(series.records(), duration_s, events)


def verdict(events: Sequence[Mapping[str, Any]], series: DiagnosisSeries, duration_s: float) -> tuple[str, str]:
    """``(level, sentence)``: level OK | FAULT | DEGRADED | NO ESTIMATE (see :mod:`..verdict`)."""
    v = assess_series(events, series, duration_s)
    return v.level, v.text


# ------------------------------------------------------------------------------------------------- figures
def _figure(w: float, h: float, **margins: float) -> Figure:
    """A figure with fixed margins in inches (:class:`..svgplot.Figure`)."""
    return Figure(w, h, **margins)


def _event_end(e: Mapping[str, Any], end_s: float) -> float:
    c = e.get("clear_time_s")
    return end_s if c in (None, "") else float(c)


def modes_figure(inp: ReportInput) -> Figure:
    """K x 3 grid: estimate +-2 sigma, baseline, truth, initialization and fault intervals over time."""
    s = inp.series
    K = s.K
    if K == 0:   # no guesses and the automatic start found no mode (health says why)
        fig = _figure(13.0, 1.5)
        fig.text(0.5, 0.5, "no modes: the automatic start found none in this record (see the estimator health)")
        return fig
    fig = _figure(13.0, 2.3 * K + 1.0, top_in=0.75, wspace=0.22)
    axes = fig.subplots(K, 3, sharex=True)
    t = s.time_s
    end = inp.duration_s
    first = s.first_estimate()
    t_init = t[first] if first is not None else end
    truth = inp.truth
    for i in range(K):
        for q in range(3):
            ax = axes[i, q]
            est, sd = s.modal[:, i, q], s.modal[:, i, q + 3]
            ax.axvspan(0, t_init, color="0.85", label="initializing")
            for e in inp.events:
                if int(e["mode"]) == i + 1 and e["quantity"] == QUANTITIES[q]:
                    ax.axvspan(float(e["onset_time_s"]), _event_end(e, end), color="#e53935", alpha=0.18,
                               label="fault (detected)")
            ax.fill_between(t, est - 2 * sd, est + 2 * sd, color="#1e88e5", alpha=0.25, label="±2σ")
            ax.plot(t, est, color="#1565c0", lw=1.3, label="estimate")
            if np.any(np.isfinite(s.baseline[:, i, q])):
                ax.plot(t, s.baseline[:, i, q], color="k", ls="--", lw=1.0, label="baseline")
            tm = truth.mode_rows()
            if tm is not None and i < tm.shape[1]:
                ax.plot(truth.t, tm[:, i, q], color="#2e7d32", ls=":", lw=1.6, label="truth (bag)")
            ax.grid()
            if i == 0:
                ax.set_title(QUANTITY_LABELS[q])
            if q == 0:
                ax.set_ylabel(f"mode {i + 1}")
            if i == K - 1:
                ax.set_xlabel("time since first sample [s]")
            _robust_ylim(ax, est, sd, tm[:, i, q] if tm is not None and i < tm.shape[1] else None)
    entries: dict[str, LegendEntry] = {}
    for ax in axes.ravel():
        for e in ax.legend_entries():
            entries.setdefault(e.label, e)
    fig.legend(list(entries.values()))
    return fig


def _robust_ylim(ax: Axes, est: np.ndarray, sd: np.ndarray, truth: np.ndarray | None) -> None:
    """Limits from the estimate after its first few samples (start-up transients do not squash the plot)."""
    vals = est[np.isfinite(est)]
    if vals.size == 0:
        return
    lo_hi = [np.percentile(vals, 1), np.percentile(vals, 99)]
    sdv = sd[np.isfinite(sd)]
    pad_sd = 2 * float(np.median(sdv)) if sdv.size else 0.0
    if truth is not None and np.any(np.isfinite(truth)):
        lo_hi += [np.nanmin(truth), np.nanmax(truth)]
    lo, hi = min(lo_hi) - pad_sd, max(lo_hi) + pad_sd
    span = hi - lo if hi > lo else max(abs(hi), 1e-12) * 0.05
    ax.set_ylim(lo - 0.15 * span, hi + 0.15 * span)


def timeline_figure(inp: ReportInput) -> Figure:
    """Rows per mode and quantity: detected fault intervals (red), truth faults (hatched), health band."""
    s = inp.series
    K = s.K
    end = inp.duration_s
    rows = [f"mode {i + 1} {QUANTITY_SHORT[q]}" for i in range(K) for q in range(3)]
    intervals = inp.truth.fault_intervals(end)
    sensor = [iv for iv in intervals if iv["kind"] != "structural"]
    labels = ["estimator health", *(["sensor (truth)"] if sensor else []), *rows]
    fig = _figure(13.0, 0.35 * len(labels) + 1.4, left_in=1.5, right_in=3.2)
    ax = fig.subplots()[0, 0]
    ypos = {lab: len(labels) - 1 - j for j, lab in enumerate(labels)}
    for blind in inp.get_verdict().blind_intervals:   # where the structural tests were blind
        ax.axvspan(blind.start_s, blind.end_s, color="#bdbdbd" if blind.startup else "#ffcc80", alpha=0.35)
    t = s.time_s
    if t.size:                                     # health band: one bar per run of equal level
        lvl = np.minimum(s.health_level, 3)
        for a, b in _level_runs(lvl):
            t_end = t[b] if b < t.size else end
            ax.bar(t[a], max(t_end - t[a], 0.0), ypos["estimator health"] - 0.35, 0.7, color=LEVEL_COLORS[int(lvl[a])])
    for iv in intervals:
        if iv["kind"] == "structural" and iv["quantity"] in QUANTITIES and isinstance(iv["mode"], int) \
                and 1 <= iv["mode"] <= K:
            y = ypos[f"mode {iv['mode']} {QUANTITY_SHORT[QUANTITIES.index(iv['quantity'])]}"]
        elif iv["kind"] != "structural":
            y = ypos["sensor (truth)"]
        else:
            continue
        ax.bar(iv["start"], max(iv["end"] - iv["start"], end * 0.004), y - 0.4, 0.8, facecolor="none",
               edgecolor="#2e7d32", hatch="///")
        ax.text(iv["start"], y + 0.42, iv["label"], size=7, color="#2e7d32", va="bottom")
    for e in inp.events:
        q = QUANTITIES.index(e["quantity"]) if e["quantity"] in QUANTITIES else None
        key = f"mode {e['mode']} {QUANTITY_SHORT[q]}" if q is not None else None
        if key not in ypos:
            continue
        y = ypos[key]
        t0 = float(e["onset_time_s"])
        ax.bar(t0, max(_event_end(e, end) - t0, end * 0.004), y - 0.3, 0.6, color="#e53935", alpha=0.8)
        if e.get("alarm_time_s") is not None and math.isfinite(float(e["alarm_time_s"])):
            ax.plot([float(e["alarm_time_s"])], [y], color="k", ls="", marker="v", ms=6)
        ax.text(t0, y - 0.45, f"{e['direction']} {_fmt_rel(e)}", size=7, va="top", color="#b71c1c")
    ax.set_yticks([ypos[lab] for lab in labels], labels)
    ax.set_ylim(-0.8, len(labels) - 0.2)
    ax.set_xlim(0, end)
    ax.set_xlabel("time since first sample [s]")
    ax.grid("x")
    legend = [LegendEntry("detected fault (onset → clear); ▼ alarm", "#e53935", alpha=0.8),
              LegendEntry("true fault (bag /truth/fault)", "none", hatch="///", edgecolor="#2e7d32"),
              *[LegendEntry(f"health {LEVEL_NAMES[k]}", LEVEL_COLORS[k]) for k in range(3)],
              LegendEntry("tests blind: start-up", "#bdbdbd", alpha=0.35),
              LegendEntry("tests blind: disruption", "#ffcc80", alpha=0.35)]
    ax.legend(legend, loc="outside right")
    ax.set_title("Fault timeline")
    return fig


def _level_runs(level: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of equal values."""
    change = np.flatnonzero(np.diff(level)) + 1
    return list(zip(np.concatenate(([0], change)), np.concatenate((change, [level.size])), strict=True))


def _fmt_rel(e: Mapping[str, Any]) -> str:
    rel = relative_change(e.get("value"), e.get("baseline"))
    return "" if rel is None else f"{rel:+.1f} %"


def frf_figure(inp: ReportInput) -> Figure | None:
    """Bode plot: model at the start and at the end over the nonparametric estimates ([RA-SRIVC] Figs. 7, 12)."""
    s = inp.series
    i0, i1 = s.first_estimate(), s.last_estimate()
    if i0 is None:
        return None
    th0 = thetas_from_modal(s.modal[i0, :, :3], inp.structures)
    th1 = thetas_from_modal(s.modal[i1, :, :3], inp.structures)
    nyq = inp.rate_hz / 2
    fmodes = [v for v in s.modal[i0, :, 0] if math.isfinite(v) and v > 0]
    pts = [e for e in (inp.frf_start, inp.frf_end) if e is not None and e.freqs_hz.size]
    lows = [0.2 * min(fmodes)] if fmodes else []
    highs = [3.0 * max(fmodes)] if fmodes else []
    lows += [0.8 * float(e.freqs_hz.min()) for e in pts]
    highs += [1.25 * float(e.freqs_hz.max()) for e in pts]
    fmin = min(lows, default=nyq * 1e-3)
    fmax = max(highs, default=nyq * 0.5)
    fmin, fmax = max(fmin, nyq * 1e-5), min(fmax, 0.95 * nyq)
    if not fmax > fmin:
        fmin, fmax = nyq * 1e-3, 0.95 * nyq
    f = np.logspace(math.log10(fmin), math.log10(fmax), 1200)
    fig = _figure(11.0, 6.5, hspace=0.08)
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)[:, 0]
    ax_m.set_xscale("log")
    ax_m.set_xlim(fmin, fmax)
    colors = ("#1565c0", "#e65100")
    for est, col in ((inp.frf_start, colors[0]), (inp.frf_end, colors[1])):
        if est is None or est.freqs_hz.size == 0:
            continue
        ax_m.plot(est.freqs_hz, 20 * np.log10(np.abs(est.g)), ls="", marker="o", ms=4, color=col, alpha=0.7,
                  label=f"data {est.t_start_s:.3g}–{est.t_end_s:.3g} s (nonparametric)")
        ax_p.plot(est.freqs_hz, np.degrees(np.angle(est.g)), ls="", marker="o", ms=4, color=col, alpha=0.7)
    for th, j, col, lab in ((th0, i0, colors[0], "start"), (th1, i1, colors[1], "end")):
        if th is None:
            continue
        g = model_frf(th, inp.structures, f, inp.rate_hz, inp.input_delay_samples)
        ax_m.plot(f, 20 * np.log10(np.abs(g)), color=col, lw=1.6, label=f"model at {s.time_s[j]:.3g} s ({lab})")
        ax_p.plot(f, np.degrees(np.angle(g)), color=col, lw=1.2)
    for i, fm in enumerate(s.modal[i0, :, 0]):      # each mode where the model starts (found or guessed)
        if math.isfinite(fm) and fmin < fm < fmax:
            ax_m.axvline(fm, color="0.4", ls=":", lw=0.9)
            ax_m.text(fm, 1.0, f"mode {i + 1}", size=8, color="0.3", ycoord="axes", dx=2, dy=-10)
    tr = inp.truth
    tm = tr.mode_rows()
    if tm is not None and tr.t is not None:
        for j, ls, lab in ((0, "--", "start"), (-1, ":", "end")):
            rows = tm[j]
            if np.all(np.isfinite(rows[:, :3])) and np.all(rows[:, 0] > 0):
                th = [theta_from_modal(*row[:3]) for row in rows]
                g = model_frf(th, [SubmodelStructure()] * len(th), f, inp.rate_hz, inp.input_delay_samples)
                ax_m.plot(f, 20 * np.log10(np.abs(g)), color="#2e7d32", ls=ls, lw=1.0,
                          label=f"true plant at {tr.t[j]:.3g} s ({lab}, all {len(th)} modes)")
    ax_m.set_ylabel("magnitude [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [Hz]")
    ax_p.set_ylim(-185, 185)
    ax_p.set_yticks([-180, -90, 0, 90, 180])
    for ax in (ax_m, ax_p):
        ax.grid()
    ax_m.legend(loc="best")
    how = "G = S_ry/S_ru (closed loop, cross-spectra with the reference)" if inp.closed_loop else \
        "G = S_uy/S_uu (open loop)"
    ax_m.set_title(f"Plant frequency response: model vs data; data points {how}")
    return fig


def health_figure(inp: ReportInput) -> Figure:
    """Health level, residual variance, condition number and relative uncertainty over time."""
    s = inp.series
    t = s.time_s
    panels = [("health level", None), ("residual variance [y²]", "residual_var"),
              ("IV condition number", "condition"), ("max relative std of (f, ζ, gain)", "max_relative_std")]
    panels = [p for p in panels if p[1] is None or np.any(np.isfinite(s.health[p[1]]))]
    fig = _figure(13.0, 1.7 * len(panels) + 0.8, left_in=1.1, hspace=0.12)
    axes = fig.subplots(len(panels), 1, sharex=True)[:, 0]
    for ax, (label, key) in zip(axes, panels, strict=True):
        if key is None:
            for a, b in _level_runs(s.health_level):
                t_end = t[b] if b < t.size else t[-1]
                k = int(s.health_level[a])
                if k < 3:
                    ax.bar(t[a], t_end - t[a], -0.2, 2.4, color=LEVEL_COLORS[k], alpha=0.25)
            ax.step(t, s.health_level, color="k", lw=1.0)
            ax.set_yticks([0, 1, 2], LEVEL_NAMES[:3])
            ax.set_ylim(-0.3, 2.3)
        else:
            v = s.health[key]
            if key in ("residual_var", "condition") and np.any(v[np.isfinite(v)] > 0):
                ax.set_yscale("log")
                ax.plot(t, np.where(v > 0, v, np.nan), color="#6a1b9a", lw=1.2)
            else:
                ax.plot(t, v, color="#6a1b9a", lw=1.2)
        ax.set_ylabel(label, size=8)
        ax.grid()
    axes[-1].set_xlabel("time since first sample [s]")
    axes[0].set_title("Estimator health (structural tests are frozen while it is not OK)")
    return fig


# ------------------------------------------------------------------------------------------------- HTML
_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:1.5em auto;max-width:1320px;color:#222}
h1{font-size:1.5em;margin-bottom:.2em} h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
.verdict{padding:.7em 1em;border-radius:6px;font-size:1.1em;margin:.8em 0}
.FAULT{background:#ffebee;border-left:6px solid #c62828}.OK{background:#e8f5e9;border-left:6px solid #2e7d32}
.DEGRADED{background:#fff8e1;border-left:6px solid #f9a825}.NO{background:#eeeeee;border-left:6px solid #757575}
table{border-collapse:collapse;font-size:.9em;margin:.5em 0} td,th{border:1px solid #ddd;padding:3px 8px}
th{background:#f5f5f5;text-align:left} td.num{text-align:right;font-family:ui-monospace,monospace}
img{max-width:100%} .note{color:#555;font-size:.9em} .fault{color:#c62828;font-weight:600}
"""


def _num(v: Any, digits: int = 5) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return html.escape(str(v))
    if not math.isfinite(x):
        return "–"
    return f"{x:.{digits}g}"


def summary_rows(inp: ReportInput) -> list[dict[str, Any]]:
    """Per mode and quantity: final estimate, std, baseline, change, truth at the end, fault state."""
    s = inp.series
    j = s.last_estimate()
    rows = []
    for i in range(s.K):
        for q in range(3):
            final = s.modal[j, i, q] if j is not None else math.nan
            std = s.modal[j, i, q + 3] if j is not None else math.nan
            base = s.baseline[-1, i, q] if s.n else math.nan
            truth = math.nan
            tm = inp.truth.mode_rows()
            if tm is not None and i < tm.shape[1]:
                truth = float(tm[-1, i, q])
            ev = [e for e in inp.events if int(e["mode"]) == i + 1 and e["quantity"] == QUANTITIES[q]]
            open_ = [e for e in ev if e.get("clear_time_s") in (None, "")]
            fault = "-"
            if open_:
                fault = f"{open_[-1]['direction'].upper()} since {float(open_[-1]['onset_time_s']):.2f} s"
            elif ev:
                fault = f"{len(ev)} cleared event(s)"
            rows.append({"mode": i + 1, "quantity": QUANTITIES[q], "label": QUANTITY_LABELS[q], "final": final,
                         "std": std, "baseline": base, "change_pct": relative_change(final, base), "truth": truth,
                         "fault": fault})
    return rows


def _img(svg: str, alt: str) -> str:
    """An inline SVG figure with its alternative text."""
    return f'<figure role="img" aria-label="{html.escape(alt)}">{svg}</figure>'


def _table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(rows_) + "</tr>" for rows_ in
                   ([c if c.startswith("<td") else f"<td>{c}</td>" for c in r] for r in rows))
    return f"<table><tr>{head}</tr>{body}</table>"


def render_html(inp: ReportInput, figures: Mapping[str, str]) -> str:
    """The report page; ``figures`` maps modes/timeline/frf/health to SVG text (missing ones are skipped)."""
    v = inp.get_verdict()
    level, text = v.level, v.text
    cls = level.split()[0]
    esc = html.escape
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{esc(inp.title)} – resonance diagnosis"
             f"</title><style>{_CSS}</style></head><body>",
             f"<h1>Resonance diagnosis: {esc(inp.title)}</h1>",
             f"<div class='verdict {cls}'><b>{esc(level)}</b> — {esc(text)}</div>",
             "<p class='note'>Each resonance (mode) of the plant is tracked online by a recursive estimator "
             "(closed-loop additive recursive SRIVC) as natural frequency, damping ratio and gain with their "
             "uncertainty. After it settles, a baseline is learned from a healthy stretch; a fault is flagged "
             "when a quantity moves away from its baseline by more than the relevant change for long enough "
             "(sequential CUSUM test).</p>"]
    parts += _coverage_html(v)
    rows = []
    for r in summary_rows(inp):
        fault_cls = " class='fault'" if r["fault"] != "-" and "cleared" not in r["fault"] else ""
        rows.append([str(r["mode"]), esc(r["label"]), f"<td class='num'>{_num(r['final'], 6)}</td>",
                     f"<td class='num'>{_num(r['std'], 3)}</td>", f"<td class='num'>{_num(r['baseline'], 6)}</td>",
                     f"<td class='num'>{_pct(r['change_pct'])}</td>",
                     f"<td class='num'>{_num(r['truth'], 6)}</td>", f"<td{fault_cls}>{esc(r['fault'])}</td>"])
    parts += ["<h2>Summary per mode (at the end of the bag)</h2>",
              _table(["mode", "quantity", "final", "± std", "baseline", "change", "truth (bag)", "fault"], rows)]
    if inp.events:
        ev_rows = [[_num(e["onset_time_s"], 6), _num(e.get("alarm_time_s"), 6),
                    "open" if e.get("clear_time_s") in (None, "") else _num(e["clear_time_s"], 6), str(e["mode"]),
                    esc(e["quantity"]), esc(e["direction"]), _num(e["baseline"], 6), _num(e["value"], 6),
                    esc(_fmt_rel(e))] for e in inp.events]
        parts += ["<h2>Fault events</h2>", _table(["onset [s]", "alarm [s]", "clear [s]", "mode", "quantity",
                                                  "direction", "baseline", "value", "change"], ev_rows)]
    captions = {
        "modes": ("Modal estimates over time", "Blue: estimate with its ±2σ band; dashed black: learned baseline; "
                  "dotted green: truth recorded in the bag (simulations only); grey: initialization; red: "
                  "detected fault intervals."),
        "timeline": ("Fault timeline", "Red bars: detected structural faults from the estimated change time to "
                     "the clear time (▼ marks when the alarm was raised). Hatched green: the true fault schedule "
                     "when the bag has one. Top row: estimator health. Shaded: the fault tests were blind (grey: "
                     "start-up; orange: data gap, health hold or baseline window restarted)."),
        "frf": ("Frequency response: model vs data", "Lines: frequency response of the estimated model (with the "
                "known input delay, zero-order hold) at the first and the last estimate. Dots: nonparametric "
                "estimate from the first and the last quarter of the data, only at frequencies the excitation "
                "reaches. A model that fits lies on the dots of its own time window."),
        "order": ("Model order: why K modes", "Below: the automatic start's order scan, one row per model order K "
                  "with a marker per fitted mode (filled: within 1 % in frequency and 5 % in damping of a mode of "
                  "order K - 1; open: new or moved), grey dots the peaks read off the FRF; right: each order's "
                  "held-out output error. The shaded row is the order chosen (the last significant gain on "
                  "held-out data). Above: the FRF of the search window's data and the chosen model."),
        "health": ("Estimator health", "Health level and its indicators: residual variance, condition number of "
                   "the instrumental-variable matrix (high: poor excitation), and the largest relative "
                   "uncertainty of the modal estimates."),
    }
    for key, (title, cap) in captions.items():
        if key in figures:
            parts += [f"<h2>{esc(title)}</h2>", f"<p class='note'>{esc(cap)}</p>", _img(figures[key], title)]
    if inp.info:
        parts += ["<h2>Run</h2>", _table(["item", "value"], [[esc(str(k)), esc(str(v))] for k, v in inp.info.items()])]
    prow = [[esc(k), f"<td class='num'>{esc(_param_str(v))}</td>", esc(inp.param_help.get(k, ""))]
            for k, v in sorted(inp.params.items())]
    parts += ["<h2>Parameters used</h2>", _table(["parameter", "value", "meaning"], prow), "</body></html>"]
    return "\n".join(parts)


def _coverage_html(v: Verdict) -> list[str]:
    """'Where the fault tests ran' section: monitored seconds and the blind intervals with their reasons."""
    esc = html.escape
    pct = 100.0 * v.monitored_s / v.duration_s if v.duration_s > 0 else 0.0
    head = (f"<p>The structural fault tests ran against a trusted baseline for <b>{v.monitored_s:.1f} s of "
            f"{v.duration_s:.1f} s</b> ({pct:.0f} % of the record). Faults that happened while they were blind can "
            "only be seen once they run again, and not at all if the baseline was learned after the change.</p>")
    rows = [[f"<td class='num'>{b.start_s:.2f}</td>", f"<td class='num'>{b.end_s:.2f}</td>",
             "start-up" if b.startup else "<b>disruption</b>", esc(b.reason)] for b in v.blind_intervals]
    table = _table(["from [s]", "to [s]", "", "why the fault tests did not run"], rows) if rows else ""
    return ["<h2>Where the fault tests ran</h2>", head, table]


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{v:+.2f} %"


def _param_str(v: Any) -> str:
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_param_str(x) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:.8g}"
    return str(v)


def write_report(inp: ReportInput, out_dir: str | Path, *, modes_svg: bool = True) -> Path:
    """Render the figures and write ``out_dir/report.html`` (and ``out_dir/modes.svg``); return the HTML path."""
    out_dir = Path(out_dir)
    figures: dict[str, str] = {}
    if inp.series.n:
        figures["modes"] = modes_figure(inp).svg("m")
        figures["timeline"] = timeline_figure(inp).svg("t")
        frf = frf_figure(inp)
        if frf is not None:
            figures["frf"] = frf.svg("b")
        figures["health"] = health_figure(inp).svg("h")
    if inp.mode_finding is not None:
        from .stabilization_plot import from_mode_finding

        figures["order"] = from_mode_finding(inp.mode_finding, inp.input_delay_samples).svg("o")
    if modes_svg and "modes" in figures:
        (out_dir / "modes.svg").write_text(as_file(figures["modes"]), encoding="utf-8")   # drawn once
    path = out_dir / "report.html"
    path.write_text(render_html(inp, figures), encoding="utf-8")
    return path
