"""What the data identify jointly, and which structural changes they support.

The recursion's covariance ``sigma^2 P_i`` is *conditional* on the other modes ([RA-SRIVC] Algorithm 2). When modes
share the excitation (a few reference lines near the resonances, [RA-SRIVC] §5) the joint covariance is many times
larger (gains 9-11x), and after a change the recursion drifts along those weak directions. The joint check answers
from a window's data: the offline fit of all modes in one IV solve ([A-SRIVC] eq. 29) and its sandwich covariance
([A-SRIVC] Theorem 1), mapped to (f, zeta, gain) by the delta method.

* **Identifiable**: 3 joint stds below the relevant change ``faults.min_change``.
* **Supported**: identifiable in the reference (end of the baseline window) and now, relevant, and 4 joint stds away.
* **Coupling**: the largest correlation between two modes' quantities; a weak mode holds the modes coupled to it.
* Where gain and damping are not separable, the resonance peak ``g / (2 zeta)`` may be; its change is reported.
* **Blend**: a fit whose output error ([BCD-SRIVC] eq. 8) in a quarter after the window's first is ``MISFIT_RATIO``
  times the reference's holds a change (a frequency jump fitted as a damping rise) or a changed noise: no support.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from ..model import SubmodelStructure, guess_theta, modal_jacobian
from ..vocabulary import QUANTITIES

Z_IDENTIFIABLE = 3.0   # a relevant change is this many joint stds: the quantity is identifiable
COUPLING = 0.5         # |correlation| between two modes' quantities from which one's weakness holds the other
Z_SUPPORT = 4.0        # a change is this many stds from the reference: supported. Checks repeat every half memory on
                       # overlapping windows for up to 3K quantities (measured at 3: 2 wrong events in 20 runs of
                       # scripts/study_narrow_excitation.py, a mode-3 frequency at -2.5 % late in the run)
MISFIT_RATIO = 1.2     # output-error variance of a window's fit over the reference's from which the window is a blend,
                       # in the worst of its last three quarters (a 62 s window over a 6.6 % frequency jump of a zeta
                       # 0.03 mode: 1.47 with the jump at 36 % of it, 1.62 at 61 %; 1.02 at 11 %, where the fit is
                       # the plant after the jump; white noise, 250 000 samples)


@dataclass(frozen=True)
class JointVerdict:
    """One joint fit of a window against the baseline (module docstring); arrays are (K, 3) unless noted."""

    t: float                      # time of the check (s since the first sample)
    window_s: tuple[float, float]
    converged: bool
    value: np.ndarray
    std: np.ndarray               # joint (marginal over every other mode) std
    identifiable: np.ndarray      # bool
    supported: np.ndarray         # int: +1 up, -1 down, 0 none
    peak_change: np.ndarray       # (K,) relative change of gain / (2 damping) vs the baseline (NaN: no peak)
    peak_std: np.ndarray          # (K,)
    peak_supported: np.ndarray    # (K,) int
    peak_own_std: np.ndarray      # (K,) relative std of this fit's own gain / (2 damping)
    message: str = ""
    coupling: np.ndarray | None = None   # (K, K) largest |correlation| between two modes' quantities in this fit
    residual_variance: float = math.nan  # output-error variance of the fit
    misfit_ratio: float = math.nan       # residual_variance over the reference's (NaN: no reference)

    @property
    def blended(self) -> bool:
        """The window's fit misfits the data ``MISFIT_RATIO`` times more than the reference's: it supports nothing."""
        return bool(self.misfit_ratio > MISFIT_RATIO)

    def armed_modes(self, applicable: np.ndarray, threshold: float = COUPLING) -> np.ndarray:
        """(K,) bool: modes whose deviations need this fit's support: a mode with a quantity the window does not
        identify, and every mode coupled to one (|correlation| of their quantities >= ``threshold``: the
        recursion's split between them is not trustworthy). A weakly excited mode far from the others holds
        only itself."""
        weak = self.converged & np.any(applicable & ~self.identifiable, axis=1)
        if self.coupling is None:       # a fit saved without its coupling: every mode, as one block
            return np.full(weak.shape, bool(weak.any()))
        coupled = np.asarray(self.coupling, float) >= threshold
        return np.asarray(weak | np.any(coupled[:, weak], axis=1), bool)

    def coupling_lines(self, armed: np.ndarray, applicable: np.ndarray) -> list[str]:
        """'mode i held by mode j' for each armed mode that is armed through another one's coupling."""
        weak = np.any(applicable & ~self.identifiable, axis=1)
        if self.coupling is None:
            return []
        return [f"mode {i + 1} held by mode {j + 1} (correlation {self.coupling[i, j]:.2f})"
                for i in np.flatnonzero(armed & ~weak) for j in np.flatnonzero(weak)
                if self.coupling[i, j] >= COUPLING]

    def not_identifiable(self, applicable: np.ndarray) -> list[str]:
        """``"mode i quantity"`` for every applicable quantity the window does not identify."""
        return [f"mode {i + 1} {QUANTITIES[q]}" for i, q in zip(*np.nonzero(applicable & ~self.identifiable),
                                                                 strict=True)]

    def peak_lines(self) -> list[str]:
        """One line per supported resonance-peak change of a mode whose gain and damping are not named."""
        out = []
        for i in np.flatnonzero(self.peak_supported):
            out.append(f"mode {i + 1} resonance peak gain/(2 damping) {100 * self.peak_change[i]:+.1f} % "
                       f"(std {100 * self.peak_std[i]:.1f} %)")
        return out

    def to_dict(self) -> dict:
        def clean(a: np.ndarray) -> list:
            return np.where(np.isfinite(a), a, np.nan).tolist()
        return {"t": self.t, "window_s": list(self.window_s), "converged": self.converged,
                "value": clean(self.value), "std": clean(self.std), "identifiable": self.identifiable.tolist(),
                "supported": self.supported.tolist(), "peak_change": clean(self.peak_change),
                "peak_std": clean(self.peak_std), "peak_supported": self.peak_supported.tolist(),
                "peak_own_std": clean(self.peak_own_std),
                "message": self.message, "coupling": None if self.coupling is None else clean(self.coupling),
                "residual_variance": _finite_or_none(self.residual_variance),
                "misfit_ratio": _finite_or_none(self.misfit_ratio)}

    @classmethod
    def from_dict(cls, d: dict) -> JointVerdict:
        def arr(k: str, dtype: type = float) -> np.ndarray:
            return np.asarray(d[k], dtype=float).astype(dtype)
        return cls(float(d["t"]), tuple(d["window_s"]), bool(d["converged"]), arr("value"), arr("std"),
                   arr("identifiable", bool), arr("supported", int), arr("peak_change"), arr("peak_std"),
                   arr("peak_supported", int), arr("peak_own_std"), str(d.get("message", "")),
                   None if d.get("coupling") is None else arr("coupling"),
                   _float_or_nan(d.get("residual_variance")), _float_or_nan(d.get("misfit_ratio")))


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _float_or_nan(x: Any) -> float:
    return math.nan if x is None else float(x)


def applicable_mask(structures: Sequence[SubmodelStructure]) -> np.ndarray:
    """(K, 3): frequency and damping exist only for second-order modes; every mode has a gain."""
    return np.array([[s.n == 2, s.n == 2, True] for s in structures], dtype=bool)


def joint_modal_covariance(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure],
                           covariance: np.ndarray) -> np.ndarray:
    """(3K, 3K) covariance of every mode's (f, zeta, gain): ``J C J^T`` with the block-diagonal modal Jacobian."""
    sizes = [s.n_theta for s in structures]
    J = np.zeros((3 * len(sizes), sum(sizes)))
    o = 0
    for i, (th, s) in enumerate(zip(thetas, structures, strict=True)):
        J[3 * i:3 * i + 3, o:o + s.n_theta] = modal_jacobian(th, s)
        o += s.n_theta
    return J @ covariance @ J.T


