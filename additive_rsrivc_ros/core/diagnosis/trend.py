"""Drift of modal quantities across recordings of one machine (``rsrivc_fleet``; ROS-free numerics).

A slow change (wear, loosening) can move a mode by a fraction of a percent per recording, too little for the per-bag
fault logic, which compares each recording with its own baseline; here recordings are compared with each other.

Per bag, a robust level (:func:`bag_level`): the median of the estimates over the recording's settled part (outside
start-up, holds and gaps), its standard error from the estimate's scatter (never below the published std) corrected
for the autocorrelation of a forgetting estimator (``g(x) = 2 (x - 1 + exp(-x)) / x^2``, ``x = T / T_m``) and for the
median's efficiency on correlated data (``pi ln2 / 2``). Across bags (:func:`drift_test`), per machine, mode and
quantity against recording order: random-effects weighted regression (``tau^2`` by DerSimonian & Laird's moments
generalised to a regression), the slope's std inflated by the Birge ratio, a t test at ``alpha / n_tests``; a drift
is flagged when the slope is significant and the fitted change reaches ``faults.min_change.*`` and
``faults.min_change.spread_factor`` times the scatter about the line (docs/fleet_drift.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..vocabulary import QUANTITIES

MIN_RECORDINGS = 4            # a line through fewer recordings leaves < 2 degrees of freedom for its scatter
DEFAULT_ALPHA = 0.01          # family-wise false-alarm probability per machine (all modes and quantities)
_MAD_TO_STD = 1.482602218505602
_MEDIAN_EFFICIENCY = math.sqrt(math.pi * math.log(2.0) / 2.0)   # median vs mean of a correlated series (docstring)


@dataclass
class BagLevel:
    """A recording's robust level per mode and quantity (see the module docstring)."""

    value: np.ndarray            # (K, 3) median over the settled estimates
    std: np.ndarray              # (K, 3) standard error of the level
    monitored_s: float           # time the levels are taken over (the settled part)
    n_eff: np.ndarray            # (K,) independent estimates in that time (1 / g)


def time_average_variance_ratio(x: np.ndarray | float) -> np.ndarray:
    """``g(x) = 2 (x - 1 + exp(-x)) / x^2``: variance of the average over a time ``x T_m`` of a stationary process
    with autocorrelation ``exp(-|tau| / T_m)``, relative to the process's variance (1 at ``x = 0``)."""
    x = np.maximum(np.asarray(x, float), 1e-9)
    small = x < 1e-4
    return np.where(small, 1.0 - x / 3.0, 2.0 * (x - 1.0 + np.exp(-np.minimum(x, 700.0))) / np.where(small, 1.0, x)**2)


def bag_level(modal: np.ndarray, monitored: np.ndarray, memory_s: Sequence[float], period_s: float) -> BagLevel | None:
    """The level of one bag from its estimates ``modal`` ``(N, K, 6)`` (f, zeta, gain and their stds, as in
    estimates.csv) at the output instants where ``monitored`` (the settled part) is true (period ``period_s``);
    None without any."""
    modal = np.asarray(modal, float)
    mask = np.asarray(monitored, bool)
    if modal.ndim != 3 or modal.shape[2] < 6 or mask.shape != modal.shape[:1] or not mask.any():
        return None
    sel = modal[mask]                                   # (n, K, 6)
    k = sel.shape[1]
    value = np.full((k, 3), np.nan)
    scatter_mad = np.full((k, 3), np.nan)
    scatter_pub = np.full((k, 3), np.nan)
    for i in range(k):
        for q in range(3):
            x = sel[:, i, q]
            ok = np.isfinite(x)
            if not ok.any():
                continue
            med = float(np.median(x[ok]))
            mad = _MAD_TO_STD * float(np.median(np.abs(x[ok] - med)))
            pub = sel[:, i, q + 3][ok]
            pub = pub[np.isfinite(pub)]
            value[i, q] = med
            scatter_mad[i, q] = mad
            scatter_pub[i, q] = float(np.median(pub)) if pub.size else 0.0
    t_mon = float(mask.sum()) * float(period_s)
    mem = np.broadcast_to(np.asarray(memory_s, float), (k,))
    g = time_average_variance_ratio(t_mon / np.maximum(mem, 1e-12))
    mad_std = scatter_mad / np.sqrt(np.maximum(1.0 - g, 0.05))[:, None]
    scatter = np.fmax(mad_std, scatter_pub)
    std = _MEDIAN_EFFICIENCY * scatter * np.sqrt(g)[:, None]
    n_eff = 1.0 / g
    return BagLevel(value, std, t_mon, n_eff)


@dataclass
class TrendTest:
    """The drift test of one mode and quantity across the recordings of one machine."""

    mode: int                    # 1-based
    quantity: str
    indices: list[int]           # recording positions used (order of first sample time)
    level0: float = math.nan     # fitted level at the first recording used
    slope: float = math.nan      # per recording
    slope_std: float = math.nan
    tau: float = math.nan        # recording-to-recording std beyond the bags' own standard errors
    p_value: float = math.nan
    alpha: float = math.nan      # level of this test (Bonferroni-corrected)
    change_percent: float = math.nan       # fitted change, first -> last recording used, % of |level0|
    change_std_percent: float = math.nan
    scatter_percent: float = math.nan      # rms of the levels about the line, % of |level0|
    threshold_percent: float = math.nan    # faults.min_change.<quantity> in %
    flagged: bool = False
    direction: str = ""
    first_index: int | None = None         # first recording whose fitted change reaches the threshold
    reason: str = ""
    fitted: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}


