"""The flat state arrays of the recursive estimator ([RA-SRIVC] Algorithm 2): layout, construction, snapshot/restore.

All state the compiled loop (:mod:`.kernel`) reads and writes lives in one dict of numpy arrays, so a snapshot is a
copy of it and a restored estimator continues bit-identically. Here: the submodel kinds, the state's construction,
``P(0)`` and the filters from rest ([RA-SRIVC] Algorithm 2 step 1), the version upgrades of older snapshots, and the
conversion of the caller's samples into the kernel's contiguous arrays.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..model import SubmodelStructure
from . import kernel as kn

STATE_KEYS = ("kind", "lam", "muf", "cnum", "cden", "cfg_i", "cfg_f", "p0diag", "theta", "thf", "P", "S", "xs", "vin",
              "phi",
              "gam", "ubuf", "zbuf", "ce", "cz", "ist", "fst", "proj", "rej", "rejr")
_INT_KEYS = ("kind", "cfg_i", "ist", "proj", "rej", "rejr")
# 2: filter model "thf", "muf"; version-1 snapshots load with thf = theta, muf = 0 (Algorithm 2)
# 3: rejections per reason "rejr" and the non-finite instrument counter in "ist"; older snapshots load with zeros
# 4: IV sandwich accumulator "S"; older snapshots load with S = P^-1 / (1 + lambda) (stationary)
# 5: a rigid body's free response c0, c1 in slots 1, 2 of theta, P, S; older snapshots start it
#    unknown
STATE_VERSION = 5


def kind_of(s: SubmodelStructure) -> int:
    """Kernel mode kind: 0 = second-order mode, l = rigid body ``b0/p^l``."""
    if s.n == 2 and s.m == 0 and s.integrators == 0:
        return 0
    if s.n == 0 and s.m == 0 and s.integrators in (1, 2):
        return s.integrators
    raise ValueError(f"unsupported submodel {s}: the recursive engine supports b0/(a2 p^2 + a1 p + 1) "
                     "and rigid-body b0/p^l (l = 1, 2)")


def structure_of(kind: int) -> SubmodelStructure:
    """The submodel of a kernel mode kind (inverse of :func:`kind_of`)."""
    return SubmodelStructure(2, 0, 0) if kind == 0 else SubmodelStructure(0, 0, int(kind))


def p0_diagonal(theta: np.ndarray, kind: int, p0_relative: tuple[float, float]) -> np.ndarray:
    """``P_i(0)`` diagonal scaled with the parameters: ``rho_a^2 a_j^2`` and ``rho_b^2 b0^2``."""
    ra, rb = p0_relative
    out = np.zeros(kn.NT)
    th = np.abs(np.asarray(theta, dtype=float))
    th = np.maximum(th, 1e-300)
    if kind == 0:
        out[:3] = [ra * th[0] ** 2, ra * th[1] ** 2, rb * th[2] ** 2]
    else:
        out[0] = rb * th[0] ** 2
        out[1:1 + kind] = kn.P0_FREE   # the free response c0 (, c1): core/estimation/kernel.py free_response_step
    return out


def stationary_sandwich(p: np.ndarray, lam: float) -> np.ndarray:
    """``S`` that makes ``P S P^T = P/(1 + lam)``: ``S = P^-1/(1 + lam)`` (symmetrized). For stationary signals
    ``P ~ (1 - lam) Rbar^-1`` and ``S ~ Rbar/(1 - lam^2)`` (``RecursiveAdditiveSRIVC.covariances``), so this is the
    sandwich of an estimator already in its stationary regime: the start of the accumulator when ``P(0)`` is not
    an information (parameter-scaled diagonal) or a snapshot predates it. Zeros if ``P`` is not invertible."""
    p = np.asarray(p, dtype=float)
    try:
        s = np.linalg.inv(p) / (1.0 + lam)
    except np.linalg.LinAlgError:
        return np.zeros_like(p)
    if not np.all(np.isfinite(s)):
        return np.zeros_like(p)
    return 0.5 * (s + s.T)


def initial_thetas(structures: list[SubmodelStructure], theta0: Any, kind: np.ndarray) -> np.ndarray:
    """``theta0`` checked and padded to the kernel's ``(K, NT)`` rows; second-order modes reflected into the stable
    region ([RA-SRIVC] §4.7)."""
    theta = np.zeros((len(structures), kn.NT))
    for i, (th, st) in enumerate(zip(theta0, structures, strict=True)):
        th = np.asarray(th, dtype=float).ravel()
        if th.shape != (st.n_theta,) or not np.all(np.isfinite(th)):
            raise ValueError(f"theta0[{i}] must be {st.n_theta} finite values, got {th}")
        if kind[i] == 0:
            a1, a2, flag = kn.project_second_order(th[0], th[1])
            if a2 == 0.0:
                raise ValueError(f"theta0[{i}]: a2 must be non-zero")
            th = np.array([a1, a2, th[2]])
        theta[i, :th.size] = th
    return theta


def new_state(kind: np.ndarray, theta: np.ndarray, rate_hz: float, controller: Any, *, input_delay: int,
              block_sweeps: int, refinements: int, projection: bool, subsampling: int, hold_len: int,
              max_step: float, p_cap: float) -> dict[str, np.ndarray]:
    """The kernel's state arrays for a fresh estimator (forgetting, filter model and ``P(0)`` still zero)."""
    K = kind.size
    if controller is not None:
        cnum, cden = controller.num.astype(float), controller.den.astype(float)
    else:
        cnum, cden = np.zeros(1), np.ones(1)
    d = int(input_delay)
    return {
        "kind": kind,
        "lam": np.zeros(K),
        "muf": np.zeros(K),
        "cnum": np.ascontiguousarray(cnum),
        "cden": np.ascontiguousarray(cden),
        "cfg_i": np.array([K, d, int(block_sweeps), int(refinements), int(bool(projection)), int(subsampling),
                           int(controller is not None), hold_len], dtype=np.int64),
        "cfg_f": np.array([1.0 / rate_hz, 0.0, float(max_step), float(p_cap), 0.0]),
        "p0diag": np.zeros((K, kn.NT)),
        "theta": theta,
        "thf": theta.copy(),
        "P": np.zeros((K, kn.NT, kn.NT)),
        "S": np.zeros((K, kn.NT, kn.NT)),
        "xs": np.zeros((K, kn.N_BANKS, 2)),
        "vin": np.zeros((K, 2)),
        "phi": np.zeros((K, 2, 2)),
        "gam": np.zeros((K, 2)),
        "ubuf": np.zeros(d + 1),
        "zbuf": np.zeros(d + 1),
        "ce": np.zeros(max(cnum.size - 1, 1)),
        "cz": np.zeros(max(cden.size - 1, 1)),
        "ist": np.zeros(kn.N_IST, dtype=np.int64),
        "fst": np.zeros(kn.N_FST),
        "proj": np.zeros(K, dtype=np.int64),
        "rej": np.zeros(K, dtype=np.int64),
        "rejr": np.zeros((K, kn.N_REJ), dtype=np.int64),
    }


