"""Stationarity of an offline record (core/identification/stationarity.py, rsrivc_identify): the statistics on
segment estimates of
known spread, and real rosbag2 records of the close-pair loop (62 / 71 Hz) with a change part-way, without one, with a
gain-only change, a short glitch, and too short to split."""

from __future__ import annotations

import json

import numpy as np
import pytest

from additive_rsrivc_ros.cli import identify
from additive_rsrivc_ros.core.identification.offline.types import IdentificationResult
from additive_rsrivc_ros.core.identification.stationarity import ALPHA, identify_segments, split_pairs, z_threshold
from additive_rsrivc_ros.core.model import SubmodelStructure, theta_from_modal
from additive_rsrivc_ros.io.bagio import write_bag
from additive_rsrivc_ros.sim.experiments import CLOSE_PAIR_MODES, close_pair_params_yaml, close_pair_record
from additive_rsrivc_ros.sim.simulate import ModalChange

RATE = 2000.0          # the close-pair loop at 2 kHz: half the cost of 4 kHz, the same statistics
TRUE = np.array([m.modal for m in CLOSE_PAIR_MODES])
STRUCT = [SubmodelStructure()] * 3
NO_RELEVANCE = (1e-12, 1e-12, 1e-12)
FAKE_RATE = 1000.0     # the fake segment fits: 120 000 samples are 120 s


def _result(modal: np.ndarray, std: np.ndarray) -> IdentificationResult:
    thetas = [theta_from_modal(*m) for m in modal]
    k = len(thetas)
    return IdentificationResult("additive-clsrivc", STRUCT[:k], thetas, [np.eye(3)] * k, np.eye(3 * k), np.eye(3 * k),
                                [np.eye(3)] * k, 1.0, 3, True, 1.0, 1.0, np.asarray(modal, float),
                                np.asarray(std, float))


def _fake_fit(rng: np.random.Generator, rel_std: float, shift=None):
    """Segment fits: the truth plus normal errors of the std they report (``shift(a, b)``: a change of the truth)."""
    def fit(a, b, warm, start):
        truth = TRUE * (1.0 + (0.0 if shift is None else shift(a, b)))
        std = np.abs(truth) * rel_std
        return _result(truth + std * rng.standard_normal(truth.shape), std)
    return fit


def test_stationary_records_are_called_stationary_at_most_alpha_of_the_time():
    """2000 stationary records of 6 segments whose estimates scatter by exactly their std: the Bonferroni rule calls
    at most ALPHA of them non-stationary (binomial 99.9 % bound); it is not a vacuous rule either (above ALPHA/4)."""
    rng = np.random.default_rng(5)
    runs, false = 2000, 0
    for _ in range(runs):
        st, part, _ = identify_segments(_fake_fit(rng, 1e-3), 120_000, FAKE_RATE,
                                        [theta_from_modal(*m) for m in TRUE], STRUCT, NO_RELEVANCE)
        false += st.stationary is False
    bound = ALPHA * runs + 3.1 * np.sqrt(ALPHA * runs)
    assert ALPHA / 4 * runs <= false <= bound, false


def test_a_change_is_found_with_its_size_where_it_happened():
    rng = np.random.default_rng(6)
    step = np.zeros((3, 3))
    step[2, 0] = -0.03

    def shift(a, b):
        return step if a >= 60_000 else 0.0

    st, part, _ = identify_segments(_fake_fit(rng, 1e-4, shift), 120_000, FAKE_RATE,
                                    [theta_from_modal(*m) for m in TRUE], STRUCT, (0.02, 0.2, 0.1))
    assert st.stationary is False and [(c.mode, c.quantity) for c in st.changes] == [(3, "natural_frequency")]
    c = st.changes[0]
    assert c.at_s == 60.0 and abs(c.relative_change + 0.03) < 5 * 1.5e-4
    assert [(p.start_s, p.end_s) for p in st.runs] == [(0.0, 60.0), (60.0, 120.0)]
    assert part is st.runs[1]       # equally long parts: the later one, the plant as it is now