def verdict_from_fit(t: float, window_s: tuple[float, float], converged: bool, modal: np.ndarray,
                     cov_modal: np.ndarray, base_value: np.ndarray, base_std: np.ndarray,
                     structures: Sequence[SubmodelStructure], min_change: Sequence[float], *,
                     base_peak_std: np.ndarray | None = None, base_identifiable: np.ndarray | None = None,
                     z: float = Z_SUPPORT, z_identifiable: float = Z_IDENTIFIABLE, message: str = "",
                     residual_variance: float = math.nan, tail_variance: float = math.nan,
                     base_residual_variance: float = math.nan) -> JointVerdict:
    """Identifiable and supported quantities of a joint fit against the baseline (module docstring); a blend
    (``tail_variance``, :attr:`JointFit.tail_cost`, over the reference's ``base_residual_variance`` above
    ``MISFIT_RATIO``) supports nothing."""
    K = len(structures)
    app = applicable_mask(structures)
    var = np.diag(cov_modal).reshape(K, 3)
    std = np.where(var >= 0, np.sqrt(np.abs(var)), np.nan)
    value = np.asarray(modal, dtype=float)[:, :3]
    rho = np.asarray(min_change, dtype=float)[None, :] * np.abs(base_value)
    ok = converged & np.isfinite(value) & np.isfinite(std) & app
    identifiable = ok & (z_identifiable * std <= rho)
    if base_identifiable is not None:    # the reference's excitation too: a fit at a wrong optimum reports small stds
        identifiable &= np.asarray(base_identifiable, dtype=bool)
    dev = value - base_value
    sig = np.sqrt(np.where(ok, std, 0.0) ** 2 + np.nan_to_num(base_std) ** 2)
    supported = np.where(identifiable & (np.abs(dev) >= rho) & (np.abs(dev) >= z * sig), np.sign(dev), 0).astype(int)
    peak_change, peak_std = np.full(K, np.nan), np.full(K, np.nan)
    peak_supported = np.zeros(K, dtype=int)
    peak_own = np.full(K, np.nan)
    base_peak = np.zeros(K) if base_peak_std is None else np.nan_to_num(np.asarray(base_peak_std, float))
    for i in range(K):
        if not (app[i, 1] and ok[i, 1] and ok[i, 2]) or base_value[i, 1] == 0 or value[i, 1] == 0:
            continue
        zeta, g = value[i, 1], value[i, 2]
        grad = np.array([-1.0 / zeta, 1.0 / g])            # d log(g / zeta) / d (zeta, g)
        c = cov_modal[3 * i + 1:3 * i + 3, 3 * i + 1:3 * i + 3]
        ratio = (g / zeta) / (base_value[i, 2] / base_value[i, 1])
        peak_change[i] = ratio - 1.0
        peak_own[i] = math.sqrt(max(float(grad @ c @ grad), 0.0))
        peak_std[i] = abs(ratio) * math.hypot(peak_own[i], base_peak[i])
        named = supported[i, 1] != 0 or supported[i, 2] != 0
        separable = identifiable[i, 1] and identifiable[i, 2]
        if not named and not separable and abs(peak_change[i]) >= min(min_change[1], min_change[2]) and \
                abs(peak_change[i]) >= z * peak_std[i]:
            peak_supported[i] = int(np.sign(peak_change[i]))
    ratio = tail_variance / base_residual_variance if base_residual_variance > 0 else math.nan
    if ratio > MISFIT_RATIO:
        supported[:], peak_supported[:] = 0, 0
        message += (f"; output error x{ratio:.2f} the reference's: the window holds a change (or the noise "
                    "changed), its fit is a blend and supports nothing")
    return JointVerdict(float(t), (float(window_s[0]), float(window_s[1])), bool(converged), value, std,
                        identifiable, supported, peak_change, peak_std, peak_supported, peak_own, message,
                        mode_coupling(cov_modal, K), float(residual_variance), float(ratio))


