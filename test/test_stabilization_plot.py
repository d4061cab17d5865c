"""The order-selection figure: drawn from the order scan's table, one marker per fitted mode, the chosen K marked."""

from __future__ import annotations

import numpy as np
import pytest
from figure_checks import assert_figure_matches_table, order_markers, parse_svg, texts
from frf_cases import CONTROLLER, DELAY, FS, MODES, split_mode_window

from additive_rsrivc_ros.outputs.stabilization_plot import (
    STABLE_DAMPING,
    STABLE_FREQUENCY,
    from_mode_finding,
    stabilization_figure,
    stable_flags,
)
from additive_rsrivc_ros.outputs.svgplot import as_file


def _row(k: int, modes: list[tuple[float, float]], accepted: bool = False, val: float | None = 1.0,
         message: str = "", rigid: int = 0) -> dict:
    return {"K": k, "fit_error": val, "validation_error": val, "accepted": accepted, "converged": True,
            "message": message, "redundant": False,
            "modes": [{"natural_frequency_hz": 0.0, "damping_ratio": 0.0, "gain": 1.0, "integrators": 2}] * rigid
            + [{"natural_frequency_hz": f, "damping_ratio": z, "gain": 1.0, "integrators": 0} for f, z in modes]}


def test_a_mode_is_stable_when_the_order_below_has_it_within_the_tolerances():
    f, z = 62.0, 0.02
    rows = [_row(1, [(f, z)]),
            _row(2, [(f * (1 + 0.5 * STABLE_FREQUENCY), z * (1 - 0.5 * STABLE_DAMPING)), (71.0, 0.01)]),
            _row(3, [(f * (1 + 2.0 * STABLE_FREQUENCY), z), (71.0, z * (1 + 2.0 * STABLE_DAMPING)), (240.0, 0.02)])]
    assert stable_flags(rows) == {1: [False], 2: [True, False], 3: [False, False, False]}


def test_the_figure_draws_each_orders_modes_and_marks_the_chosen_order():
    rows = [_row(1, [(66.0, 0.08)], val=3e-3), _row(2, [(62.0, 0.02), (71.0, 0.015)], accepted=True, val=1e-3),
            _row(3, [(62.0, 0.02), (71.0, 0.015), (300.0, 0.4)], val=0.99e-3, rigid=1),
            _row(4, [], val=None, message="not tried (2 orders in a row without gain)")]
    svg = as_file(stabilization_figure(rows, peaks_hz=[62.5, 70.0], rate_hz=1000.0).svg("o"))
    root = parse_svg(svg)
    assert assert_figure_matches_table(root, rows) == 2
    assert order_markers(root)[3] == {"circles": 3, "triangles": 1, "chosen": 0}
    words = " ".join(texts(root))
    assert "not tried" in words and "K = 2 chosen by held-out output error" in words
    assert "held-out MSE 0.00099 (-1.0 %), no significant gain" in words     # K = 3 against K = 2
    # the check itself can fail: a table that says K = 3 was chosen does not match this figure
    other = [dict(r, accepted=r["K"] == 3) for r in rows]
    with pytest.raises(AssertionError):
        assert_figure_matches_table(root, other)


def test_figure_of_a_real_order_scan_matches_its_table():
    """The order scan on a closed-loop record of the two-mode plant: the figure's markers are the table's fits."""
    from additive_rsrivc_ros.core.identification.modefind import find_modes

    r, u, y = split_mode_window()
    res = find_modes(u, y, FS, r=r, controller=CONTROLLER, input_delay=DELAY)
    rows = [row.to_dict() for row in res.table]
    assert res.K == len(MODES)
    for row in rows:    # each fitted order carries its K submodels
        assert len(row["modes"]) in (0, row["K"])
    root = parse_svg(as_file(from_mode_finding(res, DELAY).svg("o")))
    assert assert_figure_matches_table(root, rows) == res.K
    found = sorted(m["natural_frequency_hz"] for m in next(r for r in rows if r["accepted"])["modes"])
    assert np.allclose(found, [m.natural_frequency_hz for m in MODES], rtol=0.02)
