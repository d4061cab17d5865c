"""``rsrivc_fleet``'s human report: ``fleet.html`` (self-contained, inline SVG figures) from the fleet summary.

Per machine (params file): the recordings in order of their first sample's time with their verdicts, each mode's
quantities across the recordings (levels with +-2 standard errors, red from the first recording of a flagged
drift on, the fitted trend and the relevant-change band
of the fault logic around the first recording's fitted level), the drift tests (:mod:`.core.trend`) and the bags
that did not feed them; then the bags that failed. :func:`trend_svg` renders one machine's figure.
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from typing import Any

from ..core.vocabulary import QUANTITIES
from .svgplot import Axes, Figure

LABELS = dict(zip(QUANTITIES, ("natural frequency [Hz]", "damping ratio [-]", "gain (DC)"), strict=True))
_CSS = ("body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse;margin:.5em 0}"
        "td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}td.num{text-align:right}.drift{color:#b00;"
        "font-weight:bold}.note{color:#444;font-size:90%}.ok{color:#070}")


def trend_svg(machine: Mapping[str, Any], id_prefix: str = "tr", standalone: bool = False) -> str:
    """One machine's trend figure (SVG, see :meth:`..svgplot.Figure.svg`): rows = quantities, columns = modes,
    x = recording order."""
    bags, tests = machine["bags"], machine["tests"]
    k = int(machine["K"])
    w, h = 3.2 * k + 0.9, 6.4
    fig = Figure(w, h, left_in=1.05, right_in=0.15, top_in=0.6, bottom_in=0.9, hspace=0.25, wspace=0.35)
    title = "; ".join(f"DRIFT: mode {f['mode']} {f['quantity'].replace('_', ' ')} {f['direction']} "
                      f"{f['change_percent']:+.2f} % (relevant from {f['first_bag']})" for f in machine["findings"])
    fig.suptitle(title or "no drift across the recordings", color="#d62728" if title else "#333", size=9)
    axes = fig.subplots(3, k, sharex=True)
    for test in tests:
        i, q = test["mode"] - 1, QUANTITIES.index(test["quantity"])
        if i >= k:
            continue
        ax = axes[q, i]
        first = test["first_index"] if test["flagged"] and test.get("first_index") is not None else len(bags)
        for j, b in enumerate(bags):
            if i >= len(b["value"]):
                continue
            v, s = b["value"][i][q], b["std"][i][q]
            if b["used"] and v is not None and s is not None:
                ax.errorbar(j, v, 2 * s, color="#d62728" if j >= first else "#1f77b4", ms=5 if j >= first else 4)
            elif v is not None:
                ax.plot([j], [v], ls="", marker="o", mfc="none", color="0.6", ms=4)
        _trend_lines(ax, test)
        if q == 0:
            ax.set_title(f"mode {i + 1}")
        if i == 0:
            ax.set_ylabel(LABELS[test["quantity"]], size=8)
        ax.tick_pt = 7.0
        ax.grid()
    step = max(1, math.ceil(len(bags) / 12))
    for ax in axes[-1]:
        ax.set_xticks(list(range(len(bags)))[::step], [b["bag"] for b in bags][::step], rotation=30)
    axes[0, 0].set_xlim(-0.5, len(bags) - 0.5)
    return fig.svg(id_prefix, standalone)


def _trend_lines(ax: Axes, test: Mapping[str, Any]) -> None:
    """The fitted line (red when flagged) and the relevant-change band around the first recording's level."""
    idx, fitted = test.get("indices") or [], test.get("fitted") or []
    if len(fitted) < 2:
        return
    color = "#d62728" if test["flagged"] else "0.3"
    ax.plot(idx, fitted, color=color, lw=1.5 if test["flagged"] else 1.0)
    lv, thr = test.get("level0"), test.get("threshold_percent")
    if lv is not None and thr is not None:
        for sgn in (-1, 1):
            ax.axhline(lv + sgn * abs(lv) * thr / 100.0, color="0.5", ls="--", lw=0.7)


def _img(svg: str, alt: str) -> str:
    """An inline SVG figure with its alternative text."""
    return f'<figure role="img" aria-label="{html.escape(alt)}">{svg}</figure>'


