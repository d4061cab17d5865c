"""The shared vocabulary (core/vocabulary.py) and the estimator seam (core/estimator.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from additive_rsrivc_ros.core.estimator import EstimatorHealth, RecursiveEstimator
from additive_rsrivc_ros.core.faults import FaultEvent, HealthMonitor, Level
from additive_rsrivc_ros.core.model import SubmodelStructure
from additive_rsrivc_ros.core.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.core.vocabulary import (
    EVENTS_HEADER,
    LEVEL_NAMES,
    QUANTITIES,
    SIM_QUANTITIES,
    events_csv_cells,
    json_clean,
    num,
    one_line,
    quantity_of,
    sim_quantity_of,
)

# the keys of health["estimator"] in reports and summary.json (file format: must not change)
ESTIMATOR_HEALTH_KEYS = (
    "samples", "updates", "skipped_samples", "held_samples", "hold_remaining", "reprimes", "capped_updates",
    "projections", "rejected_updates", "rejected_discretization", "rejected_iv_denominator",
    "rejected_nonfinite_or_step", "nonfinite_instrument", "cond", "covariance_problems", "information_relative_std",
    "residual_var", "init_message")


def test_level_names_are_the_diagnostic_levels() -> None:
    assert LEVEL_NAMES == tuple(Level(k).name for k in range(len(LEVEL_NAMES)))


def test_simulator_quantities_translate_both_ways() -> None:
    assert [quantity_of(q) for q in SIM_QUANTITIES] == list(QUANTITIES)
    assert [sim_quantity_of(quantity_of(q)) for q in SIM_QUANTITIES] == list(SIM_QUANTITIES)
    with pytest.raises(ValueError):
        quantity_of("natural_frequency")          # not a simulator name: no silent pass-through


def test_num_is_lossless_and_names_non_finite_values() -> None:
    for x in (0.1 + 0.2, 1e-300, -3.25e17, 33.0):
        assert float(num(x)) == x
    assert [num(v) for v in (math.nan, math.inf, -math.inf, np.float32(0.5))] == ["nan", "inf", "-inf", "0.5"]


def test_events_row_matches_the_header_open_and_closed() -> None:
    ev = FaultEvent(2, "natural_frequency", "down", 20.0, 22.5, 33.1, 31.4)
    cells = events_csv_cells(ev.csv_row())
    assert tuple(ev.csv_row()) == EVENTS_HEADER and len(cells) == len(EVENTS_HEADER)
    assert cells[1] == "" and cells[:1] == ["20.0"] and cells[2:5] == [2, "natural_frequency", "down"]
    ev.clear_time_s = 0.1 + 0.2
    assert float(events_csv_cells(ev.csv_row())[1]) == 0.1 + 0.2


def test_one_line_takes_the_first_line_or_the_type() -> None:
    assert one_line(ValueError("  first\nsecond  ")) == "first"
    assert one_line(KeyError()) == "KeyError"
    assert one_line(OSError("x" * 500), 300) == "x" * 300


def test_json_clean_gives_strict_json() -> None:
    doc = json_clean({1: (np.float64(np.nan), np.int64(3)), "a": np.array([1.0, np.inf]), "p": Path("/tmp/x"),
                      "b": [np.bool_(True), -math.inf, "s"]})
    assert json.loads(json.dumps(doc, allow_nan=False)) == {"1": [None, 3], "a": [1.0, None], "p": "/tmp/x",
                                                            "b": [True, None, "s"]}


def test_estimator_implements_the_protocol_and_reports_the_documented_keys() -> None:
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 2, [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.04, 0.5])],
                                 20.0, forgetting=0.99, controller=None)
    rng = np.random.default_rng(0)
    u = rng.standard_normal(200)
    est.update(None, u, 0.1 * u)
    assert isinstance(est, RecursiveEstimator)
    h = est.health
    assert isinstance(h, EstimatorHealth) and h.samples == 200 and len(h.cond) == len(h.projections) == 2
    d = h.to_dict()
    assert tuple(d) == ESTIMATOR_HEALTH_KEYS and isinstance(d["cond"], list)
    json.dumps(json_clean(d), allow_nan=False)


@pytest.mark.filterwarnings("ignore:All-NaN slice")
def test_health_monitor_skips_unreported_items_but_flags_a_nan_condition() -> None:
    modal = np.array([[3.2, 0.1, 11.8, 0.01, 0.005, 0.1]])
    assert HealthMonitor([1.0]).assess(0.0, modal, EstimatorHealth()).ok       # nothing reported: nothing judged
    st = HealthMonitor([1.0]).assess(0.0, modal, EstimatorHealth(cond=(math.nan,)))
    assert st.hold and "IV condition" in st.reasons[0]                         # unknown conditioning is not "fine"
