"""outputs/report.py: model and nonparametric frequency responses against known systems; verdict; HTML page."""

from __future__ import annotations

import math
import re
from pathlib import Path
from types import SimpleNamespace
from xml.etree import ElementTree

import numpy as np
import pytest
from scipy import signal

from additive_rsrivc_ros.core.model import SubmodelStructure, frequency_response, theta_from_modal
from additive_rsrivc_ros.outputs import report as rp

RATE = 1000.0
H = 1.0 / RATE


def test_model_frf_zoh_exact_for_integrator() -> None:
    """ZOH{b0/p} = b0 h / (z - 1) exactly; a 3-sample delay multiplies by z^-3."""
    f = np.array([0.5, 5.0, 50.0, 400.0])
    z = np.exp(2j * np.pi * f * H)
    g = rp.model_frf([np.array([2.5])], [SubmodelStructure(n=0, m=0, integrators=1)], f, RATE, delay_samples=3)
    np.testing.assert_allclose(g, 2.5 * H / (z - 1) * z**-3, rtol=1e-10)


def test_model_frf_matches_continuous_below_nyquist() -> None:
    """For w h << 1 the ZOH response is G(jw) e^{-jw h/2} up to O((w h)^2) (two modes summed)."""
    th = [theta_from_modal(3.0, 0.2, 10.0), theta_from_modal(30.0, 0.02, 0.2)]
    st = [SubmodelStructure()] * 2
    f = np.logspace(-1, 1.3, 40)  # up to 20 Hz: w h <= 0.126
    g = rp.model_frf(th, st, f, RATE)
    gc = frequency_response(th, st, f, delay_s=H / 2)
    wh = 2 * np.pi * f * H
    assert np.all(np.abs(g - gc) / np.abs(gc) <= wh**2)
    np.testing.assert_allclose(rp.model_frf(th, st, np.array([1e-6]), RATE), [10.2], rtol=1e-6)  # DC gain sum


def test_thetas_from_modal_roundtrip() -> None:
    st = [SubmodelStructure(), SubmodelStructure(n=0, m=0, integrators=2)]
    th = rp.thetas_from_modal(np.array([[33.0, 0.017, 0.159], [0.0, 0.0, 4.0]]), st)
    np.testing.assert_allclose(th[0], theta_from_modal(33.0, 0.017, 0.159))
    np.testing.assert_allclose(th[1], [4.0])
    assert rp.thetas_from_modal(np.array([[np.nan, 0.1, 1.0], [0.0, 0.0, 4.0]]), st) is None


def _plant() -> tuple[np.ndarray, np.ndarray]:
    """A 25 Hz mode (zeta 0.05, gain 2) under ZOH at 1 kHz (discrete numerator, denominator)."""
    w = 2 * np.pi * 25.0
    numd, dend, _ = signal.cont2discrete(([2.0 * w**2], [1.0, 2 * 0.05 * w, w**2]), H, method="zoh")
    return np.atleast_2d(numd)[0], dend


