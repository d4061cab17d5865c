"""Small SVG figures for the reports: lines, bands, spans, bars, markers and text on linear or log axes.

The reports (:mod:`.report`, :mod:`.fleet_report`) need a few plot types, drawn once per run. matplotlib drew them
in 2.6 s of a 6 s diagnosis, half of it importing itself and rasterizing text; the same figures as SVG
take milliseconds, stay sharp at any zoom, and embed in the HTML as text. The API follows matplotlib's object API
where it overlaps (``Figure.subplots``, ``Axes.plot``, ``fill_between``, ``axvspan``, ``set_ylim`` ...), so the
figure code reads the same. Sizes are in inches at :data:`PX_PER_IN`, line widths and fonts in points.

Lines with more points than the axes has pixel columns keep each column's first, minimum, maximum and last point
(what the eye can see of them); non-finite values (and non-positive ones on a log axis) break a line.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

PX_PER_IN = 100.0
PT = PX_PER_IN / 72.0           # pixels per point
FONT = "system-ui,-apple-system,'Segoe UI',Roboto,'DejaVu Sans',sans-serif"
DASHES = {"-": None, "--": (3.7, 1.6), ":": (1.0, 1.65)}    # in line widths, as matplotlib's


def _esc(s: str) -> str:
    return html.escape(str(s), quote=True)


PX_LIMIT = 1e5    # pixel coordinates are clamped to +-this (the clip path hides what lies outside)


def _f(v: float) -> str:
    """A pixel coordinate: one decimal, clamped to :data:`PX_LIMIT`."""
    return f"{min(max(v, -PX_LIMIT), PX_LIMIT):.1f}"


def _points(xs: np.ndarray, ys: np.ndarray) -> list[str]:
    """``x,y`` pairs exactly as ``f"{_f(x)},{_f(y)}"`` writes them, formatted in one pass (a report's polylines
    and bands hold tens of thousands of points)."""
    return list(map("{:.1f},{:.1f}".format, np.clip(xs, -PX_LIMIT, PX_LIMIT).tolist(),
                    np.clip(ys, -PX_LIMIT, PX_LIMIT).tolist()))


def text_width(s: str, size_pt: float) -> float:
    """Approximate width in pixels of ``s`` in a sans-serif font (0.55 em per character)."""
    return 0.55 * size_pt * PT * len(s)


def nice_ticks(lo: float, hi: float, nbins: int = 5) -> np.ndarray:
    """At most ``nbins + 1`` ticks at 1, 2, 2.5 or 5 times a power of ten inside ``[lo, hi]``."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if math.isfinite(lo) else np.zeros(0)
    raw = (hi - lo) / nbins
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * mag >= raw * (1 - 1e-9))
    first = math.ceil(lo / step - 1e-9)
    last = math.floor(hi / step + 1e-9)
    return np.arange(first, last + 1) * step


def tick_labels(ticks: np.ndarray) -> list[str]:
    """Plain decimal labels with the digits the tick step needs (no offset, no exponent below 1e6)."""
    if ticks.size == 0:
        return []
    big = float(np.max(np.abs(ticks)))
    step = float(np.min(np.diff(ticks))) if ticks.size > 1 else (abs(float(ticks[0])) or 1.0)
    if big >= 1e6 or (0 < big < 1e-4):
        return [f"{v:.3g}" for v in ticks]
    e = math.floor(math.log10(step) + 1e-9)
    dec = max(0, -e + (1 if abs(step / 10.0 ** e - 2.5) < 1e-6 else 0))     # 0.25 needs two digits, 25 none
    out = []
    for v in ticks:
        lab = f"{v:.{dec}f}"
        out.append(f"{0.0:.{dec}f}" if float(lab) == 0 else lab)    # no "-0.0"
    return out


