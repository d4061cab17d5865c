"""Input synchronization of the monitor node (additive_rsrivc_ros/ros/sync.py), without DDS.

Every message carries its sample index as value, so a misaligned sample is one whose r, u, y differ.
"""

import numpy as np
import pytest

from additive_rsrivc_ros.ros.sync import InputSync, settings

RATE = 1000.0
H_NS = 1_000_000
SIG = ("reference", "input", "output")


def make(stamped: bool = False, **kw) -> InputSync:
    args = dict(max_backlog=50, quiet_s=0.05, gap_s=0.05, hold_s=0.02)
    args.update(kw)
    return InputSync(SIG, RATE, stamped=stamped, **args)


def feed(s: InputSync, ks, t0_ns: int, topics=(0, 1, 2), stamped: bool = False) -> None:
    for k in ks:
        for i in topics:
            item = (float(k), t0_ns + k * H_NS + 10 * i)
            s.queues[i].append(item + ((5_000_000_000 + k * H_NS),) if stamped else item)


def collect_all(s: InputSync, now_ns: int, idle_ns: int = 0):
    blocks = []
    while (b := s.collect(now_ns, idle_since_ns=idle_ns, ros_now_s=100.0)) is not None:
        blocks.append(b)
    return blocks


def assert_aligned(blocks) -> np.ndarray:
    t = np.concatenate([b.t for b in blocks])
    r, u, y = (np.concatenate([getattr(b, a) for b in blocks]) for a in "ruy")
    assert np.array_equal(r, u) and np.array_equal(u, y), "misaligned samples were emitted"
    return t


def test_order_mode_regular_stream_is_on_the_nominal_grid():
    s = make()
    feed(s, range(500), 0)
    t = assert_aligned(collect_all(s, 500 * H_NS + 1000))
    assert t.size == 500
    np.testing.assert_allclose(np.diff(t), 1.0 / RATE, rtol=1e-9)
    assert s.counters.mismatches == 0 and s.counters.gaps == 0 and s.counters.dropped == 0


def test_order_mode_extra_messages_are_detected_when_streams_pause():
    s = make()
    feed(s, range(200), 0)
    feed(s, range(200, 205), 0, topics=(1,))      # 5 extra input messages, never matched
    now = 205 * H_NS + 200_000_000               # all topics quiet for 200 ms, executor idle since
    blocks = collect_all(s, now, idle_ns=now - 1000)
    blocks += collect_all(s, now + 1000, idle_ns=now)
    t = assert_aligned(blocks)
    assert t.size == 200
    assert s.counters.mismatches == 1 and s.counters.dropped == 5
    # new data after the resync is aligned again and starts after a time gap
    feed(s, range(300, 400), 0)
    t2 = assert_aligned(collect_all(s, 400 * H_NS + 1000))
    assert t2.size == 100 and t2[0] - t[-1] > 2.0 / RATE


def test_order_mode_silent_topic_bounds_the_backlog_and_resynchronizes():
    s = make(max_backlog=20, stall_s=0.2)
    feed(s, range(100), 0)
    assert_aligned(collect_all(s, 100 * H_NS))
    feed(s, range(100, 400), 0, topics=(1, 2))   # reference silent for 300 ms
    assert collect_all(s, 400 * H_NS) == []
    assert s.counters.dropped > 0 and any("no data on reference" in e for e in s.events)
    feed(s, range(400, 500), 0)                  # reference back
    t = assert_aligned(collect_all(s, 500 * H_NS + 1000))
    assert t.size > 90