def hold_length(theta: np.ndarray, kind: np.ndarray, rate_hz: float, reprime_s: float | None) -> int:
    """Samples without updates after a gap: ``reprime_s`` (default 5 slowest time constants ``2 a2/a1``)."""
    if reprime_s is None:
        taus = [2.0 * theta[i, 1] / theta[i, 0] for i in range(kind.size) if kind[i] == 0 and theta[i, 0] > 0]
        reprime_s = 5.0 * max(taus) if taus else 1.0
    return int(min(max(math.ceil(reprime_s * rate_hz), 10), 600 * rate_hz))


def reset_covariance(s: dict[str, np.ndarray], p0_relative: tuple[float, float]) -> None:
    """``P_i(0)`` the parameter-scaled diagonal, ``S_i(0)`` its stationary sandwich."""
    for i in range(int(s["cfg_i"][kn.C_K])):
        diag = p0_diagonal(s["theta"][i], int(s["kind"][i]), p0_relative)
        s["p0diag"][i] = diag
        s["P"][i] = np.diag(diag)
        nt = kn.n_kernel_params(int(s["kind"][i]))
        s["S"][i] = 0.0
        s["S"][i][:nt, :nt] = stationary_sandwich(s["P"][i][:nt, :nt], float(s["lam"][i]))


def refresh_filters(s: dict[str, np.ndarray]) -> None:
    """Cache ``Phi, Gamma`` of the current filter model (the kernel keeps them in step afterwards)."""
    h = float(s["cfg_f"][kn.C_H])
    for i in range(int(s["cfg_i"][kn.C_K])):
        th = s["thf"][i]
        kn.discretize_mode(int(s["kind"][i]), float(th[0]), float(th[1]), h, s["phi"][i], s["gam"][i])


def reset_filters(s: dict[str, np.ndarray]) -> None:
    """Filters, delay line and controller memory from rest (before priming); a rigid body's free response is
    unknown again (core/estimation/kernel.py ``restart_free_response``)."""
    for key in ("xs", "vin", "ubuf", "zbuf", "ce", "cz"):
        s[key][...] = 0.0
    s["ist"][kn.I_POS] = 0
    kn.restart_free_response(s["kind"], s["theta"], s["thf"], s["P"], s["S"], s["p0diag"])