def mode_coupling(cov_modal: np.ndarray, K: int) -> np.ndarray:
    """(K, K): the largest |correlation| between a quantity of mode i and one of mode j (0 on the diagonal)."""
    c = np.asarray(cov_modal, float)
    d = np.sqrt(np.abs(np.diag(c)))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.abs(c / np.outer(d, d))
    corr = np.where(np.isfinite(corr), corr, 0.0).reshape(K, 3, K, 3).max(axis=(1, 3))
    np.fill_diagonal(corr, 0.0)
    return corr


class JointFit(NamedTuple):
    """One joint fit of a window (:func:`joint_fit`)."""

    converged: bool
    modal: np.ndarray             # (K, 3)
    covariance: np.ndarray        # (3K, 3K) of every mode's (f, zeta, gain)
    message: str
    cost: float                   # output-error variance over the window
    tail_cost: float              # the largest over the window's last three quarters (a change early in it is allowed)


def failed_fit(K: int, why: str) -> JointFit:
    """A joint fit that judges nothing (not converged, NaN values), with the reason."""
    return JointFit(False, np.full((K, 3), np.nan), np.full((3 * K, 3 * K), np.nan), why, math.nan, math.nan)


def thetas_of(modal: np.ndarray, structures: Sequence[SubmodelStructure]) -> list[np.ndarray]:
    """The submodel parameters of modal values ``(K, 3)`` (frequency, damping, gain; a rigid body's gain only)."""
    return [guess_theta(0.0 if s.n == 0 else float(m[0]), float(m[1]), float(m[2]))
            for m, s in zip(modal, structures, strict=True)]


