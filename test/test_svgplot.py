"""The report's SVG plotter (additive_rsrivc_ros.outputs.svgplot): ticks, the data-to-pixel map, broken and decimated
lines.

A figure that draws a value somewhere else than where it is, hides a spike, or joins across a gap is a wrong
picture of right numbers; these tests read the SVG back and invert the axes' map.
"""

from __future__ import annotations

import math
import re
from xml.etree import ElementTree

import numpy as np
import pytest

from additive_rsrivc_ros.outputs import svgplot as sp

NS = "{http://www.w3.org/2000/svg}"


def _paths(svg: str) -> list[list[np.ndarray]]:
    """The ``d`` of every stroked, unfilled path as a list of subpaths (N, 2) (only M/L commands)."""
    root = ElementTree.fromstring(svg)
    out = []
    for p in root.iter(f"{NS}path"):
        if p.get("fill") != "none" or p.get("stroke") is None:
            continue
        subs = []
        for sub in re.findall(r"M[^M]*", p.get("d", "")):
            pts = [tuple(map(float, xy.split(","))) for xy in re.split(r"[ML]", sub) if xy]
            subs.append(np.array(pts))
        out.append(subs)
    return out


def _axes_map(ax: sp.Axes) -> tuple:
    (x0, y0, w, h), (xl, yl) = ax.box, (ax._limits("x"), ax._limits("y"))
    return x0, y0, w, h, xl, yl


@pytest.mark.parametrize("lo,hi", [(0.0, 1.0), (0.2346, 0.2349), (3.2477, 3.2491), (-185.0, 185.0), (31.0, 33.2),
                                   (1e-7, 3e-7), (-0.3, 2.3), (0.0, 59.99), (12345.0, 12399.0), (-4e6, 9e6)])
def test_ticks_are_round_inside_and_labelled_exactly(lo: float, hi: float) -> None:
    t = sp.nice_ticks(lo, hi)
    assert 2 <= t.size <= 6, t
    assert t.min() >= lo - 1e-9 * abs(hi - lo) and t.max() <= hi + 1e-9 * abs(hi - lo)
    step = np.diff(t)
    assert np.allclose(step, step[0], rtol=1e-9)
    mant = step[0] / 10.0 ** math.floor(math.log10(step[0]) + 1e-9)
    assert min(abs(mant - m) for m in (1.0, 2.0, 2.5, 5.0)) < 1e-6, mant
    labels = sp.tick_labels(t)
    assert len(set(labels)) == t.size, labels                        # distinct: enough digits
    back = np.array([float(s) for s in labels])
    assert np.allclose(back, t, rtol=1e-3, atol=step[0] * 1e-6), (labels, t)
    assert not any(s.startswith("-0") and float(s) == 0 for s in labels)


def test_log_ticks_are_decades_and_a_short_span_gets_labels() -> None:
    major, minor = sp.log_ticks(0.7, 2000.0)
    assert list(major) == [1.0, 10.0, 100.0, 1000.0] and set(minor) >= {2.0, 5.0, 20.0, 500.0}
    major, _ = sp.log_ticks(30.0, 150.0)                             # less than two decades: 50, 100 labelled
    assert 50.0 in major and 100.0 in major


def test_a_line_is_drawn_where_its_values_are() -> None:
    fig = sp.Figure(6.0, 4.0)
    ax = fig.subplots()[0, 0]
    x = np.linspace(0.0, 10.0, 37)
    y = np.sin(x) * 3.0 + 1.0
    ax.plot(x, y)
    svg = fig.svg(standalone=True)
    (sub,), = _paths(svg)
    x0, y0, w, h, (xa, xb), (ya, yb) = _axes_map(ax)
    back_x = xa + (sub[:, 0] - x0) / w * (xb - xa)
    back_y = ya + (y0 + h - sub[:, 1]) / h * (yb - ya)
    px = (xb - xa) / w                                                 # one pixel in data units
    assert np.allclose(back_x, x, atol=0.06 * px) and np.allclose(back_y, y, atol=0.06 * (yb - ya) / h)


def test_points_are_written_as_single_coordinates_are() -> None:
    """The one-pass pair formatting of polylines and bands writes exactly what :func:`svgplot._f` writes: one
    decimal, clamped to +-1e5 px (the clip path hides the rest), -0.0 and ties as Python rounds them."""
    edge = [np.nan, -0.0, -0.04, 0.05, 0.15, 0.25, 2.675, 1e5, -1e5, 1e5 + 0.05, 3e7, -np.inf, np.inf]
    x = np.concatenate([np.random.default_rng(1).normal(0.0, 3e3, 2000), edge])
    y = x[::-1].copy()
    assert sp._points(x, y) == [f"{sp._f(a)},{sp._f(b)}" for a, b in zip(x, y, strict=True)]


