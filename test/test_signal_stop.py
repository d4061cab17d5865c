"""The stop request that SIGINT/SIGTERM handlers set (additive_rsrivc_ros.signal_stop)."""

from __future__ import annotations

import select
import signal
import threading
import time

import pytest

from additive_rsrivc_ros.signal_stop import SignalStop


@pytest.fixture
def usr1_stop():
    stop = SignalStop()
    old = signal.signal(signal.SIGUSR1, stop.handle)
    yield stop
    signal.signal(signal.SIGUSR1, old)


def test_wait_times_out_unset_and_returns_at_once_once_set() -> None:
    stop = SignalStop()
    t0 = time.monotonic()
    assert stop.wait(0.05) is False and not stop.is_set()
    assert time.monotonic() - t0 >= 0.045
    stop.set()
    stop.set()  # idempotent; a second byte in the pipe changes nothing
    t0 = time.monotonic()
    assert stop.wait(10.0) is True and stop.is_set()
    assert time.monotonic() - t0 < 1.0


def test_a_set_from_another_thread_wakes_a_waiter() -> None:
    stop = SignalStop()
    threading.Timer(0.1, stop.set).start()
    t0 = time.monotonic()
    assert stop.wait(10.0) is True
    assert time.monotonic() - t0 < 5.0


def test_a_signal_that_lands_inside_wait_wakes_it_and_names_itself(usr1_stop: SignalStop,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """The handler runs in the middle of ``wait`` (here: just before its ``select``), the moment at which
    ``threading.Event.set`` deadlocks on the lock its own ``wait`` holds. The wait must end at once, set."""
    real_select = select.select

    def select_after_a_signal(*args, **kwargs):
        signal.raise_signal(signal.SIGUSR1)  # runs the handler before it returns
        return real_select(*args, **kwargs)

    monkeypatch.setattr(select, "select", select_after_a_signal)
    t0 = time.monotonic()
    assert usr1_stop.wait(10.0) is True
    assert time.monotonic() - t0 < 5.0
    assert usr1_stop.signal_name == "SIGUSR1"


def test_a_signal_from_another_thread_ends_a_long_wait(usr1_stop: SignalStop) -> None:
    threading.Timer(0.1, signal.pthread_kill, (threading.main_thread().ident, signal.SIGUSR1)).start()
    t0 = time.monotonic()
    assert usr1_stop.wait(10.0) is True
    assert time.monotonic() - t0 < 5.0
