"""How the monitor pipeline gets a model, and gets a new one when it has none or a wrong one.

Initialization on ``init_duration_s`` of valid data ([A-SRIVC] eq. 29, then [RA-SRIVC] Algorithm 2 step 1), the
automatic start without guesses (:mod:`.autostart`), a start from the data when the guesses give no valid model,
and a restart from the data when the model-order check (:mod:`.adequacy`) finds the model wrong for the data (once
per run). A model is valid only if it is finite and, in closed loop, ``C_d`` stabilizes it; otherwise nothing is
published and the pipeline initializes again on new data.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..diagnosis.faults import FaultSettings, HealthMonitor
from ..estimation.estimator import MonitorSettings, RecursiveEstimator
from ..identification.adequacy import ModelOrderCheck
from ..identification.autostart import ModeSearch
from ..vocabulary import one_line
from .report_record import Counters, modes_text

if TYPE_CHECKING:
    from ..diagnosis.joint_check import JointChecker


class PipelineHost(Protocol):
    """What the start reads and sets on the pipeline it serves (:class:`.pipeline.MonitorPipeline`)."""

    cfg: MonitorSettings
    cfg_given: MonitorSettings
    K: int
    rate: float
    settings: FaultSettings
    counters: Counters
    health: HealthMonitor
    order_check: ModelOrderCheck
    search: ModeSearch | None
    est: RecursiveEstimator | None
    joint: JointChecker | None
    initialized: bool
    no_model: str | None
    model_max_pole: float
    marked_gaps: int
    memory_s: np.ndarray

    @property
    def notices(self) -> list[str]: ...

    @property
    def estimator(self) -> RecursiveEstimator: ...

    @property
    def mode_search(self) -> ModeSearch: ...

    def new_estimator(self) -> RecursiveEstimator: ...

    def switch_modes(self, cfg: MonitorSettings, closed: tuple[str, ...] = ()) -> None: ...

    def modal(self) -> np.ndarray: ...

    def rel(self, t_abs: float) -> float: ...

    def feed(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None: ...


class ModelStart:
    """The pipeline's start: the initialization buffer and the once-per-run starts from the data; see the module
    docstring. It acts on its host's estimator, monitors and health (:class:`PipelineHost`)."""

    def __init__(self, host: PipelineHost, init_samples: int) -> None:
        self.host = host
        self.init_samples = init_samples
        self.buffer: list[tuple[np.ndarray, ...]] = []
        self.buffered = 0
        self.data_start_tried = False        # guesses replaced by modes from the data (once per run)
        self.order_restarted = False         # a restart after the model-order check (once per run)
        self.start_checked = False           # the automatic start was checked on its window: not again at its init

    def clear_buffer(self) -> None:
        """The initialization window starts again (a break in the data)."""
        self.buffer, self.buffered = [], 0

    def missing(self) -> int:
        """Samples the initialization window still needs."""
        return self.init_samples - self.buffered

    def add(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> int:
        """Buffer samples for the initialization (invalid ones as NaN outputs, which the offline init skips); once
        the window is full, initialize. Returns how many samples were taken."""
        b = min(u.size, self.init_samples - self.buffered)
        yv = np.where(valid[:b], y[:b], np.nan)
        self.buffer.append((r[:b].copy(), u[:b].copy(), yv))
        self.buffered += b
        if self.buffered >= self.init_samples:
            rb, ub, yb = (np.concatenate([blk[q] for blk in self.buffer]) for q in range(3))
            self.clear_buffer()
            self.initialize(rb, ub, yb, t_end)
        return b

    def check_order(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        """Model-order check (:mod:`.adequacy`) on the first window of contiguous data after the initialization, once
        per run, against the estimate at its end; its finding goes on health (:meth:`ModelOrderCheck.apply`)."""
        if self.host.order_check.add(r, u, y, valid, self.host.rel(t_end), float(self.host.memory_s.max())):
            window = self.host.order_check.window()
            line = self.host.order_check.run(self.host.modal(), self.host.cfg, self.host.settings.min_change)
            if line is not None:
                self.host.notices.append(line)
            res = self.host.order_check.result
            if res is not None and res.flagged and not res.wrong_delay and not self.order_restarted:
                # (a wrong input delay is the configuration's: modes found again with it would misfit the same way)
                self.order_restarted = True
                try:
                    self._restart_from_data(*window, t_end, res)
                except Exception as exc:  # noqa: BLE001 - a failed restart is a line, never a crash
                    self.host.notices.append(f"restart from the data failed ({type(exc).__name__}: "
                                        f"{str(exc).splitlines()[0][:120] if str(exc) else ''}); the model stays "
                                        "flagged")

    def _restart_from_data(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float, res: Any,
                           initial: bool = False) -> None:
        """The model-order check found the model wrong for the data (``misfit`` or ``too_low``; a
        wrong optimum can look like either): the modes are found again on the check's window (:mod:`.modefind`; K
        automatic when the run found its modes itself, else the configured K and integrators) and adopted only if
        the same check on that window passes them; the estimator is then initialized on the window and the fault
        monitors start over (a baseline learned on a wrong model is no baseline). Once per run. Otherwise the
        flag stays on health: a model that misfits is never reported as healthy."""
        from ..identification.adequacy import check_model_order
        from ..identification.autostart import FoundModes
        from ..identification.modefind import SCAN_TOL, autostart_config

        auto = self.host.search is not None
        closed = bool(self.host.cfg.closed_loop)
        t_rel = self.host.rel(t_end)
        a, b = res.window_s
        where = f"t={a:.1f}–{b:.1f} s"
        c0 = time.perf_counter()
        try:
            new, found = autostart_config(self.host.cfg_given if auto else self.host.cfg, r if closed else None, u, y,
                                          count=None if auto else self.host.K, refit_tol=SCAN_TOL)
        except ValueError as exc:
            self.host.notices.append(f"restart from the data on {where} failed: {exc}; the model stays flagged")
            return
        if not auto and sorted(m.integrators for m in new.modes) != sorted(m.integrators for m in self.host.cfg.modes):
            self.host.notices.append(f"restart from the data on {where}: the modes found have other integrators than "
                                "modes.integrators; not used, the model stays flagged")
            return
        check = check_model_order(found.thetas, found.structures, u, y, self.host.rate, r=r if closed else None,
                                  **self._check_keywords())
        modes = modes_text(found.modal)
        if check.flagged or check.state == "skipped":
            self.host.notices.append(f"restart from the data on {where}: the {found.K} mode(s) found there ({modes}) "
                                f"do not pass the check either ({check.state}); the model stays flagged")
            return
        self.host.switch_modes(new)
        if auto:
            attempts = self.host.mode_search.found.attempts + 1 if self.host.mode_search.found is not None else 1
            modal = np.array([[m.natural_frequency_hz, m.damping_ratio, m.gain] for m in new.modes], dtype=float)
            self.host.mode_search.found = FoundModes(modal, [int(m.integrators) for m in new.modes], (a, b),
                                           f"restart after the model-order check: {found.message}",
                                           time.perf_counter() - c0, attempts)
        self.host.initialized = False
        self.host.marked_gaps = 0
        failure = self._fit_initial(r, u, y)
        if failure is not None:
            self.no_valid_model(t_rel, f"restart from the data: {failure[1]}")
            return
        self.host.initialized = True
        self.host.no_model = None
        self.host.health.clear_reference(self.host.modal())
        check.window_s, check.frf = (a, b), None
        if initial:               # the initialization window: the regular check still runs on the data that follow
            self.host.order_check.start_result = None
        else:
            self.host.order_check.result = check
        stage = "check of the initial model" if initial else "model-order check"
        line = (f"restarted from the data after the {stage} ({res.message}): the {self.host.K} mode(s) found "
                f"on {where} ({modes}) fit it; fault monitoring starts over")
        self.host.health.note("restart_from_data", t_rel, line)
        self.host.notices.append(line)
        self.host.counters.data_starts += 1

    def search_modes(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        """Automatic start (no guesses; :mod:`.autostart`): buffer the window, search it when full; once the modes
        are found the estimator gets the buffered samples as the guess path would have given them."""
        search, t_rel = self.host.mode_search, self.host.rel(t_end)
        if search.waiting(t_rel):         # back-off after repeated failures: these samples are not searched
            return
        search.add(r, u, y, valid, t_end, t_rel)
        if search.need() > 0:
            return
        new, line = search.run(t_rel)
        self.host.notices.append(line)
        if new is None:
            search.clear()
            self.host.health.note("no_modes", t_rel, line)
            return
        self._adopt_modes(new, t_rel)
        blocks = search.take()
        self._check_start(blocks, search)
        for blk in blocks:
            self.host.feed(blk.r, blk.u, blk.y, blk.valid, blk.t_end)

    def _check_start(self, blocks: list, search: ModeSearch) -> None:
        """The automatic start's model against its own window (:func:`.adequacy.check_start`): a start that misfits
        it is flagged on health at once (the regular check, on later data, may then restart from the data)."""
        from ..identification.adequacy import check_start

        found, closed = search.evidence, bool(self.host.cfg.closed_loop)
        if found is None or search.found is None:
            return
        self.start_checked = True
        r, u, y = (np.concatenate([getattr(b, k) for b in blocks]) for k in ("r", "u", "y"))
        y = np.where(np.concatenate([b.valid for b in blocks]), y, np.nan)
        try:
            res = check_start(found, r if closed else None, u, y, self.host.rate, **self._check_keywords())
        except Exception as exc:  # noqa: BLE001 - a failed check is a line, never a crash
            self.host.notices.append(f"check of the automatic start failed ({type(exc).__name__})")
            return
        if res is not None and res.flagged:
            self._flag_start(res, search.found.window_s, "the automatic start")

    def _check_keywords(self) -> dict[str, Any]:
        """The model checks' (:mod:`.adequacy`) keywords from this run's configuration."""
        cfg = self.host.cfg
        return {"controller": cfg.controller if cfg.closed_loop else None, "input_delay": cfg.input_delay_samples,
                "min_change": self.host.settings.min_change, "relevance": self.host.order_check.relevance,
                "max_iterations": cfg.estimator.init_max_iterations}

    def _flag_start(self, res: Any, window_s: tuple[float, float], what: str) -> None:
        """A start that misfits its own window: on health until the regular check runs, and a notice."""
        res.window_s, res.frf = window_s, None
        self.host.order_check.start_result = res
        a, b = window_s
        self.host.notices.append(f"model check of {what} on t={a:.1f}–{b:.1f} s: {res.message}")

    def _adopt_modes(self, cfg: MonitorSettings, t_rel: float) -> None:
        """Build estimator and monitors for the modes found; health notes so far are kept (the failed searches'
        ones are closed)."""
        self.host.switch_modes(cfg, closed=("no_modes", "initializing"))
        found = self.host.mode_search.found
        what = "no modes" if found is None else found.describe()
        self.host.health.note("initializing", t_rel, f"no mode guesses: {what}; initializing the estimator")
        self.host.marked_gaps = 0

    def initialize(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float) -> None:
        """Offline initialization + filter priming on the buffered data ([RA-SRIVC] Algorithm 2 step 1).

        Guesses are a start, not the answer: when they give no valid model (the fit fails, or
        ``C_d`` does not stabilize it), the modes are found in the same window instead (:mod:`.modefind`, K and
        ``modes.integrators`` as configured: the structure is knowledge, the numbers are guesses), once per run,
        with a health note; a model from the data that fails too leaves the pipeline
        without a model (nothing published) and it initializes again on new data."""
        t_rel = self.host.rel(t_end)
        start_checked, self.start_checked = self.start_checked, False    # for this initialization only
        failure = self._fit_initial(r, u, y)
        if failure is not None and self.host.search is None and not self.data_start_tried:
            self.data_start_tried = True
            if self._start_from_data(r, u, y, t_rel, failure[1]):
                failure = self._fit_initial(r, u, y)
        self._joint_samples_through(r, u, y, failure is None)
        if failure is not None:
            kind, why = failure
            if kind == "invalid":
                self.no_valid_model(t_rel, why)
                return
            self.host.health.note("reinitializing", t_rel, f"initialization failed ({why}); retrying on the next data")
            self.host.est = self.host.new_estimator()
            self.host.marked_gaps = 0
            return
        self.host.initialized = True
        self.host.no_model = None
        self.host.health.refitted(t_rel)
        modal = self.host.modal()
        if self.host.health.reference_modal is None and np.all(np.isfinite(modal[:, :3])):
            self.host.health.clear_reference(modal)
        if not start_checked:      # the automatic start's model was checked on its search window already
            self._check_initial_model(r, u, y, t_end)

    def _joint_samples_through(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, initialized: bool) -> None:
        """The joint check's recent samples stay contiguous through a re-initialization: its window (fed to the
        offline fit, not to the estimator) joins them when the fit succeeded, so a check can run on the new model
        at once; otherwise they start again. A first initialization (no samples held yet) adds nothing."""
        joint = self.host.joint
        if joint is None or joint.recent.n == 0:
            return
        if initialized:
            joint.add(r, u, y, float(self.host.memory_s.max()))
        else:
            joint.recent.clear()

    def _check_initial_model(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float) -> None:
        """Every initialization's model against the FRF of its own window (:func:`.adequacy.check_initial_model`, the
        automatic start's check): a model that misfits the data it was fitted on -- guesses that led the offline fit
        to a wrong optimum, a re-initialization after a divergence that lands on one -- is flagged on health from its
        first estimate, instead of being reported healthy until the regular check's window is full (which repeated
        divergences may never let happen), and the modes are found again on the window (once per run, as after the
        regular check)."""
        from ..identification.adequacy import check_initial_model

        self.host.order_check.start_result = None
        if not self.host.order_check.enabled:
            return
        try:
            res = check_initial_model(self.host.estimator.thetas, list(self.host.cfg.structures),
                                      r if self.host.cfg.closed_loop else None, u, y, self.host.rate,
                                      **self._check_keywords())
        except Exception as exc:  # noqa: BLE001 - a failed check is a line, never a crash
            self.host.notices.append(f"check of the initial model failed ({type(exc).__name__}: {one_line(exc)})")
            return
        if res is None or not res.flagged:
            return
        t_rel = self.host.rel(t_end)
        self._flag_start(res, (max(t_rel - u.size / self.host.rate, 0.0), t_rel), "the initial model")
        if not res.wrong_delay and not self.order_restarted:
            self.order_restarted = True
            try:
                self._restart_from_data(r, u, y, t_end, res, initial=True)
            except Exception as exc:  # noqa: BLE001 - a failed restart is a line, never a crash
                self.host.notices.append(f"restart from the data failed ({type(exc).__name__}: {one_line(exc)}); the "
                                    "model stays flagged")

    def _fit_initial(self, r: np.ndarray, u: np.ndarray, y: np.ndarray) -> tuple[str, str] | None:
        """Initialize the estimator on the window; ``None``, or ``("failed" | "invalid", why)``."""
        try:
            self.host.estimator.initialize(r, u, y)
        except Exception as exc:  # noqa: BLE001 - any failure of the offline init is a health incident
            self.host.counters.init_failures += 1
            return "failed", f"{type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''}"
        self.host.counters.initializations += 1
        problem = self.model_problem("initial model")
        if problem is not None:
            self.host.counters.invalid_models += 1
            return "invalid", problem
        return None

    def _start_from_data(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_rel: float, why: str) -> bool:
        """Replace guesses that gave no valid model by the K modes found in this window; False if none are found."""
        from ..identification.modefind import SCAN_TOL, autostart_config

        try:   # the offline initialization that follows refines the start on these samples
            new, found = autostart_config(self.host.cfg, r if self.host.cfg.closed_loop else None, u, y,
                                          count=self.host.K, refit_tol=SCAN_TOL)
        except ValueError as exc:
            self.host.notices.append(f"the mode guesses gave no valid model ({why}); finding the modes in the data "
                                f"failed too: {exc}")
            return False
        given = sorted(int(m.integrators) for m in self.host.cfg.modes)
        if sorted(int(m.integrators) for m in new.modes) != given:   # the user's structure is knowledge, not a guess
            self.host.notices.append(f"the mode guesses gave no valid model ({why}); the modes found in the data have "
                                f"other integrators than modes.integrators {given}: not used")
            return False
        self.host.switch_modes(new)
        modes = modes_text(found.modal)
        line = (f"the mode guesses gave no valid model ({why}); started from the {self.host.K} mode(s) found in the "
                f"data instead ({modes})")
        self.host.health.note("start_from_data", t_rel, line)
        self.host.notices.append(line)
        self.host.counters.data_starts += 1
        return True

    def model_problem(self, which: str, modal: np.ndarray | None = None) -> str | None:
        """Why the current model is no valid model, or None: it must be finite and, in closed loop, the controller
        ``C_d`` (with the input delay) must stabilize it -- the model's noise-free closed loop generates the
        instrument ([RA-SRIVC] eq. 33) and a plant that ``C_d`` does not stabilize cannot have produced the bounded
        data.
        ``modal``: the current estimate's ``(K, 6)`` when the caller has it (else it is computed)."""
        if modal is None:
            modal = np.asarray(self.host.estimator.modal(), dtype=float).reshape(self.host.K, 6)
        if not np.all(np.isfinite(modal[:, :3])):
            return f"{which} is not finite"
        rho = float(self.host.estimator.closed_loop_max_pole())
        self.host.model_max_pole = rho
        if math.isnan(rho) or rho < 1.0:
            return None
        return f"{which} destabilizes the loop with C_d: max |closed-loop pole| {rho:.4g}"

    def no_valid_model(self, t_rel: float, problem: str) -> None:
        """No valid model: drop the estimator (nothing is published) and initialize again on new data."""
        self.host.no_model = f"no valid model: {problem}; re-initializing on new data"
        self.host.health.note("no_valid_model", t_rel, self.host.no_model)
        self.host.est = self.host.new_estimator()
        self.host.marked_gaps = 0
        self.host.initialized = False
        self.clear_buffer()

    def reinitialize(self, t_rel: float) -> None:
        """Divergence: a fresh estimator initialized on the next data; baseline and events are kept."""
        self.host.est = self.host.new_estimator()
        self.host.marked_gaps = 0
        self.host.initialized = False
        self.clear_buffer()
        self.host.counters.reinitializations += 1
        self.host.no_model = "estimator diverged: re-initializing on new data"
        self.host.health.note("reinitializing", t_rel, self.host.no_model)
