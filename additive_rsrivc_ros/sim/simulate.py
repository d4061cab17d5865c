"""Time-varying additive modal plant in closed or open loop, exact ZOH (the loop: ``core.plant.simulate_kernel``).

The plant of [RA-SRIVC] eq. 5 / [A-SRIVC] eq. 2: ``x = sum_i x_i`` with ``p^l_i (a_i2 p^2 + a_i1 p + 1) x_i = b_i0 u(t -
d h)`` (rigid body: ``p^l_i x_i = b_i0 u(t - d h)``), ``u`` held between samples and delayed ``d`` samples.
``theta_i(t_k)`` holds on ``[t_k, t_k+1)`` and each mode's physical state is carried across changes (the slow-variation
setting of Remark 4.4). ``y(t_k) = x(t_k) + v(t_k)``, in closed loop ``u(t_k) = C_d(q) (r - y)(t_k)`` ([RA-SRIVC] eq.
10); the transition is exact (:mod:`..core.plant`). Sensor faults act on the measured output, which feeds the controller
too: bias or drift, a stuck value, dropped samples (the receiver holds the last value) and NaN samples (the controller
holds its last finite measurement).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.controller import DiscreteController
from ..core.model import TWO_PI, SubmodelStructure, second_order_modal
from ..core.plant import check_drive, pack_thetas, simulate_kernel
from ..core.vocabulary import SIM_QUANTITIES

SHAPES = ("step", "ramp", "raised_cosine", "bump")
SENSOR_FAULTS = ("bias", "drift", "stuck", "drop", "nan")


# ----------------------------------------------------------------------------------------------------------------
# Plant description
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlantMode:
    """One additive submodel in modal form: ``gain / (p^l (p^2/w^2 + 2 zeta p/w + 1))`` ([RA-SRIVC] eq. 16).

    ``natural_frequency_hz == 0`` is a rigid-body mode ``gain / p^l`` (needs ``integrators > 0``, [RA-SRIVC] §4.6).
    """

    natural_frequency_hz: float
    damping_ratio: float
    gain: float
    integrators: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.natural_frequency_hz) and math.isfinite(self.damping_ratio)
                and math.isfinite(self.gain)):
            raise ValueError(f"plant mode values must be finite, got {self}")
        if self.natural_frequency_hz < 0.0:
            raise ValueError(f"natural frequency must be >= 0 Hz, got {self.natural_frequency_hz}")
        if self.natural_frequency_hz == 0.0 and self.integrators < 1:
            raise ValueError("a rigid-body mode (frequency 0) needs integrators >= 1")
        if not 0 <= self.integrators <= 3:
            raise ValueError(f"integrators must be in 0..3, got {self.integrators}")
        if self.natural_frequency_hz > 0.0 and self.damping_ratio < 0.0:
            raise ValueError(f"damping ratio must be >= 0, got {self.damping_ratio}")

    @property
    def rigid(self) -> bool:
        return self.natural_frequency_hz == 0.0

    @property
    def structure(self) -> SubmodelStructure:
        return SubmodelStructure(n=0 if self.rigid else 2, m=0, integrators=self.integrators)

    @property
    def modal(self) -> np.ndarray:
        return np.array([self.natural_frequency_hz, self.damping_ratio, self.gain])


@dataclass(frozen=True)
class ModalChange:
    """A change of one modal quantity of one plant mode (manipulation or structural fault).

    ``quantity(t) = nominal * (1 + relative_change * s(t))`` with the profile ``s`` rising from 0 at ``start_s``
    to 1 at ``start_s + duration_s``: ``step`` (duration ignored), ``ramp`` (linear), ``raised_cosine``
    (smooth, (1 - cos)/2) or ``bump`` (raised cosine there and back: 0 -> 1 at the middle -> 0). Several changes
    of the same quantity multiply. ``mode`` is 0-based.
    """

    mode: int
    quantity: str
    relative_change: float
    start_s: float
    duration_s: float = 0.0
    shape: str = "step"

    def __post_init__(self) -> None:
        if self.quantity not in SIM_QUANTITIES:
            raise ValueError(f"quantity must be one of {SIM_QUANTITIES}, got {self.quantity!r}")
        if self.shape not in SHAPES:
            raise ValueError(f"shape must be one of {SHAPES}, got {self.shape!r}")
        if not (math.isfinite(self.relative_change) and self.relative_change > -1.0):
            raise ValueError(f"relative_change must be finite and > -1, got {self.relative_change}")
        if self.duration_s < 0.0 or (self.shape != "step" and self.duration_s == 0.0):
            raise ValueError(f"shape {self.shape!r} needs duration_s > 0, got {self.duration_s}")

    def profile(self, t: np.ndarray) -> np.ndarray:
        """``s(t)`` in [0, 1]."""
        t = np.asarray(t, dtype=float)
        if self.shape == "step":
            return (t >= self.start_s).astype(float)
        x = np.clip((t - self.start_s) / self.duration_s, 0.0, 1.0)
        if self.shape == "ramp":
            return x
        if self.shape == "raised_cosine":
            return 0.5 * (1.0 - np.cos(np.pi * x))
        return 0.5 * (1.0 - np.cos(TWO_PI * x))  # bump

    def to_dict(self) -> dict:
        return {"mode": self.mode, "quantity": self.quantity, "relative_change": self.relative_change,
                "start_s": self.start_s, "duration_s": self.duration_s, "shape": self.shape}


@dataclass(frozen=True)
class SensorFault:
    """A fault of the output sensor (applied to the measured ``y``, which the controller uses too).

    kinds: ``bias`` (adds ``value`` on the window), ``drift`` (adds ``value`` per second since ``start_s``),
    ``stuck`` (reads ``value``; None: the clean measurement at onset), ``drop`` (a fraction ``fraction`` of the
    window's samples are lost, the receiver holds the last value), ``nan`` (a fraction of samples read NaN).
    The window is ``[start_s, start_s + duration_s)``; ``duration_s = inf`` lasts to the end.
    """

    kind: str
    start_s: float
    duration_s: float = math.inf
    value: float | None = 0.0
    fraction: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in SENSOR_FAULTS:
            raise ValueError(f"sensor fault kind must be one of {SENSOR_FAULTS}, got {self.kind!r}")
        if not self.duration_s > 0.0:
            raise ValueError(f"sensor fault duration_s must be > 0, got {self.duration_s}")
        if self.kind in ("drop", "nan") and not 0.0 < self.fraction <= 1.0:
            raise ValueError(f"sensor fault {self.kind!r} needs 0 < fraction <= 1, got {self.fraction}")
        if self.kind in ("bias", "drift") and (self.value is None or not math.isfinite(self.value)):
            raise ValueError(f"sensor fault {self.kind!r} needs a finite value")

    def required_value(self) -> float:
        """``value`` of a fault that needs one (bias, drift: checked at construction)."""
        if self.value is None:
            raise ValueError(f"sensor fault {self.kind!r} needs a finite value")
        return self.value

    def to_dict(self) -> dict:
        return {"kind": self.kind, "start_s": self.start_s,
                "duration_s": None if math.isinf(self.duration_s) else self.duration_s,
                "value": self.value, "fraction": self.fraction}


# ----------------------------------------------------------------------------------------------------------------
# Parameter trajectories
# ----------------------------------------------------------------------------------------------------------------
def modal_trajectories(modes: Sequence[PlantMode], t: np.ndarray,
                       changes: Sequence[ModalChange] = ()) -> np.ndarray:
    """Per-sample modal truth ``(K_plant, N, 3)``: natural frequency (Hz), damping ratio, gain."""
    t = np.asarray(t, dtype=float)
    out = np.empty((len(modes), t.size, 3))
    for i, m in enumerate(modes):
        out[i] = m.modal
    for c in changes:
        if not 0 <= c.mode < len(modes):
            raise ValueError(f"change refers to mode {c.mode}, the plant has {len(modes)} modes (0-based)")
        if modes[c.mode].rigid and c.quantity != "gain":
            raise ValueError(f"mode {c.mode} is rigid-body: only its gain can change")
        out[c.mode, :, SIM_QUANTITIES.index(c.quantity)] *= 1.0 + c.relative_change * c.profile(t)
    return out


def thetas_from_modal(modal: np.ndarray, modes: Sequence[PlantMode]) -> list[np.ndarray]:
    """``theta_i(t_k) = [a1, a2, b0]`` ([RA-SRIVC] eq. 7, 16-17) per sample, or ``[b0]`` for rigid-body modes."""
    thetas = []
    for i, m in enumerate(modes):
        f, z, g = modal[i, :, 0], modal[i, :, 1], modal[i, :, 2]
        if m.rigid:
            thetas.append(g[:, None].copy())
        else:
            w = TWO_PI * f
            thetas.append(np.column_stack((2.0 * z / w, 1.0 / w**2, g)))
    return thetas


def modal_from_thetas(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure]) -> np.ndarray:
    """Inverse of :func:`thetas_from_modal`: ``(K, N, 3)`` f_hz, zeta, gain (rigid body: 0, 0, b0)."""
    out = []
    for th, s in zip(thetas, structures, strict=True):
        th = np.atleast_2d(th)
        if s.n == 0:
            out.append(np.column_stack((np.zeros(len(th)), np.zeros(len(th)), th[:, 0])))
        else:
            a1, a2, b0 = th[:, 0], th[:, 1], th[:, 2]
            out.append(np.column_stack((*second_order_modal(a1, a2), b0)))
    return np.stack(out)


# ----------------------------------------------------------------------------------------------------------------
# Signal generators (reference / open-loop input) and noise
# ----------------------------------------------------------------------------------------------------------------
def time_vector(rate_hz: float, duration_s: float) -> np.ndarray:
    """``t_k = k / rate_hz`` for ``k = 0 .. round(duration_s * rate_hz) - 1``."""
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    n = int(round(duration_s * rate_hz))
    if n < 1:
        raise ValueError(f"duration {duration_s} s is shorter than one sample at {rate_hz} Hz")
    return np.arange(n) / float(rate_hz)


def sum_of_sines(t: np.ndarray, amplitudes: Sequence[float] | np.ndarray, omegas_rad_s: Sequence[float] | np.ndarray,
                 phases: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """``sum_j A_j sin(w_j t + phi_j)`` ([RA-SRIVC] §5 reference: ``3 sin(0.005t) + sin 2t + sin 5t + sin 17.5t``)."""
    t = np.asarray(t, dtype=float)
    amps, omegas = np.asarray(amplitudes, float), np.asarray(omegas_rad_s, float)
    phis = np.zeros_like(omegas) if phases is None else np.asarray(phases, float)
    if not (amps.shape == omegas.shape == phis.shape):
        raise ValueError("amplitudes, omegas and phases must have the same length")
    out = np.zeros_like(t)
    for a, w, ph in zip(amps, omegas, phis, strict=True):
        out += a * np.sin(w * t + ph)
    return out


def multisine(t: np.ndarray, freqs_hz: Sequence[float] | np.ndarray, rms: float,
              rng: np.random.Generator) -> np.ndarray:
    """Equal-amplitude multisine with uniformly random phases, scaled to the given RMS."""
    freqs = np.asarray(freqs_hz, float)
    if freqs.size == 0 or np.any(freqs <= 0):
        raise ValueError("multisine needs positive frequencies")
    phases = rng.uniform(0.0, TWO_PI, freqs.size)
    amp = rms * math.sqrt(2.0 / freqs.size)  # each sine has RMS amp/sqrt(2)
    return sum_of_sines(t, np.full(freqs.size, amp), TWO_PI * freqs, phases)


def square_wave(t: np.ndarray, freq_hz: float, amplitude: float = 1.0, offset: float = 0.0,
                duty: float = 0.5) -> np.ndarray:
    """``offset + amplitude`` for the first ``duty`` of each period, ``offset - amplitude`` otherwise."""
    if not (freq_hz > 0 and 0.0 < duty < 1.0):
        raise ValueError("square wave needs freq_hz > 0 and 0 < duty < 1")
    # integer sample phase avoids floating drift in the switching instants
    phase = np.mod(np.asarray(t, float) * freq_hz, 1.0)
    return offset + amplitude * np.where(phase < duty, 1.0, -1.0)


def white_noise(n: int, std: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian white noise of standard deviation ``std``."""
    return std * rng.standard_normal(n)


def prbs(n: int, amplitude: float, rng: np.random.Generator, nbits: int = 10, hold: int = 1) -> np.ndarray:
    """Maximum-length pseudo-random binary sequence (+/- amplitude), random LFSR start, each bit held ``hold``."""
    from scipy import signal

    if not (2 <= nbits <= 32 and hold >= 1):
        raise ValueError("prbs needs 2 <= nbits <= 32 and hold >= 1")
    state = rng.integers(0, 2, nbits)
    if not state.any():
        state[0] = 1
    nbits_needed = -(-n // hold)
    period = 2**nbits - 1
    seq, _ = signal.max_len_seq(nbits, state=state, length=min(nbits_needed, period))
    seq = np.resize(seq, nbits_needed)
    return amplitude * (2.0 * np.repeat(seq, hold)[:n] - 1.0)


def arma_noise(n: int, std: float, rng: np.random.Generator, c: Sequence[float] | np.ndarray = (1.0,),
               d: Sequence[float] | np.ndarray = (1.0,)) -> np.ndarray:
    """Coloured noise ``v = C(q^-1)/D(q^-1) e`` (scipy.signal.lfilter), scaled so that its stationary std is ``std``.

    The stationary variance is computed from the impulse response (D must be stable); a burn-in of
    the filter's settling time is discarded so that ``v`` is stationary from the first sample.
    """
    from scipy import signal

    c, d = np.asarray(c, float), np.asarray(d, float)
    if d.size == 0 or d[0] == 0.0:
        raise ValueError("ARMA denominator must start with a non-zero coefficient")
    roots = np.roots(d) if d.size > 1 else np.array([])
    if np.any(np.abs(roots) >= 1.0):
        raise ValueError("ARMA denominator must be stable (roots inside the unit circle)")
    rho = float(np.max(np.abs(roots))) if roots.size else 0.0
    burn = int(min(1e6, 40.0 / max(1.0 - rho, 1e-6))) if rho > 0 else c.size
    imp = signal.lfilter(c, d, np.r_[1.0, np.zeros(burn + c.size)])
    gain = math.sqrt(float(np.sum(imp**2)))
    e = rng.standard_normal(n + burn)
    v = signal.lfilter(c, d, e)[burn:]
    return v * (std / gain) if gain > 0 else v


# ----------------------------------------------------------------------------------------------------------------
# Driver
# ----------------------------------------------------------------------------------------------------------------
@dataclass
class SimulationResult:
    """Simulated samples and their truth. ``modal`` is ``(K_plant, N, 3)``: f_hz, zeta, gain per sample."""

    t: np.ndarray
    r: np.ndarray | None
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    v: np.ndarray
    theta: list[np.ndarray]
    modal: np.ndarray
    structures: list[SubmodelStructure]
    rate_hz: float
    input_delay: int
    controller: DiscreteController | None
    sensor_faults: list[SensorFault] = field(default_factory=list)
    nan_mask: np.ndarray | None = None
    drop_mask: np.ndarray | None = None


def _sensor_arrays(t: np.ndarray, faults: Sequence[SensorFault], rng: np.random.Generator):
    n = t.size
    add, stuck_val = np.zeros(n), np.zeros(n)
    stuck, hold, nanm = (np.zeros(n, dtype=np.bool_) for _ in range(3))
    stuck_at_onset: list[tuple[np.ndarray, int]] = []
    for f in faults:
        win = (t >= f.start_s) & (t < f.start_s + f.duration_s)
        if f.kind == "bias":
            add[win] += f.required_value()
        elif f.kind == "drift":
            add[win] += f.required_value() * (t[win] - f.start_s)
        elif f.kind == "stuck":
            stuck |= win
            if f.value is None:
                stuck_at_onset.append((win, int(np.argmax(win)) if win.any() else -1))
            else:
                stuck_val[win] = f.value
        else:
            hit = win & (rng.random(n) < f.fraction)
            if f.kind == "drop":
                hold |= hit
            else:
                nanm |= hit
    return add, stuck, stuck_val, hold, nanm, stuck_at_onset


def simulate(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], rate_hz: float, *,
             r: np.ndarray | None = None, u: np.ndarray | None = None,
             controller: DiscreteController | None = None, input_delay: int = 0,
             noise: np.ndarray | None = None, sensor_faults: Sequence[SensorFault] = (),
             rng: np.random.Generator | None = None, n: int | None = None,
             modal: np.ndarray | None = None) -> SimulationResult:
    """Simulate the additive plant ([RA-SRIVC] eq. 5, 10) exactly at the samples.

    ``thetas[i]`` is ``(N, n_theta_i)`` (one row per sample, [RA-SRIVC] eq. 7 order) or ``(n_theta_i,)`` for a constant
    mode; ``structures[i]`` must be a mode (n = 2, m = 0) or a rigid body (n = 0, m = 0, integrators >= 1).
    Closed loop: give ``r`` and ``controller``. Open loop: give ``u``. ``noise`` is ``v(t_k)`` (default 0).
    ``modal`` (optional, ``(K, N, 3)``) is the precomputed modal truth of ``thetas``.
    """
    if len(thetas) != len(structures) or len(thetas) == 0:
        raise ValueError("need one theta trajectory per structure and at least one mode")
    closed = controller is not None
    given = r if closed else u
    if closed and (r is None or u is not None):
        raise ValueError("closed loop needs r (and no u); open loop needs u and no controller")
    if given is None:
        raise ValueError("open loop needs the input u (or give a controller and r for closed loop)")
    drive, n = check_drive(given, n, rate_hz, input_delay)
    theta, kinds, ls, full_thetas = pack_thetas(thetas, structures, n)
    rng = np.random.default_rng(0) if rng is None else rng
    v = np.zeros(n) if noise is None else np.asarray(noise, dtype=float)
    if v.shape != (n,):
        raise ValueError(f"noise has shape {v.shape}, expected ({n},)")
    t = np.arange(n) / float(rate_hz)
    add, stuck, stuck_val, hold, nanm, onset = _sensor_arrays(t, sensor_faults, rng)
    num = controller.num if controller is not None else np.zeros(1)
    den = controller.den if controller is not None else np.ones(1)
    u_out, y, x, e = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for win, k in onset:  # "stuck at the value at onset": the measurement just before the sensor froze
        if k >= 0:
            stuck_val[win] = _clean_meas_at(theta, kinds, ls, rate_hz, closed, drive, v, input_delay, num, den,
                                            add, stuck, stuck_val, hold, k)
    simulate_kernel(theta, kinds, ls, 1.0 / rate_hz, closed, drive, drive, v, input_delay, num, den, add, stuck,
                     stuck_val, hold, nanm, u_out, y, x, e)
    structures = list(structures)
    return SimulationResult(
        t=t, r=drive.copy() if closed else None, u=u_out, y=y, x=x, v=v, theta=full_thetas,
        modal=modal_from_thetas(full_thetas, structures) if modal is None else modal, structures=structures,
        rate_hz=float(rate_hz),
        input_delay=int(input_delay), controller=controller, sensor_faults=list(sensor_faults),
        nan_mask=nanm, drop_mask=hold)


def _clean_meas_at(theta, kinds, ls, rate_hz, closed, drive, v, delay, num, den, add, stuck, stuck_val, hold,
                   k: int) -> float:
    """Measurement (noise and earlier faults included) at sample ``k`` before a stuck fault starting there."""
    m = k + 1
    st = stuck[:m].copy()
    st[k] = False
    u, y, x, e = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)
    simulate_kernel(theta[:m], kinds, ls, 1.0 / rate_hz, closed, drive[:m], drive[:m], v[:m], delay, num, den,
                     add[:m], st, stuck_val[:m], hold[:m], np.zeros(m, np.bool_), u, y, x, e)
    return float(y[k])


def simulate_modes(modes: Sequence[PlantMode], rate_hz: float, *, changes: Sequence[ModalChange] = (),
                   r: np.ndarray | None = None, u: np.ndarray | None = None,
                   controller: DiscreteController | None = None, input_delay: int = 0,
                   noise: np.ndarray | None = None, sensor_faults: Sequence[SensorFault] = (),
                   rng: np.random.Generator | None = None) -> SimulationResult:
    """:func:`simulate` for a plant given in modal form with per-sample changes (manipulations, faults)."""
    n = np.asarray(r if r is not None else u).size
    t = np.arange(n) / float(rate_hz)
    modal = modal_trajectories(modes, t, changes)
    return simulate(thetas_from_modal(modal, modes), [m.structure for m in modes], rate_hz, r=r, u=u,
                    controller=controller, input_delay=input_delay, noise=noise, sensor_faults=sensor_faults,
                    rng=rng, n=n, modal=modal)