def joint_fit(r: np.ndarray | None, u: np.ndarray, y: np.ndarray, rate_hz: float,
              structures: Sequence[SubmodelStructure], thetas0: Sequence[np.ndarray], *, controller=None,
              input_delay: int = 0) -> JointFit:
    """Offline additive (CL)SRIVC of the window from ``thetas0``, its free response projected out (the window starts
    with the plant in motion). Never raises: a failed fit is returned as not converged with the reason (the caller
    then judges nothing)."""
    from ..identification.offline import identify

    K = len(structures)
    try:
        res = identify(u, y, rate_hz, list(structures), [np.asarray(t, float) for t in thetas0], r=r,
                       controller=controller, input_delay=input_delay, warmup_s=None, in_motion=True)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        return failed_fit(K, f"joint fit failed: {str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__}")
    if not res.converged or not np.all(np.isfinite(res.covariance)):
        return failed_fit(K, f"joint fit did not converge ({res.message})")
    cov = joint_modal_covariance(res.thetas, structures, res.covariance)
    return JointFit(True, np.asarray(res.modal, dtype=float)[:, :3], cov, "converged", float(res.cost),
                    _tail_cost(u, y, rate_hz, structures, res.thetas, input_delay))


def _block_costs(u: np.ndarray, y: np.ndarray, rate_hz: float, structures: Sequence[SubmodelStructure],
                 thetas: Sequence[np.ndarray], input_delay: int, blocks: int, first: int = 0) -> np.ndarray | None:
    """Output-error variance of the model ``thetas`` on blocks ``first..blocks-1`` of ``blocks`` equal blocks that end
    with the window, each judged as a record in motion (:func:`.offline.output_error_variance`); None when the
    blocks are too short for the model order."""
    from ..identification.offline import output_error_variance

    n = u.size // blocks
    if n < 2:
        return None
    starts = u.size - n * np.arange(blocks - first, 0, -1)
    try:
        return np.array([output_error_variance(u[a:a + n], y[a:a + n], rate_hz, structures, thetas,
                                               input_delay=input_delay) for a in starts])
    except (ValueError, np.linalg.LinAlgError):
        return None


def _tail_cost(u: np.ndarray, y: np.ndarray, rate_hz: float, structures: Sequence[SubmodelStructure],
               thetas: Sequence[np.ndarray], input_delay: int) -> float:
    """The largest output-error variance of the fitted model over the window's last three quarters (a change early in
    the first quarter leaves them alone); NaN when they are too short to judge."""
    costs = _block_costs(u, y, rate_hz, structures, thetas, input_delay, 4, first=1)
    return math.nan if costs is None else float(costs.max())