def log_ticks(lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Major ticks at the decades inside ``[lo, hi]`` (also 2 and 5 when it spans less than two decades) and minor
    ticks at 2 and 5 of each decade."""
    k0, k1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    dec = np.array([10.0 ** k for k in range(k0, k1 + 1)])
    sub = np.concatenate([dec * 2, dec * 5])
    inside = lambda v: v[(v >= lo * (1 - 1e-9)) & (v <= hi * (1 + 1e-9))]   # noqa: E731
    major = inside(dec)
    minor = inside(sub)
    if major.size < 3:
        major, minor = np.sort(np.concatenate([major, minor])), np.zeros(0)
    return major, np.sort(minor)


@dataclass
class _Layer:
    kind: str                      # line | band | vspan | hline | vline | rect | text | errorbar
    x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y2: np.ndarray = field(default_factory=lambda: np.zeros(0))
    style: dict[str, Any] = field(default_factory=dict)
    label: str | None = None


@dataclass
class LegendEntry:
    """A legend handle: a patch (``color``, ``alpha``, ``hatch``, ``edgecolor``) or a line (``ls``, ``marker``)."""

    label: str
    color: str = "k"
    kind: str = "patch"            # patch | line
    alpha: float = 1.0
    ls: str = "-"
    lw: float = 1.5
    marker: str | None = None
    hatch: str | None = None
    edgecolor: str | None = None
    mfc: str | None = None         # marker face colour: "none" draws an open circle


class Axes:
    """One plot area; data is drawn when the figure is rendered (limits and ticks then known)."""

    def __init__(self, fig: Figure, x0: float, y0: float, w: float, h: float) -> None:
        self.fig, self.box = fig, (x0, y0, w, h)
        self.layers: list[_Layer] = []
        self.xscale = self.yscale = "linear"
        self.xlim: tuple[float, float] | None = None
        self.ylim: tuple[float, float] | None = None
        self.xticks: tuple[Sequence[float], Sequence[str], float] | None = None
        self.yticks: tuple[Sequence[float], Sequence[str]] | None = None
        self.title = self.xlabel = self.ylabel = ""
        self.label_pt = 10.0
        self.tick_pt = 9.0
        self.grid_axes = ""         # "", "x", "y", "xy"
        self.share: list[Axes] = [self]
        self.show_xticklabels = True
        self.legend_spec: dict[str, Any] | None = None

    # ---------------------------------------------------------------------------------------------- drawing
    def plot(self, x: Any, y: Any, color: str = "#1565c0", lw: float = 1.5, ls: str = "-", label: str | None = None,
             marker: str | None = None, ms: float = 4.0, alpha: float = 1.0, mfc: str | None = None,
             gid: str | None = None) -> None:
        """A line (``ls`` ``-``, ``--``, ``:`` or ``""`` for markers only) and/or circle markers; ``gid``: the SVG
        ``class`` of a group around what it draws (a reader can then find e.g. one order's markers)."""
        self.layers.append(_Layer("line", np.asarray(x, float).ravel(), np.asarray(y, float).ravel(),
                                  style=dict(color=color, lw=lw, ls=ls, marker=marker, ms=ms, alpha=alpha, mfc=mfc,
                                             gid=gid),
                                  label=label))

    def step(self, x: Any, y: Any, **kw: Any) -> None:
        """A line that holds each value until the next x (matplotlib's ``where="post"``)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        if x.size:
            x = np.concatenate([np.repeat(x, 2)[1:], x[-1:]])
            y = np.repeat(y, 2)
        self.plot(x, y, **kw)

    def fill_between(self, x: Any, lo: Any, hi: Any, color: str = "#1e88e5", alpha: float = 0.25,
                     label: str | None = None) -> None:
        """A band between two curves, broken where either is not finite."""
        self.layers.append(_Layer("band", np.asarray(x, float), np.asarray(lo, float), np.asarray(hi, float),
                                  style=dict(color=color, alpha=alpha), label=label))

    def axvspan(self, x0: float, x1: float, color: str = "0.85", alpha: float = 1.0, label: str | None = None) -> None:
        """A shaded vertical stripe over the whole height."""
        self.layers.append(_Layer("vspan", np.array([x0, x1], float), style=dict(color=color, alpha=alpha),
                                  label=label))

    def axvline(self, x: float, color: str = "0.4", ls: str = "-", lw: float = 1.0) -> None:
        self.layers.append(_Layer("vline", np.array([x], float), style=dict(color=color, ls=ls, lw=lw)))

    def axhline(self, y: float, color: str = "0.4", ls: str = "-", lw: float = 1.0) -> None:
        self.layers.append(_Layer("hline", y=np.array([y], float), style=dict(color=color, ls=ls, lw=lw)))

    def bar(self, x0: float, width: float, y0: float, height: float, color: str = "k", alpha: float = 1.0,
            facecolor: str | None = None, edgecolor: str | None = None, hatch: str | None = None) -> None:
        """A rectangle in data coordinates (matplotlib's ``broken_barh`` with one bar)."""
        self.layers.append(_Layer("rect", np.array([x0, x0 + width], float), np.array([y0, y0 + height], float),
                                  style=dict(color=facecolor if facecolor is not None else color, alpha=alpha,
                                             edgecolor=edgecolor, hatch=hatch)))

    def errorbar(self, x: float, y: float, yerr: float, color: str = "#1f77b4", ms: float = 4.0) -> None:
        """A point with a vertical +-``yerr`` bar and caps."""
        self.layers.append(_Layer("errorbar", np.array([x], float), np.array([y - yerr, y, y + yerr], float),
                                  style=dict(color=color, ms=ms)))

    def text(self, x: float, y: float, s: str, *, size: float = 7.0, color: str = "k", ha: str = "left",
             va: str = "baseline", xcoord: str = "data", ycoord: str = "data", dx: float = 0.0,
             dy: float = 0.0) -> None:
        """Text at ``(x, y)`` in data or axes-fraction coordinates, shifted by ``(dx, dy)`` points (dy up)."""
        self.layers.append(_Layer("text", np.array([x], float), np.array([y], float),
                                  style=dict(s=s, size=size, color=color, ha=ha, va=va, xcoord=xcoord,
                                             ycoord=ycoord, dx=dx, dy=dy)))

    # ---------------------------------------------------------------------------------------------- setup
    def set_xscale(self, s: str) -> None:
        for ax in self.share:
            ax.xscale = s

    def set_yscale(self, s: str) -> None:
        self.yscale = s

    def set_xlim(self, lo: float, hi: float) -> None:
        for ax in self.share:
            ax.xlim = (float(lo), float(hi))

    def set_ylim(self, lo: float, hi: float) -> None:
        self.ylim = (float(lo), float(hi))

    def set_yticks(self, ticks: Sequence[float], labels: Sequence[str] | None = None) -> None:
        self.yticks = (list(ticks), list(labels) if labels is not None else tick_labels(np.asarray(ticks, float)))

    def set_xticks(self, ticks: Sequence[float], labels: Sequence[str], rotation: float = 0.0) -> None:
        self.xticks = (list(ticks), list(labels), rotation)

    def set_title(self, s: str) -> None:
        self.title = s

    def set_xlabel(self, s: str) -> None:
        self.xlabel = s

    def set_ylabel(self, s: str, size: float | None = None) -> None:
        self.ylabel = s
        if size is not None:
            self.label_pt = size

    def grid(self, axis: str = "xy") -> None:
        self.grid_axes = axis

    def legend(self, entries: Sequence[LegendEntry] | None = None, loc: str = "best", size: float = 8.0) -> None:
        """A legend of ``entries`` (default: the labelled layers); ``loc`` ``best`` picks the emptiest corner,
        ``outside right`` puts it right of the axes."""
        self.legend_spec = dict(entries=entries, loc=loc, size=size)

    def legend_entries(self) -> list[LegendEntry]:
        """One entry per distinct label of the layers, in drawing order."""
        out: dict[str, LegendEntry] = {}
        for ly in self.layers:
            if ly.label and ly.label not in out:
                st = ly.style
                if ly.kind == "line":
                    out[ly.label] = LegendEntry(ly.label, st["color"], "line", st["alpha"], st["ls"], st["lw"],
                                                st["marker"])
                else:
                    out[ly.label] = LegendEntry(ly.label, st["color"], "patch", st.get("alpha", 1.0))
        return list(out.values())

    # ---------------------------------------------------------------------------------------------- render
    def _data_limits(self, which: str) -> tuple[float, float] | None:
        scale = self.xscale if which == "x" else self.yscale
        vals = []
        for ax in (self.share if which == "x" else [self]):
            for ly in ax.layers:
                if ly.kind == "text":
                    continue
                v = ly.x if which == "x" else np.concatenate([ly.y, ly.y2])
                if which == "y" and ly.kind in ("vspan", "vline"):
                    continue
                if which == "x" and ly.kind == "hline":
                    continue
                v = v[np.isfinite(v)]
                vals.append(v[v > 0] if scale == "log" else v)
        v = np.concatenate(vals) if vals else np.zeros(0)
        if v.size == 0:
            return None
        return float(v.min()), float(v.max())

    def _limits(self, which: str) -> tuple[float, float]:
        fixed = self.xlim if which == "x" else self.ylim
        if fixed is not None:
            return fixed
        scale = self.xscale if which == "x" else self.yscale
        lim = self._data_limits(which)
        if lim is None:
            return (1.0, 10.0) if scale == "log" else (0.0, 1.0)
        lo, hi = lim
        if scale == "log":
            a, b = math.log10(lo), math.log10(hi)
            m = 0.05 * (b - a) if b > a else 0.5
            return 10 ** (a - m), 10 ** (b + m)
        if hi <= lo:
            d = abs(lo) * 0.05 or 0.5
            return lo - d, hi + d
        m = 0.05 * (hi - lo)
        return lo - m, hi + m

    def render(self, out: list[str], clip_id: str) -> None:
        x0, y0, w, h = self.box
        xl, yl = self._limits("x"), self._limits("y")
        out.append(f'<clipPath id="{clip_id}"><rect x="{_f(x0)}" y="{_f(y0)}" width="{_f(w)}" height="{_f(h)}"/>'
                   "</clipPath>")
        self._render_grid_and_ticks(out, xl, yl)
        self._render_layers(out, clip_id, xl, yl)
        out.append(f'<rect x="{_f(x0)}" y="{_f(y0)}" width="{_f(w)}" height="{_f(h)}" fill="none" stroke="#444" '
                   'stroke-width="0.8"/>')
        fs = self.label_pt * PT
        if self.title:
            out.append(f'<text x="{_f(x0 + w / 2)}" y="{_f(y0 - 6)}" text-anchor="middle" '
                       f'font-size="{10 * PT:.1f}">{_esc(self.title)}</text>')
        if self.xlabel and self.show_xticklabels:
            ty = y0 + h + 12 + self.tick_pt * PT + fs
            out.append(f'<text x="{_f(x0 + w / 2)}" y="{_f(ty)}" text-anchor="middle" font-size="{fs:.1f}">'
                       f"{_esc(self.xlabel)}</text>")
        if self.ylabel:
            ylw = max((text_width(s, self.tick_pt) for s in self._ytick_text(yl)), default=0.0)
            xx, yy = x0 - ylw - 10 - 0.3 * fs, y0 + h / 2
            out.append(f'<text x="{_f(xx)}" y="{_f(yy)}" text-anchor="middle" font-size="{fs:.1f}" '
                       f'transform="rotate(-90 {_f(xx)} {_f(yy)})">{_esc(self.ylabel)}</text>')
        if self.legend_spec is not None:
            self._render_legend(out, xl, yl)

    def _map(self, v: np.ndarray, lim: tuple[float, float], which: str) -> np.ndarray:
        x0, y0, w, h = self.box
        log = (self.xscale if which == "x" else self.yscale) == "log"
        with np.errstate(divide="ignore", invalid="ignore"):
            vv = np.where(np.asarray(v, float) > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan) if log else \
                np.asarray(v, float)
            lo, hi = (math.log10(lim[0]), math.log10(lim[1])) if log else lim
            frac = (vv - lo) / (hi - lo) if hi != lo else np.full_like(vv, 0.5)
        return x0 + frac * w if which == "x" else y0 + h - frac * h

    def _ticks(self, which: str, lim: tuple[float, float]) -> tuple[np.ndarray, list[str], np.ndarray, float]:
        """Major ticks, their labels, minor ticks and the labels' rotation of one axis."""
        if which == "x" and self.xticks is not None:
            ticks, labels, rotation = self.xticks
            return np.asarray(ticks, float), list(labels), np.zeros(0), rotation
        if which != "x" and self.yticks is not None:
            ticks, labels = self.yticks
            return np.asarray(ticks, float), list(labels), np.zeros(0), 0.0
        if (self.xscale if which == "x" else self.yscale) == "log":
            major, minor = log_ticks(*lim)
            return major, [f"{v:g}" for v in major], minor, 0.0
        major = nice_ticks(*lim)
        return major, tick_labels(major), np.zeros(0), 0.0

    def _ytick_text(self, yl: tuple[float, float]) -> list[str]:
        return self._ticks("y", yl)[1]

    def _render_grid_and_ticks(self, out: list[str], xl: tuple[float, float], yl: tuple[float, float]) -> None:
        x0, y0, w, h = self.box
        fs = self.tick_pt * PT
        for which, lim in (("x", xl), ("y", yl)):
            major, labels, minor, rot = self._ticks(which, lim)
            lo, hi = (x0, x0 + w) if which == "x" else (y0, y0 + h)
            for vals, is_major in ((major, True), (minor, False)):
                pos = self._map(vals, lim, which)
                for p in pos[np.isfinite(pos) & (pos >= lo - 0.5) & (pos <= hi + 0.5)]:
                    tick = 4 if is_major else 2
                    grid: tuple[float, float, float, float] = \
                        (p, y0, p, y0 + h) if which == "x" else (x0, p, x0 + w, p)
                    mark: tuple[float, float, float, float] = \
                        (p, y0 + h, p, y0 + h + tick) if which == "x" else (x0 - tick, p, x0, p)
                    if which in self.grid_axes:
                        out.append(_line(*grid, 'stroke="#ccc" stroke-width="' + ("0.8" if is_major else "0.5") + '"'))
                    out.append(_line(*mark, 'stroke="#444" stroke-width="0.8"'))
            if which == "x" and not self.show_xticklabels:
                continue
            for p, lab in zip(self._map(major, lim, which), labels, strict=True):
                if not (math.isfinite(p) and lo - 0.5 <= p <= hi + 0.5):
                    continue
                if which == "y":
                    out.append(f'<text x="{_f(x0 - 6)}" y="{_f(p + 0.35 * fs)}" text-anchor="end" '
                               f'font-size="{fs:.1f}">{_esc(lab)}</text>')
                    continue
                ty = y0 + h + 6 + fs
                turn = f' transform="rotate({-rot:g} {_f(p)} {_f(ty)})"' if rot else ""
                out.append(f'<text x="{_f(p)}" y="{_f(ty)}" text-anchor="{"end" if rot else "middle"}" '
                           f'font-size="{fs:.1f}"{turn}>{_esc(lab)}</text>')

    def _render_layers(self, out: list[str], clip_id: str, xl: tuple[float, float], yl: tuple[float, float]) -> None:
        x0, y0, w, h = self.box
        body: list[str] = []
        texts: list[str] = []
        for ly in self.layers:
            st = ly.style
            if ly.kind == "text":
                texts.append(self._text_svg(ly, xl, yl))
            elif ly.kind == "vspan":
                a, b = sorted(self._map(ly.x, xl, "x"))
                if math.isfinite(a) and math.isfinite(b):
                    body.append(f'<rect x="{_f(a)}" y="{_f(y0)}" width="{_f(max(b - a, 0))}" height="{_f(h)}" '
                                f'{_fill(st["color"], st["alpha"])}/>')
            elif ly.kind in ("vline", "hline"):
                if ly.kind == "vline":
                    p = float(self._map(ly.x, xl, "x")[0])
                    seg = (p, y0, p, y0 + h)
                else:
                    p = float(self._map(ly.y, yl, "y")[0])
                    seg = (x0, p, x0 + w, p)
                if math.isfinite(p):
                    body.append(_line(*seg, _stroke(st["color"], st["lw"], st["ls"])))
            elif ly.kind == "rect":
                xa, xb = sorted(self._map(ly.x, xl, "x"))
                ya, yb = sorted(self._map(ly.y, yl, "y"))
                if all(math.isfinite(v) for v in (xa, xb, ya, yb)):
                    fill = "none" if st["color"] == "none" else None
                    hatch = self.fig.hatch_id(st["hatch"], st["edgecolor"] or "k") if st["hatch"] else None
                    body.append(f'<rect x="{_f(xa)}" y="{_f(ya)}" width="{_f(max(xb - xa, 0.5))}" '
                                f'height="{_f(yb - ya)}" '
                                + (f'fill="url(#{hatch})"' if hatch else
                                   ('fill="none"' if fill else _fill(st["color"], st["alpha"])))
                                + (f' stroke="{_color(st["edgecolor"])}" stroke-width="{PT:.2f}"'
                                   if st["edgecolor"] else "") + "/>")
            elif ly.kind == "band":
                body.extend(self._band_svg(ly, xl, yl))
            elif ly.kind == "line":
                drawn = self._line_svg(ly, xl, yl)
                gid = st.get("gid")
                body.extend([f'<g class="{_esc(gid)}">', *drawn, "</g>"] if gid else drawn)
            elif ly.kind == "errorbar":
                px = float(self._map(ly.x, xl, "x")[0])
                lo, mid, hi = self._map(ly.y, yl, "y")
                c, r = _color(st["color"]), st["ms"] * PT / 2
                body.append(f'<path d="M{_f(px)},{_f(lo)}V{_f(hi)}M{_f(px - 3)},{_f(lo)}H{_f(px + 3)}'
                            f'M{_f(px - 3)},{_f(hi)}H{_f(px + 3)}" stroke="{c}" stroke-width="1.2" fill="none"/>'
                            f'<circle cx="{_f(px)}" cy="{_f(mid)}" r="{r:.1f}" fill="{c}"/>')
        if body:
            out.append(f'<g clip-path="url(#{clip_id})">' + "".join(body) + "</g>")
        out.extend(texts)

    def _text_svg(self, ly: _Layer, xl: tuple[float, float], yl: tuple[float, float]) -> str:
        st = ly.style
        x0, y0, w, h = self.box
        px = x0 + float(ly.x[0]) * w if st["xcoord"] == "axes" else float(self._map(ly.x, xl, "x")[0])
        py = y0 + h - float(ly.y[0]) * h if st["ycoord"] == "axes" else float(self._map(ly.y, yl, "y")[0])
        fs = st["size"] * PT
        px += st["dx"] * PT
        py -= st["dy"] * PT
        py += {"top": 0.8 * fs, "center": 0.35 * fs, "bottom": -0.2 * fs}.get(st["va"], 0.0)
        anchor = {"left": "start", "center": "middle", "right": "end"}[st["ha"]]
        return (f'<text x="{_f(px)}" y="{_f(py)}" text-anchor="{anchor}" font-size="{fs:.1f}" '
                f'fill="{_color(st["color"])}">{_esc(st["s"])}</text>')

    def _line_svg(self, ly: _Layer, xl: tuple[float, float], yl: tuple[float, float]) -> list[str]:
        st = ly.style
        px, py = self._map(ly.x, xl, "x"), self._map(ly.y, yl, "y")
        ok = np.isfinite(px) & np.isfinite(py)
        out = []
        if st["ls"]:
            d = _polyline(px, py, ok, self.box[2])
            if d:
                out.append(f'<path d="{d}" fill="none" {_stroke(st["color"], st["lw"], st["ls"], st["alpha"])}/>')
        if st["marker"] == "o":
            r = st["ms"] * PT / 2
            fill = "none" if st["mfc"] == "none" else _color(st["color"])
            c = _color(st["color"])
            op = f' opacity="{st["alpha"]:.2f}"' if st["alpha"] < 1 else ""
            out.append(f'<g fill="{fill}" stroke="{c}" stroke-width="1"{op}>' + "".join(
                f'<circle cx="{_f(a)}" cy="{_f(b)}" r="{r:.1f}"/>' for a, b in zip(px[ok], py[ok], strict=True))
                + "</g>")
        elif st["marker"] == "v":
            s = st["ms"] * PT / 2
            out.append("".join(f'<path d="M{_f(a - s)},{_f(b - s)}H{_f(a + s)}L{_f(a)},{_f(b + s)}Z" '
                               f'fill="{_color(st["color"])}"/>' for a, b in zip(px[ok], py[ok], strict=True)))
        return out

    def _band_svg(self, ly: _Layer, xl: tuple[float, float], yl: tuple[float, float]) -> list[str]:
        px = self._map(ly.x, xl, "x")
        lo, hi = self._map(ly.y, yl, "y"), self._map(ly.y2, yl, "y")
        ok = np.isfinite(px) & np.isfinite(lo) & np.isfinite(hi)
        parts = []
        for a, b in _runs(ok):
            xs, ls_, hs = _decimate_band(px[a:b], lo[a:b], hi[a:b], self.box[2])
            pts = _points(xs, hs) + _points(xs[::-1], ls_[::-1])
            parts.append("M" + "L".join(pts) + "Z")
        if not parts:
            return []
        return [f'<path d="{"".join(parts)}" {_fill(ly.style["color"], ly.style["alpha"])}/>']

    def _render_legend(self, out: list[str], xl: tuple[float, float], yl: tuple[float, float]) -> None:
        spec = self.legend_spec or {}
        entries = list(spec["entries"]) if spec.get("entries") is not None else self.legend_entries()
        if not entries:
            return
        size = spec["size"]
        row = size * PT * 1.5
        lw_ = 28.0 + max(text_width(e.label, size) for e in entries) + 10
        lh = row * len(entries) + 6
        x0, y0, w, h = self.box
        if spec["loc"] == "outside right":
            bx, by = x0 + w + 8, y0
        else:
            corners = {"upper right": (x0 + w - lw_ - 6, y0 + 6), "upper left": (x0 + 6, y0 + 6),
                       "lower left": (x0 + 6, y0 + h - lh - 6), "lower right": (x0 + w - lw_ - 6, y0 + h - lh - 6)}
            if spec["loc"] in corners:
                bx, by = corners[spec["loc"]]
            else:
                bx, by = min(corners.values(), key=lambda c: self._points_inside(c, lw_, lh, xl, yl))
            out.append(f'<rect x="{_f(bx)}" y="{_f(by)}" width="{_f(lw_)}" height="{_f(lh)}" fill="#fff" '
                       'fill-opacity="0.85" stroke="#ccc"/>')
        for j, e in enumerate(entries):
            cy = by + 3 + row * (j + 0.5)
            out.append(legend_handle(self.fig, e, bx + 4, cy))
            out.append(f'<text x="{_f(bx + 30)}" y="{_f(cy + 0.35 * size * PT)}" font-size="{size * PT:.1f}">'
                       f"{_esc(e.label)}</text>")

    def _points_inside(self, corner: tuple[float, float], w: float, h: float, xl: tuple[float, float],
                       yl: tuple[float, float]) -> int:
        n = 0
        for ly in self.layers:
            if ly.kind in ("line", "band"):
                px, py = self._map(ly.x, xl, "x"), self._map(ly.y, yl, "y")
                n += int(np.sum((px >= corner[0]) & (px <= corner[0] + w) & (py >= corner[1])
                                & (py <= corner[1] + h)))
        return n


class Figure:
    """A fixed-margin grid of :class:`Axes` (margins in inches, as the reports' previous matplotlib figures)."""

    def __init__(self, w_in: float, h_in: float, *, top_in: float = 0.45, bottom_in: float = 0.55,
                 left_in: float = 0.9, right_in: float = 0.25, hspace: float = 0.15, wspace: float = 0.25) -> None:
        self.w, self.h = w_in * PX_PER_IN, h_in * PX_PER_IN
        self.margins = (left_in * PX_PER_IN, right_in * PX_PER_IN, top_in * PX_PER_IN, bottom_in * PX_PER_IN)
        self.hspace, self.wspace = hspace, wspace
        self.axes: list[Axes] = []
        self.texts: list[str] = []
        self.legend_entries: list[LegendEntry] = []
        self._legend_size = 10.0
        self._hatches: dict[tuple[str, str], str] = {}

    def subplots(self, nrows: int = 1, ncols: int = 1, sharex: bool = False,
                 height_ratios: Sequence[float] | None = None) -> np.ndarray:
        """A ``(nrows, ncols)`` array of axes; ``sharex``: one x range, tick labels on the bottom row only;
        ``height_ratios``: relative row heights (default equal; the gap between rows is ``hspace`` of their mean)."""
        left, right, top, bottom = self.margins
        W, H = self.w - left - right, self.h - top - bottom
        aw = W / (ncols + self.wspace * (ncols - 1))
        ratios = np.ones(nrows) if height_ratios is None else np.asarray(height_ratios, float)
        if ratios.size != nrows or not np.all(ratios > 0):
            raise ValueError(f"height_ratios needs {nrows} positive values, got {list(ratios)}")
        ah = H / (nrows + self.hspace * (nrows - 1))        # mean row height
        heights = ah * nrows * ratios / ratios.sum()
        tops = top + np.concatenate([[0.0], np.cumsum(heights[:-1] + self.hspace * ah)])
        grid = np.empty((nrows, ncols), dtype=object)
        for i in range(nrows):
            for j in range(ncols):
                grid[i, j] = Axes(self, left + j * aw * (1 + self.wspace), float(tops[i]), aw, float(heights[i]))
                self.axes.append(grid[i, j])
        if sharex:
            for j in range(ncols):
                col = list(grid[:, j])
                for i, ax in enumerate(col):
                    ax.share = col
                    ax.show_xticklabels = i == nrows - 1
        return grid

    def suptitle(self, s: str, color: str = "#333", size: float = 10.0) -> None:
        self.texts.append(f'<text x="{_f(self.w / 2)}" y="{_f(18)}" text-anchor="middle" font-size="{size * PT:.1f}" '
                          f'fill="{_color(color)}">{_esc(s)}</text>')

    def text(self, xfrac: float, yfrac: float, s: str, size: float = 10.0) -> None:
        """Text centred at a fraction of the figure (``yfrac`` from the bottom)."""
        self.texts.append(f'<text x="{_f(xfrac * self.w)}" y="{_f((1 - yfrac) * self.h)}" text-anchor="middle" '
                          f'font-size="{size * PT:.1f}">{_esc(s)}</text>')

    def legend(self, entries: Sequence[LegendEntry], size: float = 10.0) -> None:
        """A one-row legend centred at the top of the figure."""
        self.legend_entries = list(entries)
        self._legend_size = size

    def hatch_id(self, hatch: str, color: str) -> str:
        key = (hatch, color)
        if key not in self._hatches:
            self._hatches[key] = f"hatch{len(self._hatches)}"
        return self._hatches[key]

    def svg(self, id_prefix: str = "f", standalone: bool = False) -> str:
        """The figure as an ``<svg>`` element for an HTML page (ids prefixed so that several figures share it), or
        ``standalone`` as an SVG file's content (with its XML namespace)."""
        body: list[str] = []
        for k, ax in enumerate(self.axes):
            ax.render(body, f"{id_prefix}c{k}")
        body.extend(self.texts)
        if self.legend_entries:
            size = self._legend_size
            widths = [36 + text_width(e.label, size) + 18 for e in self.legend_entries]
            x = (self.w - sum(widths)) / 2
            for e, wd in zip(self.legend_entries, widths, strict=True):
                body.append(legend_handle(self, e, x, 20))
                body.append(f'<text x="{_f(x + 34)}" y="{_f(20 + 0.35 * size * PT)}" font-size="{size * PT:.1f}">'
                            f"{_esc(e.label)}</text>")
                x += wd
        defs = "".join(_hatch_pattern(pid, h, c) for (h, c), pid in self._hatches.items())
        body = [b.replace('url(#hatch', f'url(#{id_prefix}hatch') for b in body]
        defs = defs.replace('id="hatch', f'id="{id_prefix}hatch')
        text = (f'<svg width="{self.w:.0f}" height="{self.h:.0f}" '
                f'viewBox="0 0 {self.w:.0f} {self.h:.0f}" font-family="{FONT}" fill="#222">'
                f'<rect width="100%" height="100%" fill="#fff"/>' + (f"<defs>{defs}</defs>" if defs else "")
                + "".join(body) + "</svg>")
        return as_file(text) if standalone else text


def as_file(svg: str) -> str:
    """An ``<svg>`` element for an HTML page (:meth:`Figure.svg`) as an SVG file's content: with its XML namespace."""
    return svg.replace("<svg ", '<svg xmlns="http://www.w3.org/2000/svg" ', 1)


def legend_handle(fig: Figure, e: LegendEntry, x: float, cy: float) -> str:
    """A legend handle 24 px wide starting at ``x``, centred on ``cy``."""
    if e.kind == "line":
        s = ""
        if e.ls:
            s += (f'<line x1="{_f(x)}" y1="{_f(cy)}" x2="{_f(x + 24)}" y2="{_f(cy)}" '
                  f'{_stroke(e.color, e.lw, e.ls, e.alpha)}/>')
        if e.marker == "o":
            fill = "none" if e.mfc == "none" else _color(e.color)
            s += f'<circle cx="{_f(x + 12)}" cy="{_f(cy)}" r="3" fill="{fill}" stroke="{_color(e.color)}"/>'
        return s
    fill = f'fill="url(#{fig.hatch_id(e.hatch, e.edgecolor or "k")})"' if e.hatch else _fill(e.color, e.alpha)
    stroke = f' stroke="{_color(e.edgecolor)}"' if e.edgecolor else ""
    return f'<rect x="{_f(x)}" y="{_f(cy - 5)}" width="24" height="10" {fill}{stroke}/>'


def _line(xa: float, ya: float, xb: float, yb: float, attrs: str) -> str:
    return f'<line x1="{_f(xa)}" y1="{_f(ya)}" x2="{_f(xb)}" y2="{_f(yb)}" {attrs}/>'


#: matplotlib's one-letter colours (not SVG colours: a browser ignores ``stroke="k"`` and draws nothing)
_LETTERS = {"b": "#0000ff", "g": "#008000", "r": "#ff0000", "c": "#00bfbf", "m": "#bf00bf", "y": "#bfbf00",
            "k": "#000000", "w": "#ffffff"}


def _color(c: str | None) -> str:
    """matplotlib one-letter colours and grey strings ("0.85") as hex; everything else as is."""
    if c is None:
        return "none"
    if c in _LETTERS:
        return _LETTERS[c]
    try:
        g = float(c)
    except ValueError:
        return c
    v = int(round(255 * min(max(g, 0.0), 1.0)))
    return f"#{v:02x}{v:02x}{v:02x}"


def _fill(color: str, alpha: float) -> str:
    return f'fill="{_color(color)}"' + (f' fill-opacity="{alpha:.2f}"' if alpha < 1 else "")


def _stroke(color: str, lw: float, ls: str, alpha: float = 1.0) -> str:
    s = f'stroke="{_color(color)}" stroke-width="{lw * PT:.2f}"'
    dash = DASHES.get(ls)
    if dash:
        s += f' stroke-dasharray="{dash[0] * lw * PT:.1f},{dash[1] * lw * PT:.1f}"'
    if alpha < 1:
        s += f' stroke-opacity="{alpha:.2f}"'
    return s + ' stroke-linejoin="round"'


def _hatch_pattern(pid: str, hatch: str, color: str) -> str:
    return (f'<pattern id="{pid}" patternUnits="userSpaceOnUse" width="6" height="6">'
            f'<path d="M-1,1L1,-1M0,6L6,0M5,7L7,5" stroke="{_color(color)}" stroke-width="1"/></pattern>')


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of True."""
    d = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _decimate(px: np.ndarray, py: np.ndarray, width_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel column: first, min, max and last point, in order (the drawn line looks the same)."""
    if px.size <= 4 * max(width_px, 1.0):
        return px, py
    col = np.floor(px).astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], col[1:] != col[:-1]]))
    stops = np.concatenate([starts[1:], [px.size]])
    keep = np.zeros(px.size, bool)
    keep[starts] = keep[stops - 1] = True
    ymin_idx = np.minimum.reduceat(np.where(np.isfinite(py), py, np.inf), starts)
    ymax_idx = np.maximum.reduceat(np.where(np.isfinite(py), py, -np.inf), starts)
    seg = np.repeat(np.arange(starts.size), stops - starts)
    keep |= (py == ymin_idx[seg]) | (py == ymax_idx[seg])
    return px[keep], py[keep]


def _decimate_band(px: np.ndarray, lo: np.ndarray, hi: np.ndarray, width_px: float) -> tuple[np.ndarray, ...]:
    """A band with more points than pixel columns: per column, the lowest lower and the highest upper edge."""
    if px.size <= 4 * max(width_px, 1.0):
        return px, lo, hi
    col = np.floor(px).astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], col[1:] != col[:-1]]))
    return px[starts], np.maximum.reduceat(lo, starts), np.minimum.reduceat(hi, starts)


def _polyline(px: np.ndarray, py: np.ndarray, ok: np.ndarray, width_px: float) -> str:
    parts = []
    for a, b in _runs(ok):
        xs, ys = _decimate(px[a:b], py[a:b], width_px)
        parts.append("M" + "L".join(_points(xs, ys)))
    return "".join(parts)