def test_order_mode_pause_becomes_time_gap_but_a_stall_with_catch_up_does_not():
    s = make()
    feed(s, range(100), 0)
    t1 = assert_aligned(collect_all(s, 100 * H_NS))
    pause_ns = 300_000_000                        # the publisher really stops for 0.3 s
    feed(s, range(100, 200), pause_ns)
    blocks = collect_all(s, pause_ns + 200 * H_NS + 50_000_000)
    t2 = assert_aligned(blocks)
    assert s.counters.gaps == 1
    assert t2[0] - t1[-1] == pytest.approx(0.3 + 1.0 / RATE, abs=2e-3)
    # stall: 100 samples delayed by the executor and delivered in one burst, grid unchanged
    s2 = make()
    feed(s2, range(100), 0)
    burst = 100 * H_NS + 100_000_000
    for k in range(100, 200):
        for i in range(3):
            s2.queues[i].append((float(k), burst + k * 1000))
    t3 = assert_aligned(collect_all(s2, burst + 200 * 1000))
    assert t3.size == 200 and s2.counters.gaps == 0
    np.testing.assert_allclose(np.diff(t3), 1.0 / RATE, rtol=1e-9)


def test_stamped_mode_drops_orphans_and_out_of_order_stamps():
    s = make(stamped=True)
    feed(s, range(50), 0, stamped=True)
    feed(s, [50], 0, topics=(0, 2), stamped=True)   # input of sample 50 lost
    feed(s, range(51, 100), 0, stamped=True)
    feed(s, [10], 0, topics=(1,), stamped=True)     # a late, out-of-order input message
    feed(s, range(100, 110), 0, stamped=True)
    t = assert_aligned(collect_all(s, 200 * H_NS))
    assert t.size == 109
    assert s.counters.unmatched == 2 and s.counters.out_of_order == 1
    assert np.all(np.diff(t) > 0)


def test_time_floor_after_restore_keeps_times_increasing():
    s = make(stamped=True)
    s.set_time_floor(1e4)
    feed(s, range(10), 0, stamped=True)
    t = assert_aligned(collect_all(s, 20 * H_NS))
    assert t[0] > 1e4 + 0.5 and np.allclose(np.diff(t), 1e-3)


def test_stamps_that_continue_after_a_restored_state_keep_their_time():
    """Data that resume where the saved state ended (the next stamp one sample later) continue the estimate: their
    times are their stamps, with no gap inserted; a stamp at or before the restored last time is moved above it."""
    s = make(stamped=True)
    last = (5_000_000_000 + 9 * H_NS) * 1e-9  # the restored pipeline's last sample: stamp 9 (feed's stamps)
    s.set_time_floor(last)
    feed(s, range(10, 20), 0, stamped=True)
    t = assert_aligned(collect_all(s, 30 * H_NS))
    np.testing.assert_allclose(t, (5_000_000_000 + np.arange(10, 20) * H_NS) * 1e-9, rtol=0, atol=1e-9)
    s = make(stamped=True)
    s.set_time_floor(last)
    feed(s, range(5, 15), 0, stamped=True)       # starts before the restored last sample
    t = assert_aligned(collect_all(s, 30 * H_NS))
    assert t[0] >= last + 1.0 and np.allclose(np.diff(t), 1e-3)


def test_bad_construction_is_rejected():
    with pytest.raises(ValueError, match="signals"):
        InputSync(("bogus",), RATE, stamped=False, max_backlog=5, quiet_s=0.1, gap_s=0.1, hold_s=0.0)
    with pytest.raises(ValueError, match="rate_hz"):
        InputSync(SIG, 0.0, stamped=False, max_backlog=5, quiet_s=0.1, gap_s=0.1, hold_s=0.0)


def test_order_mode_a_topic_stalled_by_dds_retransmission_loses_nothing():
    """Reliable DDS recovers a lost datagram at the writer's next heartbeat (Fast DDS: 3 s): one topic stalls
    while the others continue, then delivers its backlog in a burst. Within sync.stall_s (default 4 s) the
    pending samples wait: every sample comes out aligned, nothing is dropped, no resync and no time gap."""
    s = make(max_backlog=50)
    feed(s, range(100), 0)
    out = collect_all(s, 100 * H_NS)
    for k0 in range(100, 2500, 100):              # reference silent for 2.4 s, input and output on time
        feed(s, range(k0, k0 + 100), 0, topics=(1, 2))
        out += collect_all(s, (k0 + 100) * H_NS)
    burst = 2500 * H_NS + 1_000_000
    for k in range(100, 2500):
        s.queues[0].append((float(k), burst))
    feed(s, range(2500, 2600), 1_000_000)
    out += collect_all(s, 2600 * H_NS + 2_000_000)
    t = assert_aligned(out)
    assert t.size == 2600
    np.testing.assert_allclose(np.diff(t), 1.0 / RATE, rtol=1e-9)
    assert s.counters.dropped == 0 and s.counters.mismatches == 0 and s.counters.gaps == 0
    with pytest.raises(ValueError):
        make(stall_s=-1.0)