def test_parts_that_cannot_be_fitted_are_never_reported_as_the_result():
    """The segments differ, but the parts' own fits fail (e.g. a start the loop of a part does not stabilize)."""
    rng = np.random.default_rng(8)
    step = np.zeros((3, 3))
    step[2, 0] = -0.03
    good = _fake_fit(rng, 1e-4, lambda a, b: step if a >= 60_000 else 0.0)

    def fit(a, b, warm, start):
        return good(a, b, warm, start) if b - a <= 20_000 else None     # segments only

    st, part, _ = identify_segments(fit, 120_000, FAKE_RATE, [theta_from_modal(*m) for m in TRUE], STRUCT,
                                    (0.02, 0.2, 0.1))
    assert st.stationary is False and part is None and st.chosen == -1
    assert "no stationary part could be fitted" in st.message and st.to_dict()["result_part"] is None


def test_an_irrelevant_but_significant_difference_is_no_change():
    """1 % of frequency is hundreds of sigma here, but below faults.min_change.natural_frequency (2 %)."""
    rng = np.random.default_rng(7)
    step = np.zeros((3, 3))
    step[2, 0] = -0.01
    st, _, _ = identify_segments(_fake_fit(rng, 1e-5, lambda a, b: step if a >= 60_000 else 0.0), 120_000, FAKE_RATE,
                                 [theta_from_modal(*m) for m in TRUE], STRUCT, (0.02, 0.2, 0.1))
    assert st.stationary is True


def test_too_short_is_not_tested():
    st, part, start = identify_segments(_fake_fit(np.random.default_rng(1), 1e-3), 30_000, FAKE_RATE,
                                        [theta_from_modal(*m) for m in TRUE], STRUCT, NO_RELEVANCE)
    assert st.stationary is None and "record too short" in st.message and part is None
    assert z_threshold(1) == pytest.approx(2.5758, abs=1e-3)


def test_split_pairs_are_opposite_gains_within_the_bandwidth():
    split = _result(np.array([[8.0, 0.05, 1.0], [69.35, 0.041, -5.56], [69.36, 0.041, 5.64]]), np.full((3, 3), 1e-3))
    assert split_pairs(split) == [(2, 3)]
    pair = _result(np.array([[8.0, 0.05, 1.0], [62.0, 0.02, -0.1], [71.0, 0.02, 0.08]]), np.full((3, 3), 1e-3))
    assert split_pairs(pair) == []     # a real close pair: 9 Hz apart, bandwidths 1.2 + 1.4 Hz


# ------------------------------------------------------------------------------------- real records, rsrivc_identify
GUESSES = ("    modes:\n      natural_frequency_hz: [8.2, 61.0, 72.0]\n      damping_ratio: [0.06, 0.025, 0.025]\n"
           "      gain: [0.9, 0.11, 0.07]\n      memory_s: [5.0, 5.0, 5.0]\n")


def _bag(tmp_path, seed, duration, changes=(), glitch=None, guesses=False):
    sim = close_pair_record(seed, duration, tuple(changes), rate_hz=RATE)
    y = sim.y.copy()
    if glitch is not None:      # (start_s, length_s, size): an output step the controller also sees no more of
        a, n = int(glitch[0] * RATE), int(glitch[1] * RATE)
        y[a:a + n] += glitch[2]
    bag = write_bag(tmp_path / f"bag{seed}", RATE, sim.u, y, sim.r, truth_modal=sim.modal)
    params = tmp_path / "params.yaml"
    text = close_pair_params_yaml(rate_hz=RATE)
    params.write_text(text.replace("    modes:\n      memory_s: [5.0]\n", GUESSES) if guesses else text)
    return str(bag), str(params)


def _identify(bag, params, out, *extra, modes="auto"):
    """``modes`` None: from the params file's guesses (no mode finding)."""
    argv = [bag, "--params-file", params, "--out", str(out), *extra] + ([] if modes is None else ["--modes", modes])
    assert identify.main(argv) == 0
    return json.loads(out.read_text())


def _within(doc, mode, truth, n_std=5.0):
    m = doc["modes"][mode - 1]
    return abs(m["natural_frequency_hz"] - truth) < n_std * m["natural_frequency_hz_std"] + 1e-4 * truth


