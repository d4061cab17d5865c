"""The per-mode, per-quantity sequential fault test (S3, S4 of :mod:`.faults`) and the events it opens.

:class:`SequentialTest` is a two-sided CUSUM (Page 1954) on the normalized deviation from the baseline with a
relevance gate, persistence and clear hysteresis; :func:`cusum_threshold` gives its threshold for a target
in-control run length. :class:`SequentialTests` holds one test per mode and quantity and every event they opened.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..vocabulary import EVENTS_HEADER, QUANTITIES
from .fault_settings import Level


def cusum_threshold(k: float, arl0: float) -> float:
    """CUSUM threshold ``h`` giving the in-control average run length ``arl0`` for reference ``k``.

    Siegmund's approximation for unit-variance Gaussian increments (S3):
    ``ARL0 = (exp(2 k b) - 2 k b - 1) / (2 k^2)`` with ``b = h + 1.166``; ``ARL0 = b^2`` as ``k -> 0``.
    """
    if not (arl0 > 1.0 and math.isfinite(arl0)):
        raise ValueError(f"arl0 must be a finite number > 1, got {arl0}")
    if k < 1e-3:
        return max(math.sqrt(arl0) - 1.166, 0.0)
    c = 2.0 * k * k * arl0
    b = math.log(c + 1.0) / (2.0 * k)
    for _ in range(50):                  # fixed point of exp(2kb) = c + 2kb + 1 (monotone, converges fast)
        b_new = math.log(c + 2.0 * k * b + 1.0) / (2.0 * k)
        if abs(b_new - b) < 1e-12 * max(1.0, b):
            b = b_new
            break
        b = b_new
    return max(b - 1.166, 0.0)


@dataclass
class FaultEvent:
    """One structural fault episode; fields map onto events.csv (docs/INTERFACE.md)."""

    mode: int                  # 1-based, as in the diagnostics status name "mode <i>"
    quantity: str              # natural_frequency | damping | gain
    direction: str             # up | down
    onset_time_s: float        # estimated change time (S3), s since the first sample
    alarm_time_s: float        # time the fault was confirmed
    baseline: float
    value: float               # latest estimate while the fault was present
    clear_time_s: float | None = None
    z: float = math.nan        # normalized deviation at confirmation

    @property
    def is_open(self) -> bool:
        return self.clear_time_s is None

    def csv_row(self) -> dict[str, Any]:
        """The events.csv columns (``vocabulary.EVENTS_HEADER``); an empty clear time while open
        (``vocabulary.events_csv_cells`` writes them)."""
        row = {k: getattr(self, k) for k in EVENTS_HEADER}
        if self.clear_time_s is None:
            row["clear_time_s"] = ""
        return row

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class SequentialTest:
    """Two-sided CUSUM with relevance gate, persistence and clear hysteresis for one mode/quantity (S3, S4)."""

    mode: int
    quantity: str
    g_up: float = 0.0
    g_down: float = 0.0
    zero_up_t: float = math.nan
    zero_down_t: float = math.nan
    small_up_t: float = math.nan      # last time the deviation was below clear_fraction * relevant change
    small_down_t: float = math.nan
    gate_up_since: float = math.nan   # start of the current stretch with deviation >= relevant change
    gate_down_since: float = math.nan
    state: str = "ok"                 # ok | suspect | fault
    direction: int = 0
    since: float = math.nan           # suspect start / clear-streak start
    event: FaultEvent | None = None
    last_z: float = 0.0
    h: float = math.nan               # threshold used at the last step
    confirm_before: float = math.inf  # a relevant deviation starting later is not confirmed (advisory health)
    confirm_by_onset: bool = False    # compare the deviation's onset (not its relevance crossing) with it
    confirm_direction: int = 0        # non-zero: only a deviation in this direction is confirmed (the joint support)
    by_joint: bool = False            # the open event was confirmed by the joint check (S6), which also clears it
    joint_miss: int = 0               # consecutive joint checks that no longer support that event

    @property
    def level(self) -> Level:
        return {"ok": Level.OK, "suspect": Level.WARN, "fault": Level.ERROR}[self.state]

    @property
    def flag(self) -> bool:
        return self.state == "fault"

    @property
    def direction_name(self) -> str:
        return {1: "up", -1: "down"}.get(self.direction, "")

    def reset(self, t: float) -> None:
        """Forget the accumulated evidence (after a clear, a rebaseline or a hold)."""
        self.g_up = self.g_down = 0.0
        self.zero_up_t = self.zero_down_t = self.small_up_t = self.small_down_t = t
        self.gate_up_since = self.gate_down_since = math.nan
        if self.state != "fault":
            self.state, self.direction, self.since = "ok", 0, math.nan
            self.by_joint, self.joint_miss = False, 0

    def open_joint(self, t: float, onset: float, direction: int, baseline: float, value: float, z: float,
                   ) -> FaultEvent:
        """Confirm a change the joint check supports (S6): the event carries the joint fit's value."""
        self.state, self.direction, self.since = "fault", direction, math.nan
        self.by_joint, self.joint_miss = True, 0
        self.event = FaultEvent(self.mode, self.quantity, self.direction_name, onset, t, baseline, value, None, z)
        return self.event

    def step(self, t: float, w: float, x: float, sigma_d: float, b: float, rho: float, k: float, h: float,
             clear_fraction: float, persist_s: float, clear_s: float, *, arl0: float = 1e6,
             ) -> tuple[FaultEvent | None, FaultEvent | None]:
        """Advance the test by one estimate ``x`` (S3, S4); returns (opened event, closed event).

        ``h <= 0`` selects the threshold from the in-control run length ``arl0`` (:func:`cusum_threshold`).
        """
        dev = x - b
        rel = dev / abs(b)
        z = dev / sigma_d
        self.last_z = z
        k_eff = max(k, 0.5 * rho * abs(b) / sigma_d)   # reference of the CUSUM tuned to the relevant change
        if h <= 0.0:   # floor: at least one independent estimate's worth of excess over k
            h = max(cusum_threshold(k_eff, arl0), 1.0)
        self.h = h
        cap = 2.0 * h
        self.g_up = min(cap, max(0.0, self.g_up + w * (z - k_eff)))
        self.g_down = min(cap, max(0.0, self.g_down + w * (-z - k_eff)))
        if self.g_up == 0.0:
            self.zero_up_t = t
        if self.g_down == 0.0:
            self.zero_down_t = t
        if rel < clear_fraction * rho:
            self.small_up_t = t
        if rel > -clear_fraction * rho:
            self.small_down_t = t
        self.gate_up_since = (t if math.isnan(self.gate_up_since) else self.gate_up_since) if rel >= rho else math.nan
        self.gate_down_since = ((t if math.isnan(self.gate_down_since) else self.gate_down_since) if rel <= -rho
                                else math.nan)
        opened = closed = None
        if self.state == "fault":
            assert self.event is not None      # the fault state always carries its open event
            d = self.direction
            present = d * rel >= clear_fraction * rho and d * z >= k
            if present:
                self.since = math.nan
                self.event.value = x
            else:
                if math.isnan(self.since):
                    self.since = t
                if t - self.since >= clear_s:
                    self.event.clear_time_s = self.since
                    closed = self.event
                    self.event, self.state, self.direction, self.since = None, "ok", 0, math.nan
                    self.reset(t)
            return opened, closed
        cand = 0
        if self.g_up > h and rel >= rho:
            cand = 1
        elif self.g_down > h and rel <= -rho:
            cand = -1
        if cand == 0:
            self.state, self.direction, self.since = "ok", 0, math.nan
            return opened, closed
        if self.state != "suspect" or cand != self.direction:
            self.state, self.direction, self.since = "suspect", cand, t
        gate_since = self.gate_up_since if cand > 0 else self.gate_down_since
        onset = self.onset(cand)
        began = min(onset, gate_since) if self.confirm_by_onset else gate_since
        if t - gate_since >= persist_s and began <= self.confirm_before and self.confirm_direction in (0, cand):
            self.event = FaultEvent(self.mode, self.quantity, self.direction_name, onset, t, b, x, None, z)
            self.state, self.since = "fault", math.nan
            opened = self.event
        return opened, closed

    def onset(self, direction: int) -> float:
        """The suspected deviation's estimated start (S3): the last time its CUSUM was zero or the deviation small,
        at the latest the suspect start."""
        zero_t = self.zero_up_t if direction > 0 else self.zero_down_t
        small_t = self.small_up_t if direction > 0 else self.small_down_t
        onset = np.nanmax([zero_t, small_t, -np.inf])
        return min(float(onset), self.since) if math.isfinite(onset) else self.since

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["event"] = None if self.event is None else self.event.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SequentialTest:
        d = dict(d)
        ev = d.pop("event", None)
        out = cls(**d)
        out.event = None if ev is None else FaultEvent(**ev)
        return out