def test_absent_topic_keeps_the_queues_bounded_with_a_per_topic_drop_counter():
    """One topic never arrives: the others' samples are held at most max_queue each (oldest dropped, counted per
    topic, one event per episode), and memory stays flat (tracemalloc) however long the topic is absent."""
    import tracemalloc

    s = make(max_backlog=20, max_queue=200, stall_s=0.2)
    tracemalloc.start()
    peaks = []
    for k0 in range(0, 20000, 100):                # 20 s at 1 kHz, reference absent
        feed(s, range(k0, k0 + 100), 0, topics=(1, 2))
        assert collect_all(s, (k0 + 100) * H_NS) == []
        assert all(len(p) + len(q) <= 2 * s.max_queue for p, q in zip(s.pending, s.queues, strict=True))
        if k0 in (5000, 19900):
            peaks.append(tracemalloc.get_traced_memory()[0])
    tracemalloc.stop()
    assert peaks[1] - peaks[0] < 200 * 2 * 200, peaks        # no growth beyond a couple of queue bounds
    c = s.counters
    assert c.queue_dropped[0] == 0 and c.queue_dropped[1] > 0 and c.queue_dropped[2] > 0
    assert c.received[1] == 20000 and c.queue_dropped[1] >= 20000 - 2 * s.max_queue
    full = [e for e in s.events if "full" in e]
    assert len(full) == 2 and all("dropping the oldest" in e for e in full), list(s.events)   # one per topic
    # the reference comes back: aligned again (no misaligned sample), the episode ends once
    feed(s, range(20000, 20300), 0)
    out = collect_all(s, 20300 * H_NS + 1000)
    t = assert_aligned(out)
    assert t.size >= 200
    assert sum("below its bound again" in e for e in s.events) == 2


def test_callback_deque_overflow_is_counted_as_dropped_and_received():
    s = make(max_backlog=20, max_queue=100)
    for k in range(250):                         # the worker did not drain: the callback deque overflows
        for i in range(3):
            if len(s.queues[i]) >= s.max_queue:
                s.overflow[i] += 1               # what the node's callback does
            s.queues[i].append((float(k), k * H_NS))
    collect_all(s, 250 * H_NS)
    assert s.counters.received == [250, 250, 250] and s.counters.queue_dropped == [150, 150, 150]