def _wls(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least squares ``y = a + b x``: (coefficients, (X'WX)^-1, weighted residual sum Q)."""
    X = np.column_stack([np.ones_like(x), x])
    A = X.T @ (w[:, None] * X)
    cov = np.linalg.inv(A)
    beta = cov @ (X.T @ (w * y))
    r = y - X @ beta
    return beta, cov, float(np.sum(w * r * r))


def _tau2(x: np.ndarray, w: np.ndarray, q: float) -> float:
    """DerSimonian-Laird moment estimate of the extra variance for a weighted line fit (module docstring)."""
    X = np.column_stack([np.ones_like(x), x])
    A_inv = np.linalg.inv(X.T @ (w[:, None] * X))
    WX = w[:, None] * X
    denom = float(np.sum(w) - np.trace(A_inv @ (WX.T @ WX)))
    df = x.size - 2
    return max(0.0, (q - df) / denom) if denom > 0 else 0.0


def drift_test(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, se: Sequence[float] | np.ndarray, *,
               min_change: float, spread_factor: float, alpha: float, mode: int = 1,
               quantity: str = "natural_frequency", indices: Sequence[int] | None = None) -> TrendTest:
    """Random-effects trend test of levels ``y`` (standard errors ``se``) against recording order ``x``."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    se = np.asarray(se, float)
    idx = list(range(x.size)) if indices is None else list(indices)
    res = TrendTest(mode, quantity, idx, alpha=alpha, threshold_percent=100.0 * min_change)
    if x.size < MIN_RECORDINGS:
        res.reason = f"{x.size} usable recording(s), at least {MIN_RECORDINGS} needed"
        return res
    floor = 1e-12 * max(float(np.max(np.abs(y))), 1e-300)
    se = np.maximum(np.where(np.isfinite(se), se, 0.0), floor)
    w = 1.0 / se**2
    _, _, q = _wls(x, y, w)
    tau2 = _tau2(x, w, q)
    wstar = 1.0 / (se**2 + tau2)
    beta, cov, qstar = _wls(x, y, wstar)
    df = x.size - 2
    cov = cov * max(1.0, qstar / df)
    a, b = float(beta[0]), float(beta[1])
    level0 = a + b * x[0]
    res.level0, res.slope, res.slope_std, res.tau = level0, b, math.sqrt(max(cov[1, 1], 0.0)), math.sqrt(tau2)
    res.fitted = [float(a + b * v) for v in x]
    if not (math.isfinite(level0) and level0 != 0.0):
        res.reason = "level zero or undefined (rigid-body quantity)"
        return res
    from scipy.special import stdtr  # Student t CDF (scipy.stats costs a second to import)

    t_stat = b / res.slope_std if res.slope_std > 0 else math.copysign(math.inf, b) if b != 0 else 0.0
    res.p_value = float(2.0 * stdtr(df, -abs(t_stat)))
    span = float(x[-1] - x[0])
    res.change_percent = 100.0 * b * span / abs(level0)
    res.change_std_percent = 100.0 * res.slope_std * span / abs(level0)
    resid = y - np.asarray(res.fitted)
    res.scatter_percent = 100.0 * math.sqrt(float(np.sum(resid**2)) / df) / abs(level0)
    res.direction = "up" if b > 0 else "down"
    crossed = [i for i, v in zip(idx, x, strict=True) if abs(b * (v - x[0])) >= min_change * abs(level0)]
    res.first_index = crossed[0] if crossed else None
    res.flagged, res.reason = _decide(res, spread_factor)
    return res


def _decide(res: TrendTest, spread_factor: float) -> tuple[bool, str]:
    """Flag when the slope is significant, the change relevant and above the scatter (module docstring)."""
    change = abs(res.change_percent)
    if not res.p_value < res.alpha:
        return False, f"no significant trend (p = {res.p_value:.3g} >= {res.alpha:.3g})"
    if change < res.threshold_percent:
        return False, (f"significant trend but the change {res.change_percent:+.3g} % is below the relevant "
                       f"{res.threshold_percent:.3g} % (faults.min_change)")
    if change < spread_factor * res.scatter_percent:
        return False, (f"change {res.change_percent:+.3g} % within {spread_factor:g} x the scatter of the "
                       f"recordings about the trend ({res.scatter_percent:.3g} %)")
    return True, (f"drift {res.direction}: {res.change_percent:+.3g} % over the recordings (p = {res.p_value:.2g}, "
                  f"threshold {res.threshold_percent:.3g} %)")


def fleet_drift(levels: Sequence[BagLevel | None], min_change: Mapping[str, float], *, spread_factor: float,
                alpha: float = DEFAULT_ALPHA) -> list[TrendTest]:
    """Drift tests of every mode and quantity over one machine's recordings, ``levels`` in recording order
    (None: a recording that cannot feed the trend; it keeps its place in the order)."""
    used = [(j, lv) for j, lv in enumerate(levels) if lv is not None]
    if not used:
        return []
    k = min(lv.value.shape[0] for _, lv in used)
    n_tests = 3 * k
    tests = []
    for i in range(k):
        for q, name in enumerate(QUANTITIES):
            pts = [(j, lv.value[i, q], lv.std[i, q]) for j, lv in used
                   if math.isfinite(lv.value[i, q]) and math.isfinite(lv.std[i, q])]
            tests.append(drift_test([p[0] for p in pts], [p[1] for p in pts], [p[2] for p in pts],
                                    min_change=float(min_change[name]), spread_factor=spread_factor,
                                    alpha=alpha / n_tests, mode=i + 1, quantity=name, indices=[p[0] for p in pts]))
    return tests