def _table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(c if c.startswith("<td") else f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _n(v: Any, fmt: str = ".4g") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _num_td(text: str) -> str:
    return f"<td class='num'>{html.escape(text)}</td>"


def _utc(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _use_text(b: Mapping[str, Any]) -> str:
    if not b["used"]:
        return f"no: {b['exclusion']}"
    return f"yes ({b['note']})" if b.get("note") else "yes"


def _machine_html(g: Mapping[str, Any], index: int = 0) -> list[str]:
    esc = html.escape
    parts = [f"<h2>Machine: {esc(str(g['machine']))}</h2>", f"<p class='note'>params file {esc(g['params_file'])}</p>"]
    if g["findings"]:
        parts += [f"<p class='drift'>DRIFT: mode {f['mode']} {esc(f['quantity'])} {esc(f['direction'])} "
                  f"{f['change_percent']:+.2f} % across the recordings (relevant change reached at "
                  f"{esc(f['first_bag'])})</p>" for f in g["findings"]]
    else:
        parts.append("<p class='ok'>No drift across the recordings.</p>")
    rows = [[str(j + 1), esc(b["bag"]), esc(_utc(b["start_time_s"])), esc(b["verdict"]), str(b["events"]),
             _num_td(_n(b["level_s"], ".3g")), esc(_use_text(b))] for j, b in enumerate(g["bags"])]
    parts += ["<h3>Recordings (by first sample time)</h3>",
              _table(["#", "bag", "first sample", "verdict", "events", "settled [s]", "in the drift test"], rows),
              "<h3>Trend of each mode across recordings</h3>",
              "<p class='note'>Blue: the mode's level in each recording (median of its estimates over the "
              "recording's settled part) with ±2 standard errors; red: the recordings of a flagged drift from the "
              "first one whose fitted change reaches faults.min_change; hollow grey: a recording left out of the "
              "test; line: the "
              "fitted trend (red: drift flagged); dashed: the relevant change of the fault logic "
              "(faults.min_change) around the first recording's fitted level.</p>",
              _img(trend_svg(g, f"tr{index}_"), "trend across recordings")]
    trows = [[str(t["mode"]), esc(t["quantity"]), str(len(t["indices"])),
              _num_td(f"{_n(t['change_percent'], '+.3f')} ± {_n(t['change_std_percent'], '.2g')}"),
              _num_td(_n(t["p_value"], ".2g")), _num_td(_n(t["alpha"], ".2g")),
              _num_td(_n(t["threshold_percent"], ".3g")), _num_td(_n(t["scatter_percent"], ".2g")),
              f"<td class='drift'>{esc(t['reason'])}</td>" if t["flagged"] else esc(t["reason"])]
             for t in g["tests"]]
    parts += ["<h3>Drift tests</h3>",
              "<p class='note'>Random-effects weighted regression of each level on recording order (between-"
              "recording variance by DerSimonian–Laird, slope std inflated by the Birge ratio), two-sided t test at "
              "level alpha (Bonferroni over the machine's modes × quantities); flagged when significant, when the "
              "fitted change first → last recording reaches faults.min_change and when it exceeds "
              "faults.min_change.spread_factor × the scatter about the line.</p>",
              _table(["mode", "quantity", "recordings", "change [%]", "p", "alpha", "threshold [%]", "scatter [%]",
                      "decision"], trows)]
    return parts


def render_fleet_html(summary: Mapping[str, Any]) -> str:
    """The fleet report page (see the module docstring)."""
    esc = html.escape
    n_bags = sum(len(g["bags"]) for g in summary["machines"])
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>Fleet: resonance trends</title>"
             f"<style>{_CSS}</style></head><body><h1>Fleet: resonance trends across recordings</h1>",
             f"<p>{n_bags} recording(s) diagnosed on {len(summary['machines'])} machine(s); "
             f"{len(summary['failures'])} failed; {len(summary['findings'])} drift finding(s).</p>"]
    for index, g in enumerate(summary["machines"]):
        parts += _machine_html(g, index)
    if summary["failures"]:
        parts += ["<h2>Failed bags (skipped)</h2>",
                  _table(["bag", "path", "error"], [[esc(f["bag"]), esc(f["path"]), esc(f["error"])]
                                                    for f in summary["failures"]])]
    parts.append("</body></html>")
    return "\n".join(parts)