CHANGE_BLOCKS = 8   # a joint window is searched for a change in this many blocks


def change_start(u: np.ndarray, y: np.ndarray, rate_hz: float, structures: Sequence[SubmodelStructure],
                 thetas: Sequence[np.ndarray], input_delay: int, base_variance: float, min_samples: int) -> int | None:
    """Index where a joint window should start so that it holds no data of the reference plant before a change: the
    end of the first of ``CHANGE_BLOCKS`` blocks from which on the reference model's output error
    (:func:`.offline.output_error_variance`) exceeds ``MISFIT_RATIO`` x ``base_variance`` for good, after one that
    does not. 0: no lasting change, or every block misfits (the window is after the change, or the change lies in
    its first block: the blend check judges). None: fewer than ``min_samples`` follow the change (wait)."""
    if not base_variance > 0:
        return 0
    costs = _block_costs(u, y, rate_hz, structures, thetas, input_delay, CHANGE_BLOCKS)
    if costs is None:
        return 0                    # blocks too short for the model order: no change can be placed
    first = _trailing_misfit_start(u.size, costs > MISFIT_RATIO * base_variance)
    if first is None:
        return 0                    # no lasting change, or the window is all after it (or it lies in the first block)
    start = first + u.size // CHANGE_BLOCKS                # the end of the first misfit block of the last run
    return start if u.size - start >= min_samples else None


