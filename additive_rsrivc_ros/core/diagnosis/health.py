"""Estimator and data health, kept apart from the structural fault tests (S5 of :mod:`.faults`).

:class:`HealthMonitor` turns the estimate, the estimator's health record and the incidents the pipeline notes (data
gaps, stuck sensors, re-initializations) into a :class:`HealthStatus` per report: a diagnostic level, its reasons and
the holds (:class:`.decision.Hold`) that keep the fault tests back while the estimate re-converges.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..estimation.estimator import EstimatorHealth
from ..model import SubmodelStructure
from .decision import Hold
from .fault_settings import FaultSettings, Level

MODE_SCOPE = ":mode"
"""Key suffix of a health issue scoped to one mode (``loss_of_excitation:mode4``)."""


@dataclass
class HealthStatus:
    """Estimator/data health at one report (S5); ``hold`` means structural alarms are held back."""

    level: Level
    reasons: list[str]
    hold: bool                      # an issue holds every mode
    values: dict[str, Any]
    holds: list[Hold] = field(default_factory=list)   # every active hold (owner, reason, end, modes)

    def mode_hold(self, n_modes: int) -> np.ndarray:
        """(K,) bool: the mode's tests are held (by an issue of every mode or of its own)."""
        return np.array([any(h.holds(i) for h in self.holds) or self.hold for i in range(n_modes)], dtype=bool)

    @property
    def ok(self) -> bool:
        return self.level == Level.OK

    def to_dict(self) -> dict[str, Any]:
        return {"level": int(self.level), "ok": self.ok, "hold": self.hold, "reasons": list(self.reasons),
                **self.values}