@pytest.fixture(scope="module")
def changed(tmp_path_factory):
    """120 s at 1 kHz, mode 3 at 71 Hz, then 3 % lower from 60 s on."""
    return _bag(tmp_path_factory.mktemp("changed"), 3, 120.0, [ModalChange(2, "frequency", -0.03, 60.0)])


def test_a_changed_record_is_split_where_it_changed_and_never_fitted_as_a_split_mode(changed, tmp_path, capsys):
    doc = _identify(*changed, tmp_path / "whole.json")
    out = capsys.readouterr().out.splitlines()
    assert doc["stationary"] is False and len(doc["modes"]) == 3 and "split_modes" not in doc
    assert sum("NOT stationary" in line for line in out) == 1
    ch = doc["stationarity"]["changes"]
    assert [(c["mode"], c["quantity"]) for c in ch] == [(3, "natural_frequency")]
    assert ch[0]["at_s"] == 60.0
    assert abs(ch[0]["relative_change"] + 0.03) < 5 * np.hypot(ch[0]["before_std"], ch[0]["after_std"]) / 71.0
    assert doc["fitted_s"] == pytest.approx([60.0, 120.0]) and _within(doc, 3, 71.0 * 0.97)
    assert all(m["gain"] > 0 for m in doc["modes"])


def test_the_range_picks_either_part_in_the_records_time(changed, tmp_path):
    """K given: on 55 s after the change (the pair 62 / 68.9 Hz) the order scan picks K = 2 at this rate."""
    before = _identify(*changed, tmp_path / "before.json", "--end", "55", modes="3")
    after = _identify(*changed, tmp_path / "after.json", "--start", "65", modes="3")
    assert _within(before, 3, 71.0) and _within(after, 3, 71.0 * 0.97)
    assert before["time_range"]["end_s"] == 55.0 and after["time_range"]["start_s"] == 65.0
    assert after["screening"]["segment_s"][0] == pytest.approx(65.0)   # times are the record's
    assert before["stationary"] is True and after["stationary"] is True
    assert after["fitted_s"] == pytest.approx([65.0, 120.0])
    short = _identify(*changed, tmp_path / "short.json", "--start", "80", "--end", "115", modes="3")
    assert short["stationary"] is None and "record too short" in short["stationarity"]["message"]


@pytest.mark.parametrize("seed", [11, 12])
def test_a_stationary_record_is_called_stationary(tmp_path, seed):
    """From the params file's guesses (a few % off); the changed record above found its modes."""
    doc = _identify(*_bag(tmp_path, seed, 120.0, guesses=True), tmp_path / "id.json", modes=None)
    assert doc["stationary"] is True, doc["stationarity"]["message"]
    assert doc["fitted_s"] == pytest.approx([0.0, 120.0]) and doc["converged"]
    assert all(_within(doc, i + 1, m.natural_frequency_hz) for i, m in enumerate(CLOSE_PAIR_MODES))


def test_a_gain_only_change_is_found_as_a_gain_change(tmp_path):
    doc = _identify(*_bag(tmp_path, 21, 120.0, [ModalChange(1, "gain", -0.25, 60.0)], guesses=True),
                    tmp_path / "id.json", modes=None)
    assert doc["stationary"] is False
    ch = doc["stationarity"]["changes"]
    assert (2, "gain") in [(c["mode"], c["quantity"]) for c in ch]
    assert not any(c["quantity"] == "natural_frequency" for c in ch)
    g = next(c for c in ch if c["quantity"] == "gain")
    assert abs(g["relative_change"] + 0.25) < 5 * np.hypot(g["before_std"], g["after_std"]) / 0.1 + 0.01


def test_a_short_glitch_is_no_change_of_the_plant(tmp_path):
    """Half a second of output offset (a sensor glitch the loop reacts to) inside one segment: the segment's estimate
    moves, but not by a relevant change: the record is still stationary."""
    doc = _identify(*_bag(tmp_path, 31, 120.0, glitch=(70.0, 0.5, 0.05), guesses=True), tmp_path / "id.json",
                    modes=None)
    assert doc["stationary"] is True, doc["stationarity"]["message"]