def test_log_axis_places_decades_evenly_and_breaks_at_non_positive_values() -> None:
    fig = sp.Figure(6.0, 4.0)
    ax = fig.subplots()[0, 0]
    ax.set_yscale("log")
    ax.plot([0, 1, 2, 3, 4, 5], [1.0, 10.0, 100.0, 0.0, 1e3, 1e4])
    (subs,) = _paths(fig.svg(standalone=True))
    assert [len(s) for s in subs] == [3, 2]                          # 0 on a log axis: a gap, not a dive
    d = np.diff(np.concatenate(subs)[:, 1])
    assert np.allclose(d[[0, 1, 3]], d[0], atol=0.15)                # one decade = the same height


def test_non_finite_values_break_the_line_and_never_reach_the_svg() -> None:
    fig = sp.Figure(6.0, 4.0)
    ax = fig.subplots()[0, 0]
    y = np.arange(20.0)
    y[[5, 12, 13]] = [np.nan, np.inf, -np.inf]
    ax.plot(np.arange(20.0), y)
    ax.fill_between(np.arange(20.0), y - 1, y + 1)
    svg = fig.svg(standalone=True)
    assert "nan" not in svg.lower() and "inf" not in svg.lower()
    (subs,) = _paths(svg)
    assert [len(s) for s in subs] == [5, 6, 6]


def test_an_all_nan_or_empty_axes_still_renders() -> None:
    fig = sp.Figure(6.0, 4.0)
    a, b = fig.subplots(2, 1)[:, 0]
    a.plot(np.arange(5.0), np.full(5, np.nan))
    b.plot([], [])
    b.set_yscale("log")
    ElementTree.fromstring(fig.svg(standalone=True))


def test_decimation_keeps_every_spike_and_every_pixel_column_extreme() -> None:
    rng = np.random.default_rng(3)
    n = 200_000
    x = np.arange(n) / 4096.0
    y = rng.standard_normal(n) * 0.1
    y[123_457] = 5.0                                                  # one sample the eye must still see
    y[77_777] = -4.0
    fig = sp.Figure(6.0, 3.0)
    ax = fig.subplots()[0, 0]
    ax.plot(x, y)
    (subs,) = _paths(fig.svg(standalone=True))
    pts = np.concatenate(subs)
    assert pts.shape[0] <= 4 * ax.box[2] + 4                         # decimated to the pixel columns
    x0, y0, w, h, _, (ya, yb) = _axes_map(ax)
    back_y = ya + (y0 + h - pts[:, 1]) / h * (yb - ya)
    assert back_y.max() == pytest.approx(5.0, abs=0.05 * (yb - ya) / h * 10)
    assert back_y.min() == pytest.approx(-4.0, abs=0.05 * (yb - ya) / h * 10)


def test_a_decimated_band_covers_the_whole_envelope() -> None:
    n = 50_000
    x = np.linspace(0.0, 1.0, n)
    lo, hi = -np.ones(n), np.ones(n)
    hi[31_000], lo[9_000] = 3.0, -2.0
    fig = sp.Figure(6.0, 3.0)
    ax = fig.subplots()[0, 0]
    ax.fill_between(x, lo, hi)
    ax.set_ylim(-4.0, 4.0)
    svg = fig.svg(standalone=True)
    root = ElementTree.fromstring(svg)
    band = next(p for p in root.iter(f"{NS}path") if p.get("fill") not in (None, "none"))
    ys = np.array([float(v.split(",")[1]) for v in re.split(r"[MLZ]", band.get("d")) if v])
    x0, y0, w, h, _, (ya, yb) = _axes_map(ax)
    back = ya + (y0 + h - ys) / h * (yb - ya)
    assert back.max() == pytest.approx(3.0, abs=1e-3) and back.min() == pytest.approx(-2.0, abs=1e-3)


def test_best_legend_goes_to_the_empty_corner() -> None:
    fig = sp.Figure(6.0, 4.0)
    ax = fig.subplots()[0, 0]
    x = np.linspace(0.0, 1.0, 200)
    ax.plot(x, 1.0 - x, label="falling")                             # the line fills upper left and lower right
    ax.legend(loc="best")
    root = ElementTree.fromstring(fig.svg(standalone=True))
    box = next(r for r in root.iter(f"{NS}rect") if r.get("fill-opacity") == "0.85")
    x0, y0, w, h = ax.box
    cx, cy = float(box.get("x")) + float(box.get("width")) / 2, float(box.get("y")) + float(box.get("height")) / 2
    assert (cx > x0 + w / 2) == (cy < y0 + h / 2), (cx, cy)           # upper right or lower left


def test_text_is_escaped_and_ids_are_prefixed() -> None:
    figs = []
    for prefix in ("a", "b"):
        fig = sp.Figure(4.0, 3.0)
        ax = fig.subplots()[0, 0]
        ax.bar(0.0, 1.0, 0.0, 1.0, facecolor="none", edgecolor="#2e7d32", hatch="///")
        ax.set_title("<bag> & \"x\"")
        figs.append(fig.svg(prefix))
    page = "<div>" + "".join(figs) + "</div>"
    root = ElementTree.fromstring(page)                              # well-formed: the title was escaped
    ids = [e.get("id") for e in root.iter() if e.get("id")]
    assert len(ids) == len(set(ids)) == 4
    assert any(t.text == "<bag> & \"x\"" for t in root.iter("text"))