class HealthMonitor:
    """Estimator health, separate from structural faults (S5).

    Issues are either *states* seen at an assessment (divergence, projection storm, loss of excitation,
    residual-variance jump) or *incidents* noted by the pipeline (:meth:`note`: data gap, non-finite or
    stuck sensor, out-of-order stamps, re-initialization). Each stays active for a hold-off of
    ``health.holdoff_memory_lengths`` x the longest memory after it was last seen, because the estimate
    needs that long to re-converge; an issue that a fresh offline initialization resolves ends sooner
    (:meth:`refitted`).
    """

    ERROR_KINDS = ("divergence", "stuck_sensor", "reinitializing", "no_valid_model", "time_scale")
    SHORT_KINDS = ("nonfinite", "outlier", "data_gap", "repriming", "duplicate_stamps", "out_of_order", "clock_step")
    """Data problems that do not move the estimate: skipped samples (no update; the kernel holds the input and
    predicts the output), samples dropped for their stamps (a recorder duplicate, a clock stepped back: the grid goes
    on as after a short gap) and breaks whose filter transient the estimator's own re-prime hold covers. They hold
    the tests while they last plus ``health.holdoff_min_s``, not for the re-convergence hold-off."""
    ADVISORY_KINDS = ("residual_jump", "projection_storm")
    """Also the signature of a genuine abrupt structural change: they do not hold structural alarms back,
    they only require that a confirmed fault began together with them (FaultMonitor ``suspect_since``)."""

    def __init__(self, memory_s: Sequence[float] | np.ndarray, settings: FaultSettings | None = None, *,
                 reference_modal: np.ndarray | None = None, structures: Sequence[SubmodelStructure] | None = None,
                 rate_hz: float | None = None) -> None:
        self.memory_s = np.asarray(memory_s, dtype=float)
        self.K = self.memory_s.size
        self.settings = settings or FaultSettings()
        self.structures = list(structures) if structures is not None else [SubmodelStructure()] * self.K
        self.reference_modal = None if reference_modal is None else np.asarray(reference_modal, float)[:, :3]
        self.rate_hz = rate_hz
        self.active: dict[str, tuple[float, str]] = {}   # kind -> (last seen time, message)
        self.first_seen: dict[str, float] = {}            # kind -> start of the current episode
        self.counts: dict[str, int] = {}
        self.residual_ref = math.nan
        self.last_projections: float | None = None
        self.last_samples: float | None = None
        self.t_last = math.nan

    @property
    def holdoff_s(self) -> float:
        s = self.settings
        return max(s.health_holdoff_min_s, s.health_holdoff_memory_lengths * float(self.memory_s.max()))

    def hold_of(self, kind: str) -> float:
        """Hold-off (s) after the last sighting of an issue of this kind (see ``SHORT_KINDS``)."""
        return self.settings.health_holdoff_min_s if kind in self.SHORT_KINDS else self.holdoff_s

    def note(self, kind: str, t: float, message: str, count: int = 1, *, mode: int | None = None) -> None:
        """Record an incident at time ``t`` (s); it stays active for the hold-off. ``mode`` (0-based) scopes it to
        one mode: it then holds that mode's tests only (:mod:`.decision`)."""
        key = kind if mode is None else f"{kind}{MODE_SCOPE}{mode + 1}"
        self.active[key] = (t, message)
        self.first_seen.setdefault(key, t)
        self.counts[kind] = self.counts.get(kind, 0) + count

    REFIT_KINDS = ("divergence", "no_valid_model", "reinitializing")
    """Issues that a fresh offline initialization on new data ends (:meth:`refitted`)."""

    def refitted(self, t: float) -> None:
        """A fresh offline initialization on data after a divergence or a model that was no valid model ([RA-SRIVC]
        Algorithm 2 step 1) succeeded at ``t``: its estimate is a converged fit of the new data, so those issues (and
        the collection that led to it) end after ``health.holdoff_min_s`` instead of the re-convergence hold-off."""
        keys = [k for k in self.active if k.partition(MODE_SCOPE)[0] in self.REFIT_KINDS]
        if not keys:
            return
        for key in keys + [k for k in self.active if k.partition(MODE_SCOPE)[0] == "initializing"]:
            t_seen, msg = self.active[key]
            end = t + self.settings.health_holdoff_min_s
            self.active[key] = (min(t_seen, end - self.hold_of(key.partition(MODE_SCOPE)[0])), msg)

    def clear_reference(self, modal: np.ndarray | None = None) -> None:
        """New reference for the parameter blow-up check (e.g. after a re-initialization)."""
        self.reference_modal = None if modal is None else np.asarray(modal, float)[:, :3].copy()
        self.residual_ref = math.nan

    def assess(self, t: float, modal: np.ndarray, est_health: EstimatorHealth | None = None) -> HealthStatus:
        """Check the estimate and the estimator's health record at time ``t`` and return the status (S5); a check
        whose item the estimator does not report (empty, ``None``) is skipped."""
        s = self.settings
        est = est_health if est_health is not None else EstimatorHealth()
        values: dict[str, Any] = {}
        modal = np.asarray(modal, dtype=float)
        # divergence: non-finite or blown-up parameters ([RA-SRIVC] §4.7 projection keeps A_i stable, not bounded)
        if not np.all(np.isfinite(modal[:, :3])):
            self.note("divergence", t, "divergence: non-finite estimate")
        elif self.reference_modal is not None:
            ref = self.reference_modal
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.abs(modal[:, :3] / ref)
            cols = [0, 2]
            r = ratio[:, cols]
            ok = np.isfinite(r) & (r > 0)
            bad = ok & ((r > s.health_max_parameter_ratio) | (r < 1.0 / s.health_max_parameter_ratio))
            bad |= ~ok & (ref[:, cols] != 0)
            if np.any(bad):
                i = int(np.argwhere(bad)[0][0])
                self.note("divergence", t, f"divergence: mode {i + 1} moved by more than a factor "
                          f"{s.health_max_parameter_ratio:g} from its reference")
        # loss of excitation: relative std of frequency / gain from sigma^2 P_bar (it winds up without excitation;
        # the published IV-sandwich std does not, core/estimation/recursive.py covariances); the reported std if not
        # given
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_std = np.abs(modal[:, 3:6] / modal[:, :3])
        rel = np.array([[rel_std[i, 0] if self.structures[i].n == 2 else 0.0, rel_std[i, 2]] for i in range(self.K)])
        if np.shape(est.information_relative_std) == (self.K,):
            rel = np.asarray(est.information_relative_std, dtype=float)[:, None]
        values["max_relative_std"] = float(np.nanmax(rel)) if np.any(np.isfinite(rel)) else math.nan
        for i in sorted({int(i) for i in np.argwhere(rel > s.health_max_relative_std)[:, 0]}):
            # a weakly excited mode blinds itself, not its neighbours (their estimates are judged on their own)
            self.note("loss_of_excitation", t, f"loss of excitation: mode {i + 1} relative std "
                      f"{np.nanmax(rel[i]):.2g} > {s.health_max_relative_std:g}", mode=i)
        # published std unavailable: a non-finite or indefinite covariance block reports NaN, never 0
        for i, p in enumerate(est.covariance_problems):
            if p:
                self.note("invalid_uncertainty", t, f"no valid uncertainty (std NaN): mode {i + 1} covariance "
                          f"block {p}", mode=i)
        if est.cond:
            conds = np.asarray(est.cond, float)
            c = float(np.nanmax(conds))
            values["condition"] = c
            per_mode = conds.shape == (self.K,)
            scopes: list[int | None] = list(range(self.K)) if per_mode else [None]
            for scope in scopes:
                ci = c if scope is None else float(conds[scope])
                if not ci <= s.health_max_condition:
                    which = "" if scope is None else f"mode {scope + 1} "
                    self.note("loss_of_excitation", t, f"loss of excitation: {which}IV condition number {ci:.3g} > "
                              f"{s.health_max_condition:.3g}", mode=scope)
        # projection storm: fraction of updates that needed the stability projection ([RA-SRIVC] §4.7)
        if est.projections:
            p_now = float(np.sum(np.asarray(est.projections, float)))
            n_now = float(est.updates)
            if self.last_projections is not None and self.last_samples is not None and n_now > self.last_samples:
                frac = (p_now - self.last_projections) / (n_now - self.last_samples)
                values["projection_fraction"] = frac
                if frac > s.health_max_projection_fraction:
                    self.note("projection_storm", t, f"projection storm: {frac:.1%} of updates needed the "
                              "stability projection")
            self.last_projections, self.last_samples = p_now, n_now
        # residual variance jump against a slow reference learned while healthy
        if est.residual_var is not None:
            rv = float(est.residual_var)
            values["residual_var"] = rv
            if math.isfinite(rv) and rv >= 0:
                if math.isnan(self.residual_ref):
                    self.residual_ref = rv
                ratio_r = rv / self.residual_ref if self.residual_ref > 0 else 1.0
                values["residual_ratio"] = ratio_r
                if ratio_r > s.health_residual_jump_ratio:
                    self.note("residual_jump", t, f"residual variance jumped x{ratio_r:.3g} over its healthy level")
                elif (not self.active and ratio_r < 1.5) or ratio_r < 1.0:
                    # the healthy level follows slow benign changes only: never absorbs a jump
                    dt = 0.0 if math.isnan(self.t_last) else max(t - self.t_last, 0.0)
                    a = min(1.0, dt / (10.0 * float(self.memory_s.max())))
                    self.residual_ref += a * (rv - self.residual_ref)
            elif not math.isfinite(rv):
                self.note("divergence", t, "divergence: non-finite residual variance")
        self.t_last = t
        status = self.status(t)
        status.values.update(values)
        return status

    def status(self, t: float) -> HealthStatus:
        """Active issues at ``t`` (expired ones are dropped); ``values['new_issues']`` were seen at ``t``.

        ``hold`` is True while an issue that holds every mode is active; ``holds`` lists every active hold as a
        :class:`.decision.Hold` (owner, reason, since, end, modes), the ones scoped to a mode included."""
        reasons = []
        level = Level.OK
        new = []
        hold = False
        holds: list[Hold] = []
        advisory_since: float | None = None
        for key, (t_seen, msg) in list(self.active.items()):
            kind, _, scope = key.partition(MODE_SCOPE)
            hold_s = self.hold_of(kind)
            if t - t_seen > hold_s:
                del self.active[key]
                continue
            if t_seen >= t:
                new.append(kind)
            suffix = "" if t_seen >= t else f" (recovering, hold-off until t={t_seen + hold_s:.1f} s)"
            reasons.append(msg + suffix)
            level = max(level, Level.ERROR if kind in self.ERROR_KINDS else Level.WARN)
            first = self.first_seen.get(key, t_seen)
            if kind in self.ADVISORY_KINDS:
                advisory_since = first if advisory_since is None else min(advisory_since, first)
                continue
            modes = (int(scope) - 1,) if scope else None
            holds.append(Hold(kind, msg, first, t_seen + hold_s, modes))
            hold = hold or modes is None
        for key in list(self.first_seen):
            if key not in self.active:
                del self.first_seen[key]
        values = {"counts": dict(self.counts), "issues": sorted({k.partition(MODE_SCOPE)[0] for k in self.active}),
                  "new_issues": sorted(set(new)), "advisory_since": advisory_since}
        return HealthStatus(level, reasons, hold, values, holds)

    def get_state(self) -> dict[str, Any]:
        return {"active": {k: list(v) for k, v in self.active.items()}, "counts": dict(self.counts),
                "first_seen": dict(self.first_seen),
                "residual_ref": self.residual_ref, "last_projections": self.last_projections,
                "last_samples": self.last_samples, "t_last": self.t_last,
                "reference_modal": None if self.reference_modal is None else self.reference_modal.tolist()}

    def set_state(self, d: Mapping[str, Any]) -> None:
        self.active = {k: (float(v[0]), str(v[1])) for k, v in d["active"].items()}
        self.counts = {k: int(v) for k, v in d["counts"].items()}
        self.first_seen = {k: float(v) for k, v in d.get("first_seen", {}).items()}
        self.residual_ref = float(d["residual_ref"])
        self.last_projections, self.last_samples = d["last_projections"], d["last_samples"]
        self.t_last = float(d["t_last"])
        rm = d.get("reference_modal")
        self.reference_modal = None if rm is None else np.asarray(rm, float)