def _rate_feed(s: InputSync, seconds: float, rate: float, t0_ns: int = 0, burst_every: int = 0) -> int:
    """Feed all topics at `rate` Hz (arrival stamps), draining every 2 ms; returns the end time."""
    h = 1e9 / rate
    n = int(seconds * rate)
    now = t0_ns
    k = 0
    next_check = t0_ns + 1_000_000_000
    while k < n:
        now += 2_000_000
        while k < n and t0_ns + k * h <= now:
            arr = now if burst_every and (k // burst_every) % 2 else int(t0_ns + k * h)
            for i in range(3):
                s.queues[i].append((float(k), arr))
            k += 1
        s.collect(now, idle_since_ns=0, ros_now_s=100.0)
        if now >= next_check:
            s.check_rates(now)
            next_check += 1_000_000_000
    return now


def test_arrival_rate_at_half_loop_rate_is_a_mismatch_with_a_one_line_reason():
    s = make(max_backlog=500, max_queue=20000, labels=("/reference", "/plant_input", "/plant_output"))
    _rate_feed(s, 6.0, RATE / 2)
    assert set(s.rate_mismatch) == {"/reference", "/plant_input", "/plant_output"}
    assert s.counters.rate_mismatches == 3
    ev = [e for e in s.events if e.startswith("arrival rate")]
    assert len(ev) == 3 and ev[-1] == "arrival rate 500 Hz on /plant_output, loop_rate_hz 1000", ev
    ok = make(max_backlog=500, max_queue=20000)
    _rate_feed(ok, 6.0, RATE * 1.005)             # within the 2 % tolerance
    assert not ok.rate_mismatch and ok.counters.rate_mismatches == 0
    assert abs(ok.measured_rate[0] / (RATE * 1.005) - 1) < 0.002


def test_stall_of_the_node_is_not_an_input_pause():
    """Samples held back by the node's own stall (the executor did not run) and partly lost: a time gap counted as
    the node's stall, not as an input pause; a real pause of the same length is an input pause."""
    s = make()
    feed(s, range(100), 0)
    collect_all(s, 100 * H_NS)
    s.note_stall(100 * H_NS, 100 * H_NS + 400_000_000)
    late = 100 * H_NS + 400_000_000               # 100 samples lost in the stall, the rest arrive after it
    for k in range(200, 300):
        for i in range(3):
            s.queues[i].append((float(k), late + (k - 200) * H_NS))
    assert_aligned(collect_all(s, late + 100 * H_NS + 300_000_000))
    assert s.counters.node_stall_gaps == 1 and s.counters.gaps == 0
    p = make()
    feed(p, range(100), 0)
    collect_all(p, 100 * H_NS)
    feed(p, range(100, 200), 300_000_000)
    collect_all(p, 200 * H_NS + 600_000_000)
    assert p.counters.gaps == 1 and p.counters.node_stall_gaps == 0
    assert s.silent(late, 0.1, looking_since_ns=late - 50_000_000) == []      # not looking long enough


def _limits(s: InputSync) -> tuple[int, ...]:
    st = s.settings
    return st.max_backlog, st.gap_ns, st.hold_ns, st.quiet_ns, st.persist_ns, st.silent_ns


def test_a_runtime_change_gets_the_floors_and_conversions_of_start_up():
    """update() (a runtime parameter change) gives the same limits as building the stage with the new values:
    the silence (stale_timeout_s) and the count-mismatch persistence never below a stall (sync.stall_s, 2 x
    sync.quiet_s); sync.gap_s 0 is automatic; sync.max_backlog_s at least 8 samples."""
    s = make(stall_s=4.0, silent_s=1.0)
    assert s.settings.silent_ns == 4_000_000_000                     # start-up floor: a stall
    s.update(silent_s=0.5)                                  # a runtime stale_timeout_s below the stall
    assert s.settings.silent_ns == 4_000_000_000 == make(stall_s=4.0, silent_s=0.5).settings.silent_ns
    s.update(quiet_s=3.0)                                   # the persistence follows quiet_s as at start-up
    assert (s.settings.persist_ns, s.settings.silent_ns) == (6_000_000_000, 6_000_000_000)
    assert _limits(s) == _limits(make(stall_s=4.0, silent_s=0.5, quiet_s=3.0))
    params = {"stale_timeout_s": 0.2, "sync.max_backlog_s": 0.001, "sync.gap_s": 0.0, "sync.quiet_s": 0.05,
              "sync.hold_s": 0.3}
    new = settings(params, RATE)
    assert new == {"silent_s": 0.2, "max_backlog": 8, "gap_s": 0.1, "quiet_s": 0.05, "hold_s": 0.3}
    s.update(**new)
    assert _limits(s) == _limits(make(stall_s=4.0, **new))
    assert settings({"sync.hold_s": 0.1}, RATE) == {"hold_s": 0.1}      # only what changed


def test_input_stage_answers_what_the_node_asks_without_probes():
    s = make()
    assert s.pairing == "arrival order" and make(stamped=True).pairing == "stamped"
    assert s.extra_values() == {} and s.lasting_reasons() == [] and s.queue_reasons() == [] and s.wake is None

