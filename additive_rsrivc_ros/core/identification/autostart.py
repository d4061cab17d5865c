"""The automatic start of :class:`.pipeline.MonitorPipeline` when the params give no mode guesses.

:class:`ModeSearch` collects the first ``max(init_duration_s, 2 s)`` of checked samples (invalid ones kept on the grid
as NaN), runs :func:`.modefind.autostart_config` on them (FRF peaks refined by the offline additive (CL)SRIVC, [A-SRIVC]
eq. 29, K by held-out output error) and hands the pipeline the modes found plus the buffered samples, which go to the
estimator as on the guess path (the first ``init_duration_s`` to the offline initialization, [RA-SRIVC] Algorithm 2 step
1). A window without usable excitation, or with less than :data:`MIN_CONTIGUOUS_S` of contiguous valid samples, is a
failed attempt, said in one line; an excited clean window that showed no mode makes the next one twice as long (up to
:data:`MAX_GROWTH` x); others are retried at once :data:`FAST_RETRIES` times, then after a growing wait of at most
:data:`MAX_WAIT_S` of data. Nothing is estimated meanwhile.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..estimation.estimator import MonitorSettings
from ..vocabulary import one_line

MIN_WINDOW_S = 2.0
"""Shortest window the modes are searched on (the FRF needs a few averages at a resolution below 1 Hz)."""
MIN_CONTIGUOUS_S = 2.0
"""Shortest stretch of contiguous valid samples the search runs on (at most the whole window)."""
FAST_RETRIES = 3
MAX_WAIT_S = 60.0
MAX_GROWTH = 4


@dataclass
class _Block:
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    valid: np.ndarray
    t_end: float        # absolute time of the block's last sample


@dataclass
class FoundModes:
    """What the search found: rows ``f_hz, zeta, gain`` (frequency 0: rigid body), integrators, evidence."""

    modal: np.ndarray
    integrators: list[int]
    window_s: tuple[float, float]
    message: str
    seconds: float = math.nan
    attempts: int = 1

    def describe(self) -> str:
        """``found 2 mode(s) on the first 5 s (3.2487 Hz, 32.971 Hz; K = 2 by held-out output error ...)``."""
        modes = ", ".join(f"{m[0]:.5g} Hz" if m[0] > 0 else f"rigid body b0/p^{ell}"
                          for m, ell in zip(self.modal, self.integrators, strict=True))
        a, b = self.window_s
        where = f"the first {b - a:.4g} s" if abs(a) < 1e-6 else f"t={a:.1f}–{b:.1f} s"
        return f"found {len(self.integrators)} mode(s) on {where} ({modes}; {self.message})"

    def to_dict(self) -> dict[str, Any]:
        return {"modal": self.modal.tolist(), "integrators": list(self.integrators),
                "window_s": list(self.window_s), "message": self.message, "seconds": self.seconds,
                "attempts": self.attempts}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FoundModes:
        return cls(np.asarray(d["modal"], dtype=float).reshape(-1, 3), [int(v) for v in d["integrators"]],
                   (float(d["window_s"][0]), float(d["window_s"][1])), str(d.get("message", "")),
                   float(d.get("seconds", math.nan) or math.nan), int(d.get("attempts", 1)))


@dataclass
class ModeSearch:
    """Window buffer, attempts and back-off of the automatic start (see the module docstring)."""

    cfg: MonitorSettings                      # MonitorConfig without guesses
    blocks: list[_Block] = field(default_factory=list)
    n: int = 0
    t_start_s: float = math.nan               # window start (s since the first sample)
    attempts: int = 0
    failures: int = 0
    wait_until_s: float = -math.inf           # no collection before this time (back-off)
    growth: int = 1                           # window length factor (doubled after an excited window without modes)
    last_failure: str = ""
    found: FoundModes | None = None
    evidence: Any = None                      # the last successful search's modefind.ModeFindResult

    @property
    def rate(self) -> float:
        return float(self.cfg.loop_rate_hz)

    @property
    def window(self) -> int:
        """Samples per window: ``max(init_duration_s, 2 s)``."""
        return self.growth * max(2, int(round(max(float(self.cfg.init_duration_s), MIN_WINDOW_S) * self.rate)))

    def need(self) -> int:
        return self.window - self.n

    def waiting(self, t_rel: float) -> bool:
        return t_rel < self.wait_until_s

    def clear(self) -> None:
        """Drop the window (a data break: the search needs contiguous data, as the initialization does)."""
        self.blocks, self.n, self.t_start_s = [], 0, math.nan

    def add(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float,
            t_end_rel: float) -> None:
        if self.n == 0:
            self.t_start_s = max(t_end_rel - (u.size - 1) / self.rate, 0.0)   # times count from the first sample
        self.blocks.append(_Block(r.copy(), u.copy(), y.copy(), valid.copy(), t_end))
        self.n += u.size

    def take(self) -> list[_Block]:
        """The buffered blocks (for the estimator), emptying the window."""
        out = self.blocks
        self.clear()
        return out

    def status_line(self) -> str:
        """Health reason while searching."""
        line = (f"starting: finding modes (no guesses): collecting {self.window / self.rate:g} s of valid data for "
                "the automatic start")
        if self.n:
            line += f" ({self.n / self.rate:.1f} s so far)"
        return line

    def run(self, t_end_rel: float) -> tuple[MonitorSettings | None, str]:
        """Search the full window: ``(configuration with the modes found, notice)`` or ``(None, failure line)``."""
        self.attempts += 1
        window_s = (self.t_start_s, self.t_start_s + self.n / self.rate)
        r, u, y, valid = (np.concatenate([getattr(b, k) for b in self.blocks]) for k in ("r", "u", "y", "valid"))
        closed = bool(self.cfg.closed_loop) and self.cfg.controller is not None
        y = np.where(valid, y, np.nan)
        c0 = time.perf_counter()
        problem = _window_problem(r if closed else None, u, y, self.rate)
        excited = problem is None
        new = None
        if problem is None:
            try:
                from .modefind import SCAN_TOL, autostart_config
                # the estimator's offline initialization refines the start on these samples right after
                new, res = autostart_config(self.cfg, r if closed else None, u, y, refit_tol=SCAN_TOL)
                self.evidence = res
                if not all(res.identifiable) and self.growth < MAX_GROWTH:
                    bad = ", ".join(f"{m[0]:.4g} Hz" for m, ok in zip(res.modal, res.identifiable, strict=True)
                                    if not ok)
                    new, problem = None, f"mode(s) outside the band the window excites ({bad}): window too short"
            except Exception as exc:  # noqa: BLE001 - a failed search is a health line, never a crash
                problem = one_line(exc)
                if not isinstance(exc, ValueError):
                    problem = f"{type(exc).__name__}: {problem}"
        seconds = time.perf_counter() - c0
        if new is not None:
            modal = np.array([[m.natural_frequency_hz, m.damping_ratio, m.gain] for m in new.modes])
            self.found = FoundModes(modal, [m.integrators for m in new.modes], window_s, res.message, seconds,
                                    self.attempts)
            return new, "no mode guesses: " + self.found.describe()
        assert problem is not None   # autostart_config returns modes or raises
        self.failures += 1
        wait = 0.0
        may_grow = excited and self.growth < MAX_GROWTH
        invalid = int(np.count_nonzero(~_valid(r if closed else None, u, y))) if may_grow else 0
        if invalid:
            problem += f" ({invalid} invalid samples in the window: the next one keeps its length)"
        if may_grow and not invalid:
            self.growth *= 2
        elif self.failures > FAST_RETRIES:
            wait = min(MAX_WAIT_S, self.window / self.rate * 2.0 ** (self.failures - FAST_RETRIES))
        self.wait_until_s = t_end_rel + wait
        nxt = (f"retrying on the next {self.window / self.rate:g} s" if wait == 0.0 else
               f"next attempt on {self.window / self.rate:g} s from t={self.wait_until_s:.1f} s")
        self.last_failure = (f"no modes found on t={window_s[0]:.1f}–{window_s[1]:.1f} s: {problem}; {nxt} "
                             f"(attempt {self.attempts}); nothing is estimated until modes are found")
        return None, self.last_failure

    def info(self) -> dict[str, Any]:
        """Health ``autostart``: state, attempts, the modes found and the last failure."""
        out: dict[str, Any] = {"state": "found" if self.found is not None else "finding", "attempts": self.attempts,
                               "failures": self.failures, "window_s": self.window / self.rate,
                               "last_failure": self.last_failure}
        if self.found is not None:
            out.update(self.found.to_dict())
            out["K"] = len(self.found.integrators)
        return out


def _longest_run(ok: np.ndarray) -> int:
    """Length of the longest run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], ok.astype(np.int8), [0]))))
    return int(np.max(edges[1::2] - edges[::2])) if edges.size else 0


def _valid(r: np.ndarray | None, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Samples with finite input, output (and reference in closed loop): the pipeline's invalid ones are NaN here."""
    return np.isfinite(u) & np.isfinite(y) & (np.isfinite(r) if r is not None else True)


def _window_problem(r: np.ndarray | None, u: np.ndarray, y: np.ndarray, rate: float) -> str | None:
    """Why the window cannot show modes before any fit: too little contiguous valid data, or no excitation."""
    ok = _valid(r, u, y)
    need = min(u.size, int(round(MIN_CONTIGUOUS_S * rate)))
    longest = _longest_run(ok)
    if longest < need:
        return (f"only {longest / rate:.2f} s of contiguous valid samples (need {need / rate:.2f} s; "
                f"{int((~ok).sum())} invalid samples in the window)")
    x, name = (r, "reference") if r is not None else (u, "input")
    xv = x[np.isfinite(x)]
    if xv.size == 0 or float(np.ptp(xv)) <= 1e-12 * max(1.0, float(np.max(np.abs(xv)))):
        return f"no excitation: the {name} is constant over the window"
    return None
