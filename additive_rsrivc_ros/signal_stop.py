"""A stop request that SIGINT/SIGTERM handlers may set without taking a lock.

``threading.Event.set`` takes the event's internal lock. A Python signal handler runs in the main thread between two
bytecodes, so when the signal lands while the main thread is inside ``Event.wait`` holding that same lock, the
handler's ``set`` waits for the lock forever. Measured: ``rsrivc_replay --loop`` hung on SIGTERM in about
1 of 20 runs, stack ``handler -> Event.set -> Condition.__enter__`` on top of ``Event.wait -> Condition.__enter__``
(a CI failure of ``test_sigterm_stops_cleanly``).

:class:`SignalStop` keeps a plain flag and wakes waiters through a pipe: :meth:`set` is one attribute store and one
non-blocking ``os.write``, :meth:`wait` is a ``select`` on the pipe. It offers the part of ``threading.Event`` that the
tools use (``set``, ``is_set``, ``wait``), so code written against an Event takes either.
"""

from __future__ import annotations

import os
import select
import signal
from collections.abc import Iterable
from typing import Any, Protocol


class StopFlag(Protocol):
    """What a loop needs of a stop request: ``threading.Event`` and :class:`SignalStop` both offer it."""

    def is_set(self) -> bool: ...

    def wait(self, timeout: float | None = None) -> bool: ...


class SignalStop:
    """A one-way stop flag: set once (by a signal handler or any thread), never cleared."""

    def __init__(self) -> None:
        self._set = False
        self.signal_name = ""
        self._read_fd, self._write_fd = os.pipe()
        os.set_blocking(self._read_fd, False)
        os.set_blocking(self._write_fd, False)

    def set(self) -> None:
        """Request the stop; safe inside a signal handler (no lock, no blocking call)."""
        self._set = True
        try:
            os.write(self._write_fd, b"\0")
        except OSError:  # the pipe is full (BlockingIOError: already woken) or closed at exit
            pass

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout: float | None = None) -> bool:
        """Sleep until the stop is requested or ``timeout`` seconds have passed; return :meth:`is_set`."""
        if not self._set:
            try:
                select.select([self._read_fd], [], [], None if timeout is None else max(timeout, 0.0))
            except (OSError, ValueError):  # closed descriptor: nothing left to wait for
                pass
        return self._set

    def handle(self, signum: int, _frame: Any) -> None:
        """A signal handler: remember the signal's name and request the stop."""
        try:
            self.signal_name = signal.Signals(signum).name
        except ValueError:
            self.signal_name = str(signum)
        self.set()

    def install(self, signals: Iterable[int] = (signal.SIGINT, signal.SIGTERM)) -> None:
        """Make ``signals`` request this stop (call from the main thread)."""
        for s in signals:
            signal.signal(s, self.handle)