def _trailing_misfit_start(size: int, misfit: np.ndarray) -> int | None:
    """Sample index where the run of misfit blocks (of ``CHANGE_BLOCKS`` equal blocks ending with the window) that
    ends the window begins; None when the last block fits or every block misfits."""
    if not misfit[-1] or misfit.all():
        return None
    last_good = int(np.flatnonzero(~misfit)[-1])
    return size - (CHANGE_BLOCKS - last_good - 1) * (size // CHANGE_BLOCKS)


def clean_end(u: np.ndarray, y: np.ndarray, rate_hz: float, structures: Sequence[SubmodelStructure], fit: JointFit,
              input_delay: int) -> int | None:
    """Where a window whose fit misfits its later part (``fit.tail_cost`` above ``MISFIT_RATIO`` x ``fit.cost``)
    stops holding one plant: the start of the last run of ``CHANGE_BLOCKS`` blocks whose output error under the fit
    exceeds ``MISFIT_RATIO`` x the median block's. None: no such run at the end (or every block misfits)."""
    if not fit.tail_cost > MISFIT_RATIO * fit.cost:
        return None
    costs = _block_costs(u, y, rate_hz, structures, thetas_of(fit.modal, structures), input_delay, CHANGE_BLOCKS)
    return None if costs is None else _trailing_misfit_start(u.size, costs > MISFIT_RATIO * float(np.median(costs)))


class RecentSamples:
    """The last samples fed to the estimator, contiguous (a data break clears them); ``y`` is NaN where invalid."""

    def __init__(self) -> None:
        self.chunks: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque()
        self.n = 0

    def clear(self) -> None:
        self.chunks.clear()
        self.n = 0

    def add(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, capacity: int) -> None:
        if u.size == 0 or capacity <= 0:
            return
        self.chunks.append((np.array(r, dtype=float), np.array(u, dtype=float), np.array(y, dtype=float)))
        self.n += u.size
        while self.chunks and self.n - self.chunks[0][1].size >= capacity:
            self.n -= self.chunks.popleft()[1].size

    def last(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The last ``n`` samples as (r, u, y), or None when fewer are held."""
        if n <= 0 or self.n < n:
            return None
        r, u, y = (np.concatenate([c[q] for c in self.chunks])[-n:] for q in range(3))
        return r, u, y


class JointChecker:
    """Drives S6 (:mod:`.faults`) for a pipeline: keeps the recent samples and runs the joint fit when due.

    After the baseline is learned, one fit of the last ``MAX_WINDOW`` memory lengths (``MIN_WINDOW`` when fewer
    are held) is the reference and arms S6 or not; while armed,
    checks run at :meth:`FaultMonitor.joint_due` on a window that starts at the earliest deviation of a test (at
    least :meth:`min_window` (``MIN_WINDOW`` on narrow excitation, where a joint fit of one memory length does not
    converge reliably), at most ``MAX_WINDOW`` longest memory lengths), cut after a change found in it
    (:func:`change_start`)."""

    MIN_WINDOW = 2.0
    MAX_WINDOW = 4.0
    SHORTEST_WINDOW = 0.5   # memory lengths: the shortest check window where the reference identifies with room
    MAX_SAMPLES = 200_000   # a longer window is cut (to MIN_WINDOW at least): ~1 s per fit on this machine

    def __init__(self, cfg: Any) -> None:
        self.rate = float(cfg.loop_rate_hz)
        self.structures = list(cfg.structures)
        self.controller = cfg.controller if cfg.closed_loop else None
        self.closed_loop = bool(cfg.closed_loop)
        self.delay = int(cfg.input_delay_samples)
        self.recent = RecentSamples()
        self.last_t = math.nan

    def add(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, memory_max_s: float) -> None:
        self.recent.add(r, u, y, int(math.ceil(self.MAX_WINDOW * memory_max_s * self.rate)) + 1)

    def step(self, t: float, faults: Any) -> Any:
        """Run a due check; returns the monitor's :class:`FaultUpdate` or None (nothing ran)."""
        if faults.phase != "monitoring" or faults.baseline is None:
            return None
        mem = float(faults.memory_s.max())
        ref = faults.joint_reference
        if ref is None or (not ref.converged and self._quiet(faults)):
            # the reference: the joint fit of the baseline window arms the modes it does not identify; a fit that
            # does not converge arms every mode and is retried while no test deviates (a later window may hold a
            # change, which must not become the reference)
            if not math.isnan(self.last_t) and t - self.last_t < self.MIN_WINDOW * mem:
                return None
            verdict = self.verdict(t, self.MAX_WINDOW * mem, faults) or self.verdict(t, self.MIN_WINDOW * mem, faults)
            if verdict is None:
                return None
            self.last_t = t
            if verdict.converged and verdict.blended:
                # the window's later part misfits the fit 1.2x its own level: it holds a change (a baseline
                # completed just after one), and a blend of two plants must not become the reference
                verdict = replace(verdict, converged=False, message=verdict.message + "; not a reference")
            if ref is None or verdict.converged:
                faults.arm_joint(verdict)
            return None
        if not ref.converged:
            return None     # a deviation while the reference is pending: no fit of it could confirm anything
        if not faults.joint_due(t, self.last_t):
            return None
        since = [tst.since for row in faults.tests for tst in row if tst.state == "suspect"]
        least = self.min_window(faults)
        age = t - min(since) if since else least * mem
        window = min(max(age, least * mem), self.MAX_WINDOW * mem)
        if faults.anomaly_since is not None:
            # an abrupt change (the stress's start): a window that straddles it fits a blend of two plants; only the
            # data after it say what changed
            window = min(window, t - faults.anomaly_since)
            if window < least * mem:
                return None
        verdict = self.verdict(t, window, faults)
        if verdict is None:
            return None
        self.last_t = t
        return faults.apply_joint(t, verdict)

    def min_window(self, faults: Any) -> float:
        """Shortest check window in memory lengths: ``MIN_WINDOW``, or less where the reference fit identifies every
        applicable quantity with room to spare: the length in which 2 x ``Z_IDENTIFIABLE`` of its stds (std ~
        1/sqrt(length)) stay within the relevant change, at least ``SHORTEST_WINDOW``."""
        ref = faults.joint_reference
        if ref is None or not ref.converged:
            return self.MIN_WINDOW
        rho = np.asarray(faults.settings.min_change, float)[None, :] * np.abs(ref.value)
        with np.errstate(divide="ignore", invalid="ignore"):
            need = (ref.window_s[1] - ref.window_s[0]) * (2.0 * Z_IDENTIFIABLE * ref.std / rho) ** 2
        need = need[applicable_mask(self.structures)]
        if need.size == 0 or not np.all(np.isfinite(need)):
            return self.MIN_WINDOW
        return float(min(max(need.max() / float(faults.memory_s.max()), self.SHORTEST_WINDOW), self.MIN_WINDOW))

    @staticmethod
    def _quiet(faults: Any) -> bool:
        """No test deviates (every CUSUM at rest) and no stress: the window holds no change to mistake for the
        reference."""
        return faults.anomaly_since is None and all(tst.state == "ok" and tst.g_up == 0.0 and tst.g_down == 0.0
                                                    for row in faults.tests for tst in row)

    def verdict(self, t: float, window_s: float, faults: Any) -> JointVerdict | None:
        """The joint fit of the last ``window_s`` seconds from the baseline model; None without enough data."""
        mem = float(faults.memory_s.max())
        least = self.min_window(faults)
        n = int(round(min(window_s, max(least * mem, self.MAX_SAMPLES / self.rate)) * self.rate))
        data = self.recent.last(n)
        if data is None:
            return None
        r, u, y = data
        bad = np.flatnonzero(~(np.isfinite(u) & np.isfinite(y) & (np.isfinite(r) if self.closed_loop else True)))
        if bad.size:                # invalid samples (held, non-finite): only the clean stretch after the last one
            start = int(bad[-1]) + 1
            if u.size - start < int(round(least * mem * self.rate)):
                return None
            r, u, y = r[start:], u[start:], y[start:]
            n = u.size
        ref = faults.joint_reference
        value, std = faults.joint_basis()
        peak_std, ident = (None, None) if ref is None or not ref.converged else (ref.peak_own_std, ref.identifiable)
        base_var = math.nan if ref is None or not ref.converged else ref.residual_variance
        blend_var = base_var
        thetas0 = thetas_of(value, self.structures)
        after = change_start(u, y, self.rate, self.structures, thetas0, self.delay, base_var,
                             int(round(least * mem * self.rate)))
        if after is None:
            return None             # the window after the change is still too short to fit
        r, u, y = r[after:], u[after:], y[after:]
        n = u.size
        end = t
        candidate = ref is None or not ref.converged
        enough = max(n / 2, self.SHORTEST_WINDOW * mem * self.rate)    # of a reference candidate cut short
        if candidate and faults.anomaly_since is not None and faults.anomaly_since > t - n / self.rate:
            # a reference candidate that reaches into an abrupt change (the baseline completed just after one, a
            # restart pushed its end there): only the data before the change, if half of it is
            keep = int(round((faults.anomaly_since - (t - n / self.rate)) * self.rate))
            if keep < enough:
                none = failed_fit(len(self.structures), "the window is mostly after an output anomaly: no reference")
                return verdict_from_fit(t, (t - n / self.rate, t), False, none.modal, none.covariance, value, std,
                                        self.structures, faults.settings.min_change, message=none.message)
            r, u, y, end, n = r[:keep], u[:keep], y[:keep], t - (n - keep) / self.rate, keep
        fit = joint_fit(r if self.closed_loop else None, u, y, self.rate, self.structures, thetas0,
                        controller=self.controller, input_delay=self.delay)
        if candidate:
            # a reference candidate is judged against its own output error; one whose end holds a change (a
            # baseline completed just after it) is refitted on the data before that change, if half of it is
            cut = clean_end(u, y, self.rate, self.structures, fit, self.delay) if fit.converged else None
            if cut is not None and cut >= enough:
                r, u, y, end = r[:cut], u[:cut], y[:cut], end - (n - cut) / self.rate
                n = cut
                fit = joint_fit(r if self.closed_loop else None, u, y, self.rate, self.structures, thetas0,
                                controller=self.controller, input_delay=self.delay)
            blend_var = fit.cost
        return verdict_from_fit(t, (end - n / self.rate, end), fit.converged, fit.modal, fit.covariance, value, std,
                                self.structures, faults.settings.min_change, base_peak_std=peak_std,
                                base_identifiable=ident, message=fit.message, residual_variance=fit.cost,
                                tail_variance=fit.tail_cost, base_residual_variance=blend_var)
