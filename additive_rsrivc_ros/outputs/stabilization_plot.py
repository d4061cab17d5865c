"""Why K modes: the order scan of the automatic mode finder as a stabilization diagram beside the FRF (SVG).

The order scan (:func:`.core.modefind.order_table`) fits K = 1, 2, ... submodels and keeps, per order, the fit with the
lowest held-out output error; K is the last order that gained significantly on held-out data. Its table
(``order_selection``: per K the errors, ``accepted`` and the fitted ``modes``) is drawn as modal analysis draws
stabilization diagrams: one row per K, one marker per fitted mode at its natural frequency, filled when the order below
has a mode within :data:`STABLE_FREQUENCY` in frequency and :data:`STABLE_DAMPING` in damping, open when it is new or
has moved. The chosen row is shaded and labelled; the right margin gives each row's held-out error and its change
from K - 1. Above, on the same frequency axis: the valid bins of the nonparametric FRF (:mod:`.core.frf`), the chosen
model and the FRF peaks the scan started from. Each row's markers are an SVG group of class ``stab-K<K>`` (plus
``chosen``; a rigid body, frequency 0, is a triangle at the left edge in ``stab-K<K> rigid``), so that a reader can
relate the figure to the JSON table. ``rsrivc_identify`` writes it next to its JSON, ``rsrivc_diagnose`` puts it into
``report.html``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .svgplot import Figure, LegendEntry, as_file

STABLE_FREQUENCY = 0.01
"""Relative frequency change up to which a mode counts as the same mode as one of the next smaller order."""
STABLE_DAMPING = 0.05
"""Relative damping change up to which it also counts as stable in damping (modal analysis' usual 1 % / 5 %)."""
RIGID_AT = 1.12
"""A rigid body (frequency 0) is drawn at this multiple of the lowest frequency shown (the left edge)."""
MAX_FRF_DOTS = 600
"""Up to this many valid FRF bins are drawn as dots (the estimates they are), more as a line."""
COLORS = {"stable": "#1565c0", "new": "#1565c0", "peak": "#616161", "chosen": "#2e7d32", "model": "#e65100"}


def _modes(row: Mapping[str, Any]) -> list[tuple[float, float, int]]:
    """``(f_hz, zeta, integrators)`` of a row's fitted submodels (``order_selection[i]['modes']``)."""
    out = []
    for m in row.get("modes") or []:
        f = m.get("natural_frequency_hz")
        z = m.get("damping_ratio")
        out.append((float(f) if f is not None else math.nan, float(z) if z is not None else math.nan,
                    int(m.get("integrators", 0))))
    return out


def stable_flags(rows: Sequence[Mapping[str, Any]]) -> dict[int, list[bool]]:
    """Per K, per fitted resonant mode (frequency > 0, in the row's order): does the row of order K - 1 have a mode
    within :data:`STABLE_FREQUENCY` in frequency and :data:`STABLE_DAMPING` in damping?"""
    by_k = {int(r["K"]): [m for m in _modes(r) if m[0] > 0] for r in rows}
    out: dict[int, list[bool]] = {}
    for k, modes in by_k.items():
        prev = by_k.get(k - 1, [])
        out[k] = [any(abs(f / g - 1.0) <= STABLE_FREQUENCY and abs(z / w - 1.0) <= STABLE_DAMPING
                      for g, w, _ in prev if g > 0 and w > 0) for f, z, _ in modes]
    return out


def _row_note(row: Mapping[str, Any], below: Mapping[str, Any] | None, chosen_k: int | None) -> str:
    """The right-margin text of a row: its held-out mean squared error, its change from the order below (K - 1) and
    what the scan made of it."""
    err, prev = row.get("validation_error"), (below or {}).get("validation_error")
    note = f"held-out MSE {err:.3g}" if isinstance(err, int | float) else "held-out MSE –"
    if isinstance(err, int | float) and isinstance(prev, int | float) and prev > 0:
        note += f" ({100.0 * (err / prev - 1.0):+.1f} %)"
    status = _row_status(row, chosen_k)
    return note + (f", {status}" if status else "")


def _row_status(row: Mapping[str, Any], chosen_k: int | None = None) -> str:
    """What the scan did with an order, in a few words."""
    if row.get("accepted"):
        return "chosen"
    msg = str(row.get("message") or "")
    if not row.get("modes"):
        if msg.startswith("not tried"):
            return "not tried"
        first = msg.split(";")[0].strip() or "no usable fit"
        return first if len(first) <= 40 else first[:39] + "…"
    if row.get("redundant"):
        return "gain not from its added mode"
    if chosen_k is not None and int(row["K"]) > chosen_k:
        return "no significant gain"
    return ""


def _frequency_range(rows: Sequence[Mapping[str, Any]], peaks_hz: Sequence[float], frf: Any,
                     rate_hz: float) -> tuple[float, float]:
    f = [m[0] for r in rows for m in _modes(r) if m[0] > 0 and math.isfinite(m[0])]
    f += [p for p in peaks_hz if p > 0]
    band = frf.band_hz if frf is not None else None
    if band is not None:
        f += [band[0], band[1]]
    nyq = 0.5 * rate_hz
    if not f:
        return nyq * 1e-3, nyq
    lo, hi = 0.7 * min(f), min(1.4 * max(f), nyq)
    return (lo, hi) if hi > lo else (0.5 * lo, nyq)


def _frf_panel(ax: Any, frf: Any, model: tuple[Sequence[np.ndarray], Sequence[Any]] | None, peaks_hz: Sequence[float],
               chosen_hz: Sequence[float], input_delay: int, f_range: tuple[float, float]) -> None:
    from ..core.identification.frf import discrete_model_frf

    entries = []
    if frf is not None:
        ok = frf.valid & (frf.freqs_hz > 0)
        mag = 20.0 * np.log10(np.maximum(np.abs(frf.G), 1e-300))
        dots = int(ok.sum()) <= MAX_FRF_DOTS
        if dots:
            ax.plot(frf.freqs_hz[ok], mag[ok], ls="", marker="o", ms=3, color="#78909c")
        else:
            ax.plot(frf.freqs_hz, np.where(ok, mag, np.nan), color="#78909c", lw=1.0)
        entries.append(LegendEntry("FRF of the data (valid bins)", "#78909c", "line", ls="" if dots else "-",
                                   lw=1.0, marker="o" if dots else None))
    if model is not None and model[0]:
        f = np.geomspace(f_range[0], f_range[1], 1500)
        g = discrete_model_frf(model[0], model[1], frf.rate_hz if frf is not None else 2.0 * f_range[1], f,
                               input_delay)
        ax.plot(f, 20.0 * np.log10(np.maximum(np.abs(g), 1e-300)), color=COLORS["model"], lw=1.5)
        entries.append(LegendEntry(f"chosen model (K = {len(model[0])})", COLORS["model"], "line"))
    if chosen_hz:
        entries.append(LegendEntry("its modes", COLORS["chosen"], "line", ls="--", lw=0.9))
    if peaks_hz:
        entries.append(LegendEntry("peaks read off the FRF", COLORS["peak"], "line", ls=":", lw=0.9))
    for p in peaks_hz:
        if f_range[0] < p < f_range[1]:
            ax.axvline(p, color=COLORS["peak"], ls=":", lw=0.8)
    for fm in chosen_hz:
        if f_range[0] < fm < f_range[1]:
            ax.axvline(fm, color=COLORS["chosen"], ls="--", lw=0.9)
    ax.set_ylabel("|G| [dB]")
    ax.grid()
    ax.legend(entries, loc="best", size=7.5)


def _diagram_panel(ax: Any, rows: Sequence[Mapping[str, Any]], peaks_hz: Sequence[float],
                   f_range: tuple[float, float]) -> None:
    flags = stable_flags(rows)
    ks = [int(r["K"]) for r in rows]
    labels = {0: "FRF peaks"}
    chosen_k = next((int(r["K"]) for r in rows if r.get("accepted")), None)
    by_k = {int(r["K"]): r for r in rows}
    for row in rows:
        k = int(row["K"])
        chosen = bool(row.get("accepted"))
        labels[k] = f"K = {k}" + (" (chosen)" if chosen else "")
        if chosen:
            ax.bar(f_range[0], f_range[1] - f_range[0], k - 0.4, 0.8, color=COLORS["chosen"], alpha=0.15)
        modes = _modes(row)
        res = [m for m in modes if m[0] > 0]
        st = np.array(flags.get(k, []), bool)
        f = np.array([m[0] for m in res], float)
        tag = f"stab-K{k}" + (" chosen" if chosen else "")
        ax.plot(f[st], np.full(int(st.sum()), k), ls="", marker="o", ms=6, color=COLORS["stable"], gid=tag)
        ax.plot(f[~st], np.full(int((~st).sum()), k), ls="", marker="o", ms=6, color=COLORS["new"], mfc="none",
                gid=tag)
        n_rigid = sum(1 for m in modes if m[0] == 0.0)
        if n_rigid:
            ax.plot(np.full(n_rigid, f_range[0] * RIGID_AT), np.full(n_rigid, k), ls="", marker="v", ms=7,
                    color=COLORS["stable"], gid=tag + " rigid")
        ax.text(1.0, k, _row_note(row, by_k.get(k - 1), chosen_k), size=7.5, xcoord="axes", dx=6, va="center",
                color=COLORS["chosen"] if chosen else "#333")
    p = np.array([v for v in peaks_hz if v > 0], float)
    ax.plot(p, np.zeros(p.size), ls="", marker="o", ms=4, color=COLORS["peak"], gid="stab-peaks")
    top = max(ks, default=1)
    ax.set_ylim(-0.7, top + 0.7)
    ticks = [0, *ks]
    ax.set_yticks(ticks, [labels[t] for t in ticks])
    ax.set_ylabel("model order")
    ax.set_xlabel("frequency [Hz]")
    ax.grid("x")


def stabilization_figure(rows: Sequence[Mapping[str, Any]], *, frf: Any = None, peaks_hz: Sequence[float] = (),
                         model: tuple[Sequence[np.ndarray], Sequence[Any]] | None = None,
                         chosen_hz: Sequence[float] = (), rate_hz: float | None = None, input_delay: int = 0,
                         title: str = "") -> Figure:
    """The figure from the ``order_selection`` rows (their ``to_dict()`` form, as in the JSON), the FRF
    (:class:`.core.frf.FRFEstimate`, optional), the FRF peaks the scan started from, the chosen model
    ``(thetas, structures)`` and its modes' frequencies."""
    rate = float(rate_hz if rate_hz is not None else (frf.rate_hz if frf is not None else 1.0))
    f_range = _frequency_range(rows, peaks_hz, frf, rate)
    n_rows = len(rows) + 1
    fig = Figure(12.0, 3.0 + 0.42 * n_rows, left_in=1.25, right_in=3.4, top_in=0.75, hspace=0.06)
    ax_frf, ax_st = fig.subplots(2, 1, sharex=True, height_ratios=(2.6, 0.55 * n_rows))[:, 0]
    ax_frf.set_xscale("log")
    ax_frf.set_xlim(*f_range)
    _frf_panel(ax_frf, frf, model, peaks_hz, chosen_hz, input_delay, f_range)
    _diagram_panel(ax_st, rows, peaks_hz, f_range)
    chosen = next((int(r["K"]) for r in rows if r.get("accepted")), None)
    ax_frf.set_title(title or (f"Model order: K = {chosen} chosen by held-out output error" if chosen is not None
                               else "Model order: no order chosen"))
    legend = [LegendEntry("mode stable to the order below (1 % f, 5 % ζ)", COLORS["stable"], "line", ls="",
                          marker="o"),
              LegendEntry("new or moved mode", COLORS["new"], "line", ls="", marker="o", mfc="none"),
              LegendEntry("chosen order", COLORS["chosen"], alpha=0.3)]
    if any(m[0] == 0.0 for r in rows for m in _modes(r)):
        legend.insert(2, LegendEntry("▼ rigid body b0/p^l (at the left edge)", COLORS["stable"], "line", ls=""))
    fig.legend(legend, size=8.0)
    return fig


def from_mode_finding(found: Any, input_delay: int = 0, title: str = "") -> Figure:
    """:func:`stabilization_figure` of a :class:`.core.modefind.ModeFindResult` (its table as its ``to_dict``
    writes it into the JSON)."""
    rows = [row.to_dict() for row in found.table]
    peaks = [c.natural_frequency_hz for c in found.candidates if c.natural_frequency_hz > 0]
    chosen_hz = [float(m[0]) for m, s in zip(found.modal, found.structures, strict=True) if s.n == 2]
    return stabilization_figure(rows, frf=found.frf, peaks_hz=peaks, model=(found.thetas, found.structures),
                                chosen_hz=chosen_hz, rate_hz=found.frf.rate_hz, input_delay=input_delay, title=title)


def figure_path(json_path: str | Path) -> Path:
    """Where ``rsrivc_identify`` writes the figure: ``FILE.order.svg`` next to ``FILE.json``."""
    return Path(json_path).with_suffix(".order.svg")



def order_svg(found: Any, input_delay: int = 0) -> str:
    """The figure of a mode finding as an SVG file's content."""
    return as_file(from_mode_finding(found, input_delay).svg("o"))