def _closed_loop(r: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u = C (r - y), y = G u + v with the P-controller C = 0.3 (G is strictly proper: no algebraic loop)."""
    b, a = _plant()
    assert b.size == a.size == 3 and abs(b[0]) < 1e-12 and a[0] == 1.0
    n = r.size
    u = np.zeros(n + 2)  # two leading zeros: index k + 2 is sample k
    x = np.zeros(n + 2)
    for k in range(2, n + 2):
        x[k] = b[1] * u[k - 1] + b[2] * u[k - 2] - a[1] * x[k - 1] - a[2] * x[k - 2]
        u[k] = 0.3 * (r[k - 2] - x[k] - v[k - 2])
    return u[2:], x[2:] + v


def test_nonparametric_frf_closed_loop_square_wave() -> None:
    """S_yr/S_ur (core.frf) recovers the plant on the odd harmonics of a square-wave setpoint despite feedback and
    noise: each harmonic is reported at its own frequency (not the nearest bin's: 5 Hz lies between bins), the
    leakage bins around it are dropped, and every kept bin lies within 3 of its stated uncertainties of the truth.
    """
    rng = np.random.default_rng(1)
    n = 40000
    t = np.arange(n) * H
    r = np.sign(np.sin(2 * np.pi * 5.0 * t + 1e-9))
    y0 = _closed_loop(r, np.zeros(n))[1]
    v = 0.01 * np.std(y0) * rng.standard_normal(n)
    u, y = _closed_loop(r, v)
    est = rp.nonparametric_frf(u, y, RATE, r)
    b, a = _plant()
    _, g = signal.freqz(b, a, worN=2 * np.pi * est.freqs_hz * H)
    strong = np.abs(g) > 0.05 * np.abs(g).max()
    assert strong.sum() >= 5
    harmonic = 5.0 * (2 * np.round((est.freqs_hz / 5.0 - 1) / 2) + 1)
    bin_hz = RATE / 4096
    line = strong & (est.freqs_hz > 2.5)       # (bin 1 carries the windowed segments' residual mean: near-DC G)
    assert np.all(np.abs(est.freqs_hz[line] - harmonic[line]) < 0.02 * bin_hz)   # the line, not the bin
    assert np.all(np.abs(est.g - g) <= 3 * est.uncertainty)
    rel = np.abs(est.g - g) / np.abs(g)
    assert np.all(rel[line] < 0.01), rel
    # no leakage bins: nothing kept within two bins of a harmonic except the harmonic itself
    near = (np.abs(est.freqs_hz - harmonic) > 0.02 * bin_hz) & (np.abs(est.freqs_hz - harmonic) < 2.5 * bin_hz)
    assert not np.any(near & (est.freqs_hz > 2.5)), est.freqs_hz[near]


def test_nonparametric_frf_open_loop_white_noise() -> None:
    """Broadband input: S_uy/S_uu over the whole band; errors consistent with the Welch variance."""
    rng = np.random.default_rng(2)
    n = 2**16
    u = rng.standard_normal(n)
    b, a = _plant()
    y = signal.lfilter(b, a, u)
    y += 0.01 * np.std(y) * rng.standard_normal(n)
    est = rp.nonparametric_frf(u, y, RATE, None, nperseg=1024)
    # broadband: every bin where the output is well above the noise (up to 150 Hz, 6x the resonance) is kept;
    # far above the resonance |G| falls under the noise floor and the coherence test drops those bins
    f_all = np.arange(1, 154) * RATE / 1024
    assert np.all(np.isin(f_all, est.freqs_hz))
    _, g = signal.freqz(b, a, worN=2 * np.pi * est.freqs_hz * H)
    band = est.freqs_hz < 100
    assert np.median(np.abs(est.g[band] - g[band]) / np.abs(g[band])) < 0.05


def test_nonparametric_frf_rejects_tiny_window() -> None:
    with pytest.raises(ValueError):
        rp.nonparametric_frf(np.ones(10), np.ones(10), RATE)


def _series(n: int = 60, K: int = 2, fault_at: float | None = 3.0) -> tuple[rp.DiagnosisSeries, list[dict]]:
    """Synthetic Report-like objects: mode 2's frequency drops by 5 % at ``fault_at``."""
    reps = []
    truth_f = np.array([3.0, 30.0])
    for j in range(n):
        t = 0.1 * j
        est = j >= 10
        f = truth_f * np.array([1.0, 0.95 if fault_at is not None and t >= fault_at else 1.0])
        modal = np.full((K, 6), np.nan)
        if est:
            modal = np.column_stack([f, [0.2, 0.02], [10.0, 0.2], 0.01 * f, [0.002, 0.0005], [0.05, 0.002]])
        base = np.full((K, 3), np.nan)
        if j >= 20:
            base = np.column_stack([truth_f, [0.2, 0.02], [10.0, 0.2]])
        flags = np.zeros((K, 3), bool)
        if fault_at is not None and t >= fault_at + 0.5:
            flags[1, 0] = True
        reps.append(SimpleNamespace(time_s=t, modal=modal, baseline=base, flags=flags, estimating=est,
                                    phase="monitoring" if j >= 20 else "settling",
                                    health={"level": 0 if est else 1, "reasons": [] if est else ["initializing"],
                                            "residual_var": 1e-4 if est else None, "condition": 50.0}))
    events = []
    if fault_at is not None:
        events = [{"onset_time_s": fault_at, "clear_time_s": None, "mode": 2, "quantity": "natural_frequency",
                   "direction": "down", "baseline": 30.0, "value": 28.5, "alarm_time_s": fault_at + 0.5, "z": 9.0}]
    return rp.DiagnosisSeries.from_reports(reps, K), events


def test_series_and_verdict() -> None:
    s, ev = _series()
    assert s.n == 60 and s.K == 2 and s.first_estimate() == 10 and s.last_estimate() == 59
    assert math.isnan(s.health["residual_var"][0]) and s.health["residual_var"][10] == 1e-4
    level, text = rp.verdict(ev, s, 6.0)
    assert level == "FAULT" and "mode 2 natural frequency down -5.0 %" in text and "still open" in text
    s_ok, _ = _series(fault_at=None)
    assert rp.verdict([], s_ok, 6.0)[0] == "OK"
    s_none, _ = _series(n=5)
    assert rp.verdict([], s_none, 0.5)[0] == "NO ESTIMATE"


def test_truth_fault_intervals() -> None:
    truth = rp.TruthData(fault=[
        {"time_s": 0.0, "event": "start", "active": []},
        {"time_s": 2.0, "event": "onset", "fault": {"kind": "structural", "mode": 2, "quantity": "damping",
                                                    "relative_change": -0.3, "shape": "bump"}},
        {"time_s": 4.0, "event": "end", "fault": {"kind": "structural", "mode": 2, "quantity": "damping",
                                                  "relative_change": -0.3, "shape": "bump"}},
        {"time_s": 5.0, "event": "onset", "fault": {"kind": "sensor", "type": "stuck"}}])
    iv = truth.fault_intervals(end_s=10.0)
    assert [(d["start"], d["end"], d["kind"]) for d in iv] == [(2.0, 4.0, "structural"), (5.0, 10.0, "sensor")]
    assert "-30 %" in iv[0]["label"]


def test_write_report_self_contained(tmp_path: Path) -> None:
    s, ev = _series()
    rng = np.random.default_rng(3)
    u = rng.standard_normal(4000)
    b, a = _plant()
    y = signal.lfilter(b, a, u)
    truth = rp.TruthData(t=np.arange(60) * 0.1, modes=np.tile([[3.0, 0.2, 10.0, 0, 0, 0],
                                                              [30.0, 0.02, 0.2, 0, 0, 0]], (60, 1, 1)),
                         fault=[{"time_s": 3.0, "event": "onset", "fault": {"kind": "structural", "mode": 2,
                                 "quantity": "natural_frequency", "relative_change": -0.05, "shape": "step"}}])
    inp = rp.ReportInput(title="synthetic <bag>", series=s, events=ev, structures=[SubmodelStructure()] * 2,
                         rate_hz=RATE, closed_loop=False, input_delay_samples=0, duration_s=6.0,
                         params={"loop_rate_hz": RATE, "modes.memory_s": [1.0, 0.5]}, info={"bag": "x"},
                         truth=truth, frf_start=rp.nonparametric_frf(u, y, RATE), frf_end=None,
                         param_help={"loop_rate_hz": "Sample rate"})
    path = rp.write_report(inp, tmp_path)
    text = path.read_text()
    assert text.count("<svg ") == 4
    assert "synthetic &lt;bag&gt;" in text and "<bag>" not in text  # escaped
    assert "FAULT" in text and "Parameters used" in text and "Sample rate" in text
    assert "http://" not in text and "https://" not in text  # no external resources
    svg = ElementTree.fromstring((tmp_path / "modes.svg").read_text())
    assert svg.tag == "{http://www.w3.org/2000/svg}svg"
    ids = re.findall(r' id="([^"]+)"', text)
    assert ids and len(ids) == len(set(ids)), "the page's figures share element ids"
    # every paint is an SVG colour: a browser ignores an invalid one (matplotlib's "k" drew no baseline line)
    paints = set(re.findall(r' (?:stroke|fill)="([^"]*)"', text))
    bad = {p for p in paints if not re.fullmatch(r"#[0-9a-f]{3}|#[0-9a-f]{6}|none|url\(#[\w-]+\)|black|white", p)}
    assert not bad, f"not SVG colours: {sorted(bad)}"
    assert 'stroke="#000000" stroke-width="1.39" stroke-dasharray' in (tmp_path / "modes.svg").read_text()  # baseline
    rows = rp.summary_rows(inp)
    r = next(x for x in rows if x["mode"] == 2 and x["quantity"] == "natural_frequency")
    assert r["change_pct"] == pytest.approx(-5.0) and r["fault"].startswith("DOWN since 3.00")