def snapshot(s: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Complete state as a dict of numpy arrays (copies) with its ``version``."""
    out = {k: s[k].copy() for k in STATE_KEYS}
    out["version"] = np.array([STATE_VERSION], dtype=np.int64)
    return out


def _upgraded(state: Mapping[str, np.ndarray], s: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """An older snapshot with the keys of :data:`STATE_VERSION` (see the version notes above)."""
    state = dict(state)
    K = int(s["cfg_i"][kn.C_K])
    if "thf" not in state and "theta" in state:
        state["thf"] = np.asarray(state["theta"], dtype=float).copy()
    if "muf" not in state and "lam" in state:
        state["muf"] = np.zeros(np.asarray(state["lam"]).shape)
    if "S" not in state and "P" in state:   # version <= 3: no IV sandwich accumulator, start it stationary
        lam = np.broadcast_to(np.asarray(state.get("lam", s["lam"]), dtype=float), (K,))
        state["S"] = np.zeros(np.asarray(state["P"]).shape)
        for i, p in enumerate(np.asarray(state["P"], dtype=float)):
            nt = kn.NT if int(np.asarray(state["kind"])[i]) == 0 else 1
            state["S"][i][:nt, :nt] = stationary_sandwich(p[:nt, :nt], float(lam[i]))
    if "rejr" not in state:   # version <= 2: no per-reason counts, shorter int state
        state["rejr"] = np.zeros_like(s["rejr"])
    if "ist" in state and np.asarray(state["ist"]).shape[0] < kn.N_IST:
        state["ist"] = np.concatenate((np.asarray(state["ist"], dtype=np.int64),
                                       np.zeros(kn.N_IST - np.asarray(state["ist"]).shape[0], dtype=np.int64)))
    return state


def restore(s: dict[str, np.ndarray], state: Mapping[str, np.ndarray]) -> None:
    """Copy a :func:`snapshot` (any version) into ``s``; shapes and submodel kinds must match."""
    state = _upgraded(state, s)
    for k in STATE_KEYS:
        if k not in state:
            raise ValueError(f"state is missing '{k}'")
        a = np.asarray(state[k])
        if a.shape != s[k].shape:
            raise ValueError(f"state '{k}' has shape {a.shape}, this estimator needs {s[k].shape}")
    if not np.array_equal(np.asarray(state["kind"]), s["kind"]):
        raise ValueError("state was saved for different submodel structures")
    for k in STATE_KEYS:
        dtype = np.int64 if k in _INT_KEYS else np.float64
        s[k][...] = np.asarray(state[k], dtype=dtype)
    if int(np.asarray(state.get("version", [0])).ravel()[0]) < 5:   # no free response: estimate it from now on
        kn.restart_free_response(s["kind"], s["theta"], s["thf"], s["P"], s["S"], s["p0diag"])


def save_state(path: str | Path, state: dict[str, np.ndarray]) -> None:
    """Write a :func:`snapshot` to an ``.npz`` file."""
    np.savez(Path(path), **state)  # type: ignore[arg-type]  # numpy>=2.1 stub: **kwds may fill allow_pickle


def load_state(path: str | Path) -> dict[str, np.ndarray]:
    """The snapshot :func:`save_state` wrote."""
    with np.load(Path(path)) as z:
        return {k: z[k] for k in z.files}


def sample_arrays(r: Any, u: Any, y: Any, valid: Any, closed_loop: bool) -> tuple[np.ndarray, ...]:
    """``r, u, y, valid`` as the kernel's contiguous float arrays and uint8 mask (``r`` zeros in open loop)."""
    u = np.ascontiguousarray(np.atleast_1d(np.asarray(u, dtype=float)).ravel())
    y = np.ascontiguousarray(np.atleast_1d(np.asarray(y, dtype=float)).ravel())
    n = u.size
    if y.size != n:
        raise ValueError(f"u and y must have the same length, got {n} and {y.size}")
    if r is None:
        if closed_loop:
            raise ValueError("closed loop: the reference r is needed for the instrument ([RA-SRIVC] eq. 33)")
        r = np.zeros(n)
    r = np.ascontiguousarray(np.atleast_1d(np.asarray(r, dtype=float)).ravel())
    if r.size != n:
        raise ValueError(f"r must have the same length as u, got {r.size} and {n}")
    if valid is None:
        v = np.ones(n, dtype=np.uint8)
    else:
        v = np.ascontiguousarray(np.broadcast_to(np.asarray(valid, dtype=bool), (n,)).astype(np.uint8))
    return r, u, y, v