@dataclass
class FaultUpdate:
    """What one :meth:`.faults.FaultMonitor.update` changed."""

    opened: list[FaultEvent] = field(default_factory=list)
    closed: list[FaultEvent] = field(default_factory=list)
    baseline_ready: bool = False


class SequentialTests:
    """The K x 3 :class:`SequentialTest` (one per mode and quantity, rows by mode) and every event they opened
    (``events``; the open ones are also held by their tests). Iterating gives the rows."""

    def __init__(self, n_modes: int) -> None:
        self.rows = [[SequentialTest(i + 1, q) for q in QUANTITIES] for i in range(n_modes)]
        self.events: list[FaultEvent] = []   # every event ever opened (open ones are also in the rows)

    def __iter__(self) -> Iterator[list[SequentialTest]]:
        return iter(self.rows)

    def __getitem__(self, i: int) -> list[SequentialTest]:
        return self.rows[i]

    def reset(self, t: float) -> None:
        """Every test forgets its evidence (:meth:`SequentialTest.reset`; an open event stays open)."""
        for row in self.rows:
            for test in row:
                test.reset(t)

    def close_all(self, t: float) -> list[FaultEvent]:
        """Close every open event at ``t`` and reset every test; returns the closed events."""
        closed = []
        for row in self.rows:
            for test in row:
                if test.event is not None:
                    test.event.clear_time_s = t
                    closed.append(test.event)
                test.event, test.state, test.direction, test.since = None, "ok", 0, math.nan
                test.reset(t)
        return closed

    @property
    def open_events(self) -> list[FaultEvent]:
        return [t.event for row in self.rows for t in row if t.event is not None]

    @property
    def flags(self) -> np.ndarray:
        """(K, 3) bool: confirmed fault per mode and quantity."""
        return np.array([[t.flag for t in row] for row in self.rows], dtype=bool)

    @property
    def levels(self) -> np.ndarray:
        """(K, 3) int :class:`Level` per mode and quantity."""
        return np.array([[int(t.level) for t in row] for row in self.rows], dtype=int)

    @property
    def directions(self) -> list[list[str]]:
        return [[t.direction_name for t in row] for row in self.rows]

    def to_dicts(self) -> list[list[dict[str, Any]]]:
        return [[t.to_dict() for t in row] for row in self.rows]

    def load(self, tests: list[list[Mapping[str, Any]]], events: list[Mapping[str, Any]]) -> None:
        """Restore :meth:`to_dicts` output and the events (an open event is the object its test holds)."""
        self.rows = [[SequentialTest.from_dict(d) for d in row] for row in tests]
        by_key = {(e.mode, e.quantity, e.onset_time_s): e for row in self.rows for t in row
                  if (e := t.event) is not None}
        self.events = [by_key.get((d["mode"], d["quantity"], d["onset_time_s"])) or FaultEvent(**d)
                       for d in events]
