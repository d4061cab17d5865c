"""The start of the recursive estimator: the offline fit on the first data, the guesses as a prior, ``P(0)``.

[RA-SRIVC] Algorithm 2 needs a model to build its first filters: the offline additive (CL)SRIVC ([A-SRIVC] eqs.
20-29) on the initialization window replaces the guesses when it explains the data better, combined with them as a
prior (per mode, in modal coordinates; held-out data decide what the data do not inform), ``P_i(0)`` from its
information ([A-SRIVC] eq. 33, rescaled to the recursion's weighting) and ``S_i(0)`` from its sandwich, then the
filters are primed (Algorithm 2 step 1). :class:`OfflineStart` does this for a :class:`StartHost`, the estimator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from ..model import SubmodelStructure, modal_from_theta, theta_from_modal
from . import kernel as kn
from .recursive_report import covariance_problem
from .recursive_state import sample_arrays, stationary_sandwich


def p0_from_information(p_block: np.ndarray, n_samples: int, lam: float) -> np.ndarray | None:
    """``P_i(0)`` from an offline fit: its ``(sum_k zeta_i phi_i^T)^-1`` over ``n_samples`` samples ([A-SRIVC] eq. 33)
    rescaled to the exponential weighting of the recursion ([RA-SRIVC] eqs. 30-32, ``P^-1 <- lambda P^-1 + zeta
    phi^T``): the record's per-sample information times ``sum_k lambda^k = (1 - lambda^N)/(1 - lambda)``, i.e.
    ``P_i(0) = N (1 - lambda) / (1 - lambda^N) * p_block``. ``None`` if the block is not usable (non-finite or
    a non-positive diagonal)."""
    p = np.asarray(p_block, dtype=float)
    if n_samples < 1 or not np.all(np.isfinite(p)) or np.any(np.diag(p) <= 0.0) or not 0.0 < lam < 1.0:
        return None
    weight = n_samples * (1.0 - lam) / (1.0 - lam ** n_samples)
    return weight * p


def sandwich_from_offline(p0: np.ndarray, cov0: np.ndarray, sigma2_0: float) -> np.ndarray | None:
    """``S_i(0) = P_i(0)^-1 C_0 P_i(0)^-T / sigma_0^2``: the recursion starts at the offline estimate, whose error
    covariance ``C_0`` is the offline IV sandwich ([A-SRIVC] Theorem 1, its block of the joint matrix, so the coupling
    of the modes in the start record is in it); with it ``sigma^2 P S P^T`` equals ``C_0`` at the start and the
    ``lam^(2N) S(0)`` term forgets it like the recursion forgets ``theta_bar(0)``. ``None`` if not usable."""
    try:
        pinv = np.linalg.inv(np.asarray(p0, dtype=float))
    except np.linalg.LinAlgError:
        return None
    c0 = np.asarray(cov0, dtype=float)
    if not (np.isfinite(sigma2_0) and sigma2_0 > 0.0) or c0.shape != pinv.shape:
        return None
    s = pinv @ c0 @ pinv.T / sigma2_0
    s = 0.5 * (s + s.T)
    if not np.all(np.isfinite(s)) or covariance_problem(s):
        return None
    return s


class StartHost(Protocol):
    """What :class:`OfflineStart` uses of the estimator it starts (``RecursiveAdditiveSRIVC``)."""

    structures: list[SubmodelStructure]
    rate_hz: float
    controller: Any
    init_method: str
    init_max_iterations: int
    init_warmup_s: float | None
    guess_spread: float
    p0_policy: str
    init_message: str
    last_init: Any

    @property
    def K(self) -> int: ...
    @property
    def closed_loop(self) -> bool: ...
    @property
    def thetas(self) -> list[np.ndarray]: ...
    @property
    def arrays(self) -> dict[str, np.ndarray]: ...
    def reset(self, theta0: Sequence[np.ndarray] | None = None) -> None: ...
    def prime(self, r: Any, u: Any, y: Any, valid: Any = None) -> None: ...
    def output_error_variance(self, thetas: Sequence[np.ndarray], r: np.ndarray, u: np.ndarray, y: np.ndarray,
                              v: np.ndarray, start: int = 0) -> float: ...


class OfflineStart:
    """Robust start of one estimator (``est``): offline init, the guesses as a prior, ``P(0)``, then priming."""

    def __init__(self, est: StartHost) -> None:
        self.est = est

    def run(self, r: Any, u: Any, y: Any) -> Any:
        """Robust start: offline init, P(0) scaled per parameter, then priming.

        The offline estimate (``core.offline.identify``, [A-SRIVC] eqs. 20-29), combined with the guesses as a prior
        (:meth:`with_guess_prior`), replaces the guesses only when it is finite, stable and explains the data better
        (smaller output-error variance). Returns the ``IdentificationResult`` or ``None`` (no offline core,
        ``init_method="none"`` or failure).
        """
        est = self.est
        r, u, y, v = sample_arrays(r, u, y, None, est.closed_loop)
        result = None
        accepted = False
        guesses = est.thetas
        if est.init_method != "none" and u.size > 0:
            try:
                from ..identification.offline import identify
            except ImportError:  # pragma: no cover - offline core not installed
                est.init_message = "offline core unavailable: using the guesses"
            else:
                def fit_once(r: np.ndarray, u: np.ndarray, y: np.ndarray) -> Any:
                    ok = np.isfinite(u) & np.isfinite(y) & (np.isfinite(r) if est.closed_loop else True)
                    return identify(u[ok], y[ok], est.rate_hz, est.structures, guesses,
                                    r=r[ok] if est.closed_loop else None, controller=est.controller,
                                    input_delay=int(est.arrays["cfg_i"][kn.C_DELAY]), method=est.init_method,
                                    max_iterations=est.init_max_iterations, warmup_s=est.init_warmup_s)
                try:
                    result = fit_once(r, u, y)
                except Exception as exc:  # noqa: BLE001 - any failure falls back to the guesses
                    est.init_message = f"offline init failed ({type(exc).__name__}: {exc}); using the guesses"
                    result = None
                if result is not None:
                    accepted = self._accept(result, guesses, (r, u, y, v), fit_once)
        elif est.init_method == "none":
            est.init_message = "initialized with the guesses (init_method none)"
        est.reset(est.thetas)
        if accepted and est.p0_policy == "information":
            self.covariance_from_information(result)
        est.arrays["fst"][:] = 0.0
        est.prime(r, u, y, v)
        est.last_init = result
        return result

    def _accept(self, result: Any, guesses: list[np.ndarray], data: tuple[np.ndarray, ...], fit_once: Any) -> bool:
        """Start from the fit (with the guesses' prior) if it is usable and explains ``data`` no worse than the
        guesses (output-error variance of a primed copy); the reason goes to ``init_message``."""
        est = self.est
        r, u, y, v = data
        cand = [np.asarray(t, dtype=float) for t in result.thetas]
        usable = all(np.all(np.isfinite(t)) for t in cand) and all(
            t[0] > 0 and t[1] > 0 for t, k in zip(cand, est.arrays["kind"], strict=True) if k == 0)
        if not usable:
            est.init_message = "offline init rejected (non-finite or unstable)"
            return False
        e_new = est.output_error_variance(cand, r, u, y, v)
        e_old = est.output_error_variance(guesses, r, u, y, v)
        if not (np.isfinite(e_new) and not e_new > e_old):
            est.init_message = f"offline init rejected (worse fit {e_new:.3g} > {e_old:.3g})"
            return False
        # the fit explains the data better: its posterior with the guesses is the start (between the two, so its
        # error is judged through the fit's; in-sample it may be a hair worse)
        cand, prior_note = self.with_guess_prior(guesses, cand, result, (r, u, y, v), fit_once)
        e_post = est.output_error_variance(cand, r, u, y, v) if prior_note else e_new
        est.reset(cand)
        est.init_message = (f"offline init ({getattr(result, 'message', '')}){prior_note}: "
                            f"output-error variance {e_old:.3g} -> {e_post:.3g} (fit {e_new:.3g})")
        return True

    HELD_OUT = 1.0 / 3.0   # the last third of the initialization window judges the guesses against the fit

    def uninformed(self, guesses: list[np.ndarray], data: tuple[np.ndarray, ...], fit_once: Any,
                    ) -> set[tuple[int, int]]:
        """(mode, quantity) pairs the data do not inform: the guess predicts data *not used to fit* as well.

        The offline fit of the first two thirds of the window (``fit_once(r, u, y)``) predicts the last third by its
        output ``y_fit = sum_i G_i u`` (the models run over the whole window; a rigid body's free response is
        projected out). So does the same fit with one mode's shape (natural frequency and damping) put back to its
        guess, and with its gain put back: ``y_fit - delta``. The guess's squared error exceeds the fit's by
        ``mean(delta^2 + 2 e delta)`` with ``e = y - y_fit``, whose noise part has the std ``2 sigma rms(delta) /
        sqrt(n)``; the fit is preferred only when it predicts significantly better (2 stds). In-sample, a mode no
        reference line reaches can take any shape and still lower the error by fitting noise (measured: a 3.2 Hz mode
        fitted at 1.5 Hz with std 0.2 %), while its gain is informed by the lines below it (its static part).
        """
        from ..identification.offline import integrator_free_response
        from ..plant import open_loop_output

        r, u, y, _ = data
        split = int(round(u.size * (1.0 - self.HELD_OUT)))
        if split < 10 or u.size - split < 10 or not np.all(np.isfinite(u)):
            return set()
        try:
            head = fit_once(r[:split], u[:split], y[:split])
        except Exception:  # noqa: BLE001 - no held-out judgement without a fit: the whole-window fit decides
            return set()
        fit = [np.asarray(t, dtype=float) for t in head.thetas]
        if not all(np.all(np.isfinite(t)) for t in fit):
            return set()
        delay = int(self.est.arrays["cfg_i"][kn.C_DELAY])
        ints = max(st.integrators for st in self.est.structures)
        basis = integrator_free_response(u.size, ints, 1.0 / self.est.rate_hz) if ints else None

        def detrended(x: np.ndarray) -> np.ndarray:
            return x if basis is None else x - basis @ (basis.T @ x)

        def output(thetas: list[np.ndarray]) -> np.ndarray:
            return detrended(open_loop_output(thetas, self.est.structures, self.est.rate_hz, u, delay))

        y_fit = output(fit)
        finite = np.isfinite(y)
        tail = (np.arange(u.size) >= split) & finite
        e = (detrended(np.where(finite, y, 0.0)) - y_fit)[tail]
        n = e.size
        if n < 10 or not np.all(np.isfinite(e)):
            return set()
        sigma = float(np.sqrt(np.mean(e * e)))
        out: set[tuple[int, int]] = set()
        for i, st in enumerate(self.est.structures):
            mg, mf = modal_from_theta(guesses[i], st), modal_from_theta(fit[i], st)
            parts = [((0, 1), (mg[0], mg[1], mf[2])), ((2,), (mf[0], mf[1], mg[2]))] if st.n == 2 else [((2,), None)]
            for qs, modal in parts:
                if modal is not None and not np.all(np.isfinite(modal)):
                    continue
                theta = guesses[i] if modal is None else theta_from_modal(*modal)
                delta = (y_fit - output([theta if k == i else f for k, f in enumerate(fit)]))[tail]
                if not np.all(np.isfinite(delta)):
                    continue
                worse = float(np.mean(delta * delta + 2.0 * e * delta))
                if worse <= 2.0 * 2.0 * sigma * float(np.sqrt(np.mean(delta * delta))) / np.sqrt(n):
                    out |= {(i, q) for q in qs}
        return out

    def with_guess_prior(self, guesses: list[np.ndarray], fit: list[np.ndarray], result: Any,
                          data: tuple[np.ndarray, ...], fit_once: Any) -> tuple[list[np.ndarray], str]:
        """The offline fit combined with the guesses as a prior (guesses are a prior, not the answer).

        In modal coordinates ``m = (f, zeta, gain)`` per mode: prior ``N(m_g, diag((s m_g)^2))`` with ``s`` =
        ``guess_spread`` (a tiny spread for what :meth:`uninformed` finds, and for a mode the fit leaves
        without a modal form), data ``N(m_f, C_f)`` with ``C_f`` the fit's joint covariance of every mode
        ([A-SRIVC] Theorem 1 sandwich, delta method); the start is the posterior mean ``m_g + P (P + C_f)^-1 (m_f -
        m_g)``: the fit where its data inform, the guesses where they do not, per mode (within a mode the covariance of
        gain and damping carries the other along the resonance peak). Only second-order modes and rigid bodies
        (their gain); otherwise the fit.
        Returns ``(thetas, note)``.
        """
        from ..diagnosis.joint_check import joint_modal_covariance

        s = self.est.guess_spread
        sts = self.est.structures
        cov = getattr(result, "covariance", None)
        if s <= 0.0 or not all(st.m == 0 and st.n in (0, 2) for st in sts) or cov is None or \
                not np.all(np.isfinite(cov)):
            return fit, ""
        mf = np.array([modal_from_theta(t, st) for t, st in zip(fit, sts, strict=True)])
        mg = np.array([modal_from_theta(t, st) for t, st in zip(guesses, sts, strict=True)])
        app = np.array([[st.n == 2, st.n == 2, True] for st in sts])
        kept = self.uninformed(guesses, data, fit_once)
        kept |= {(i, q) for i in range(self.est.K) if not np.all(np.isfinite(mf[i][app[i]])) for q in range(3)}
        use = (app & np.isfinite(mg) & (mg != 0.0)).ravel()
        idx = np.flatnonzero(use)
        spread = np.array([1e-6 if (i, q) in kept else s for i in range(self.est.K) for q in range(3)])
        post = mg.ravel().copy()
        if idx.size:
            C = joint_modal_covariance(fit, sts, cov)[np.ix_(idx, idx)]
            lost = ~np.isfinite(np.diag(C)) | ~np.isfinite(mf.ravel()[idx])   # no modal form: the fit says nothing
            C[lost, :] = C[:, lost] = 0.0
            C[lost, lost] = (1e6 * mg.ravel()[idx][lost]) ** 2
            C = np.where(np.isfinite(C), C, 0.0)
            P = np.diag((spread[idx] * mg.ravel()[idx]) ** 2)
            d = np.where(np.isfinite(mf.ravel()[idx]), mf.ravel()[idx] - mg.ravel()[idx], 0.0)
            # per mode (its gain and damping trade along a resonance), not across modes: linear conditioning on a mode
            # the fit put far from its guess (a wrong optimum) moved the informed modes by more than their error
            # (measured: mode 1 by 6 %)
            mode_of = idx // 3
            for i in np.unique(mode_of):
                b = mode_of == i
                if (i, 0) in kept:       # the guessed shape predicted as well with the fit's gain: keep that pair
                    b &= idx % 3 == 2
                    post[idx[b]] = mg.ravel()[idx[b]] + np.diag(P)[b] / (np.diag(P)[b] + np.diag(C)[b]) * d[b]
                    continue
                try:
                    post[idx[b]] = mg.ravel()[idx[b]] + P[np.ix_(b, b)] @ np.linalg.solve(
                        P[np.ix_(b, b)] + C[np.ix_(b, b)], d[b])
                except np.linalg.LinAlgError:
                    return fit, ""
        post_modal = post.reshape(self.est.K, 3)
        if not np.all(np.isfinite(post_modal[app])) or np.any(post_modal[:, :2][app[:, :2]] <= 0.0):
            return fit, ""
        out = [np.array([post_modal[i, 2]]) if st.n == 0 else theta_from_modal(*post_modal[i])
               for i, st in enumerate(sts)]
        names = [f"mode {i + 1} {'shape' if q == 0 else 'gain'}" for i, q in sorted(kept) if q != 1 and app[i, q]]
        note = f"; guesses as a prior (spread {100 * s:g} %)" + (
            f", kept: {', '.join(names)} (the guess predicts held-out data as well)" if names else "")
        return out, note

    def prior_p0(self, i: int, sigma2: float) -> np.ndarray | None:
        """``P_bar`` of mode ``i``'s guess as a prior (``guess_spread`` ``s``, relative, on f, zeta and gain alike):
        with ``a1 = 2 zeta / w``, ``a2 = 1/w^2``, ``b0 = g``, ``var ln a1 = 2 s^2``, ``var ln a2 = 4 s^2``,
        ``cov(ln a1, ln a2) = 2 s^2``, ``var ln b0 = s^2``, scaled by the coefficients and divided by ``sigma^2``
        (the recursion's covariance is ``sigma^2 P_bar``). None without a prior or a usable ``sigma^2``."""
        s, st = self.est.guess_spread, self.est.structures[i]
        if s <= 0.0 or not (np.isfinite(sigma2) and sigma2 > 0.0) or st.m != 0 or st.n not in (0, 2):
            return None
        th = np.abs(self.est.arrays["theta"][i, :st.n_theta])
        if st.n == 0:
            cov_ln = np.array([[1.0]])
        else:
            cov_ln = np.array([[2.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
        return s * s * cov_ln * np.outer(th, th) / sigma2

    def covariance_from_information(self, result: Any) -> None:
        """``P_i(0)`` from the accepted offline fit (:func:`p0_from_information`), combined with the guesses' prior
        (:meth:`prior_p0`: ``P^-1 = P_info^-1 + P_prior^-1``, so a mode the data hardly inform starts with the
        prior's adaptation gain, not an unbounded one); modes with neither keep the parameter-scaled diagonal."""
        s = self.est.arrays
        blocks = getattr(result, "p_blocks", None) or []
        n = int(getattr(result, "n_samples", 0))
        sigma2 = float(getattr(result, "residual_variance", math.nan))
        used = prior_used = 0
        for i, st in enumerate(self.est.structures):
            nt = st.n_theta
            p0 = p0_from_information(blocks[i], n, float(s["lam"][i])) if i < len(blocks) else None
            if p0 is not None and p0.shape != (nt, nt):
                p0 = None
            prior = self.prior_p0(i, sigma2)
            if prior is not None:
                try:
                    p0 = prior if p0 is None else np.linalg.inv(np.linalg.inv(p0) + np.linalg.inv(prior))
                    prior_used += 1
                except np.linalg.LinAlgError:
                    pass
            if p0 is None or not np.all(np.isfinite(p0)):
                continue
            p0 = 0.5 * (p0 + p0.T)
            s["P"][i][...] = 0.0
            s["P"][i][:nt, :nt] = p0
            s["p0diag"][i][...] = 0.0
            s["p0diag"][i][:nt] = np.diag(p0)
            covs = getattr(result, "covariances", None) or []
            s0 = sandwich_from_offline(p0, covs[i], sigma2) if i < len(covs) and prior is None else None
            s["S"][i][...] = 0.0
            s["S"][i][:nt, :nt] = s0 if s0 is not None else stationary_sandwich(p0, float(s["lam"][i]))
            used += 1
        self.est.init_message += f"; P(0) from the offline information for {used} of {self.est.K} modes" + (
            f" (with the guesses' prior for {prior_used})" if prior_used else "")

