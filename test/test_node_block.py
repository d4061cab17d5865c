"""Block input (issue 14 item 7): Float64MultiArray rows ``index, reference, input, output`` paired by the
controller's index.

ROS-free part: :class:`BlockSync` (ros/blocks.py) on hand-made blocks -- exact times from the index, a lost block is
a counted gap, a late block within ``block.reorder_s`` is put back in order, retransmitted rows are dropped, a
counter that goes back is a restart, malformed blocks are counted with one log line, the controller invariant flags
swapped columns, and the same estimates as the per-sample path through the core (MonitorPipeline with the stream
aligner on the same samples).

Node part: rsrivc_monitor over real DDS (localhost, own domain) with ``block.topic``; its ~/modes must equal the
per-sample path's pipeline fed the same samples (the node is a shell around it; the sample times are exact because
the node's clock is a constant /clock, so the comparison is to rounding), also with a lost block, a retransmitted
block, malformed blocks and a controller restart, which are counted on /diagnostics while the node lives on.
"""
from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from test_node_helpers import Client, start_node, stop_node  # noqa: E402

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.ros import blocks
from additive_rsrivc_ros.ros.blocks import BlockSync
from additive_rsrivc_ros.ros.convert import block_message, block_rows
from additive_rsrivc_ros.sim import scenarios

REPO = Path(__file__).resolve().parents[1]
PAPER = str(REPO / "config" / "paper_example.yaml")
RATE = 20.0
MS = 1_000_000


def _sync(**kw) -> BlockSync:
    args = {"closed_loop": True, "label": "/block", "convert": block_rows, "reorder_s": 0.05}
    args.update(kw)
    return BlockSync(RATE, **args)


def _blk(k0: int, n: int, seed: int = 0) -> Float64MultiArray:
    rng = np.random.default_rng(seed + k0)
    k = np.arange(k0, k0 + n, dtype=float)
    return block_message(k, rng.standard_normal(n), rng.standard_normal(n), rng.standard_normal(n))


def _feed(s: BlockSync, msgs: list, now_ns: int, ros_now_s: float = 100.0):
    for m in msgs:
        s.enqueue(m, now_ns)
    return s.collect(now_ns, ros_now_s=ros_now_s)


def _rows(m: Float64MultiArray) -> np.ndarray:
    return np.asarray(m.data).reshape(-1, 4)


# ------------------------------------------------------------------------------------------- ROS-free (BlockSync)
def test_in_order_blocks_exact_times_and_values():
    s = _sync()
    msgs = [_blk(1000 + 10 * j, 10) for j in range(5)]
    out = _feed(s, msgs, 1 * MS, ros_now_s=100.0)
    rows = np.vstack([_rows(m) for m in msgs])
    assert len(out) == 50 and s.block["gaps"] == 0 and s.counters.received[0] == 50
    np.testing.assert_array_equal(out.t, 100.0 + (rows[:, 0] - 1000) / RATE)
    np.testing.assert_array_equal(np.column_stack([out.r, out.u, out.y]), rows[:, 1:])
    # open loop: the reference column is ignored
    s2 = _sync(closed_loop=False)
    out2 = _feed(s2, msgs[:1], 1 * MS)
    assert out2.r is None and np.array_equal(out2.u, rows[:10, 2])


def test_lost_block_is_a_counted_gap_and_late_block_within_window_is_reordered():
    s = _sync()
    a, b, c, d = (_blk(10 * j, 10) for j in range(4))
    first = _feed(s, [a, c], 1 * MS)              # b missing: c is held (reorder window 50 ms)
    assert len(first) == 10 and s.block["gaps"] == 0 and s.extra_values()["block_held_samples"] == 10
    late = _feed(s, [b], 20 * MS)                  # b arrives within the window: b then c, no gap
    assert np.array_equal(_rows(b)[:, 0], np.round((late.t[:10] - 100.0) * RATE))
    assert len(late) == 20 and s.block["gaps"] == 0 and s.block["reordered"] == 1
    # now d is lost for good: e waits 50 ms, then the hole is a gap of 10 samples; d arriving later is dropped
    e = _blk(40, 10)
    assert _feed(s, [e], 30 * MS) is None
    out = _feed(s, [], 81 * MS)
    assert len(out) == 10 and s.block["gaps"] == 1 and s.block["missing_samples"] == 10
    assert out.t[0] - late.t[-1] == pytest.approx(11 / RATE)
    assert any("index gap" in ev and "10 samples missing" in ev for ev in s.events)
    assert _feed(s, [d], 90 * MS) is None and s.block["late_samples"] == 10


def test_block_older_than_the_first_one_is_late_not_a_restart():
    s = _sync()
    assert len(_feed(s, [_blk(10, 10)], 1 * MS)) == 10
    assert _feed(s, [_blk(0, 10)], 2 * MS) is None
    assert s.block["late_samples"] == 10 and s.block["restarts"] == 0


def test_rows_missing_inside_a_block_are_a_gap_at_once():
    s = _sync()
    rows = _rows(_blk(0, 10))
    keep = np.r_[0:4, 7:10]
    m = block_message(rows[keep, 0], rows[keep, 1], rows[keep, 2], rows[keep, 3])
    out = _feed(s, [m], 1 * MS)
    assert len(out) == 7 and s.block["gaps"] == 1 and s.block["missing_samples"] == 3


def test_retransmitted_and_overlapping_blocks_drop_duplicates():
    s = _sync()
    a, b = _blk(0, 10), _blk(10, 10)
    _feed(s, [a, b], 1 * MS)
    assert _feed(s, [b], 2 * MS) is None and s.block["duplicate_samples"] == 10
    # overlapping retransmit: rows 15..24, of which 15..19 were released
    rb, rc = _rows(b), _rows(_blk(20, 10))
    over = np.vstack([rb[5:], rc[:5]])
    out = _feed(s, [block_message(*over.T)], 3 * MS)
    assert len(out) == 5 and np.array_equal(out.y, rc[:5, 3]) and s.block["duplicate_samples"] == 15
    assert s.block["restarts"] == 0 and s.block["gaps"] == 0


def test_a_retransmitted_block_longer_than_the_duplicate_memory_is_a_duplicate_not_a_restart():
    """100-row blocks at 20 Hz are 5 s each, longer than DUPLICATE_MEMORY_S (2 s = 40 rows): a block sent again after
    its first copy was released must still be recognized (it was called a controller restart and re-primed the
    estimator, depending on whether the worker had released the first copy yet: a CI timeout of the node test)."""
    s = _sync()
    a, b, c = _blk(0, 100), _blk(100, 100), _blk(200, 100)
    first = _feed(s, [a, b], 1 * MS)
    assert len(first) == 200
    assert _feed(s, [b], 2 * MS) is None                          # the whole block again, after its release
    assert s.block["duplicate_samples"] == 100 and s.block["restarts"] == 0 and s.block["gaps"] == 0
    # an overlapping retransmit reaching back over both released blocks (150 rows behind, 50 new)
    ra, rb, rc = _rows(a), _rows(b), _rows(c)
    over = np.vstack([ra[50:], rb, rc[:50]])
    out = _feed(s, [block_message(*over.T)], 3 * MS)
    assert len(out) == 50 and np.array_equal(out.y, rc[:50, 3]) and out.t[0] - first.t[-1] == pytest.approx(1 / RATE)
    assert s.block["duplicate_samples"] == 250 and s.block["restarts"] == 0 and s.block["gaps"] == 0
    # the same block with other values is still a restart
    _feed(s, [_blk(100, 100, seed=7)], 4 * MS)
    assert s.block["restarts"] == 1


def test_blocks_longer_than_the_stale_timeout_are_named_once_and_while_they_last():
    """A block of 100 rows at 20 Hz covers 5 s: with stale_timeout_s 1 s the input looks silent between blocks; the
    node must say why (one log line, a lasting reason) instead of only flapping to 'no data'."""
    s = _sync(silent_s=1.0)
    _feed(s, [_blk(0, 10)], 1 * MS)                                  # 0.5 s: fine
    assert s.lasting_reasons() == [] and not any("stale_timeout_s" in ev for ev in s.events)
    _feed(s, [_blk(10, 100), _blk(110, 100)], 2 * MS)
    lines = [ev for ev in s.events if "stale_timeout_s" in ev]
    assert len(lines) == 1 and "100 rows cover 5 s" in lines[0] and "above 5 s" in lines[0]
    assert any("stale_timeout_s" in r for r in s.lasting_reasons())
    s.update(silent_s=6.0)                                            # the user follows the advice (runtime change)
    assert s.lasting_reasons() == []
    _feed(s, [_blk(210, 100)], 3 * MS)
    assert len([ev for ev in s.events if "stale_timeout_s" in ev]) == 1


def test_a_block_contradicting_a_held_one_is_a_restart_not_a_duplicate():
    """Rows of a block waiting behind a hole, sent again with other values: a contradiction (the counter started a
    new run), never dropped as duplicates; the held rows are released first (the hole a gap), then the new run after
    a time jump. The same rows with equal values stay duplicates."""
    s = _sync()
    a, c = _blk(0, 10), _blk(20, 10)
    _feed(s, [a, c], 1 * MS)                                     # b (10..19) missing: c held
    assert s.extra_values()["block_held_samples"] == 10
    assert _feed(s, [c], 2 * MS) is None and s.block["duplicate_samples"] == 10 and s.block["restarts"] == 0
    c2 = _blk(20, 10, seed=7)                                     # same indices, other values
    out = _feed(s, [c2], 3 * MS)
    assert s.block["restarts"] == 1 and s.block["conflicting_samples"] == 10 and s.block["duplicate_samples"] == 10
    assert s.block["gaps"] == 1 and s.block["missing_samples"] == 10          # the hole before c
    assert len(out) == 20
    np.testing.assert_array_equal(out.y[:10], _rows(c)[:, 3])                  # the held rows first
    np.testing.assert_array_equal(out.y[10:], _rows(c2)[:, 3])                 # then the new run
    assert out.t[10] - out.t[9] >= blocks.RESTART_GAP_S
    assert any("controller restart" in ev and "10 rows reuse indices" in ev for ev in s.events)


def test_counter_going_back_is_a_restart_with_a_time_gap():
    s = _sync()
    msgs = [_blk(10 * j, 10) for j in range(10)]                 # 0..99
    before = _feed(s, msgs, 1 * MS)
    # index reused with other values (a restarted controller counting from 0 again): restart, not duplicates
    again = _feed(s, [_blk(0, 10, seed=7)], 2 * MS)
    assert s.block["restarts"] == 1 and s.block["duplicate_samples"] == 0 and len(again) == 10
    assert again.t[0] - before.t[-1] >= blocks.RESTART_GAP_S
    assert any("controller restart" in ev for ev in s.events)
    # the new run continues normally
    nxt = _feed(s, [_blk(10, 10, seed=7)], 3 * MS)
    assert len(nxt) == 10 and nxt.t[0] - again.t[-1] == pytest.approx(1 / RATE)
    # far back (beyond the duplicate memory of 2 s = 40 samples here): restart too
    s2 = _sync()
    _feed(s2, [_blk(1000 + 10 * j, 10) for j in range(10)], 1 * MS)
    _feed(s2, [_blk(5, 10)], 2 * MS)
    assert s2.block["restarts"] == 1


@pytest.mark.parametrize("what", ["labels", "signal_size", "length", "nan_index", "fraction_index", "decreasing",
                                  "dims", "column_major", "empty"])
def test_malformed_blocks_are_counted_and_logged_once(what):
    s = _sync()
    good = _blk(0, 8)
    rows = _rows(good).copy()
    m = block_message(*rows.T)
    if what == "labels":
        m.layout.dim[0].label = "rows"
    elif what == "signal_size":
        m.layout.dim[1].size = 3
    elif what == "length":
        m.data = m.data[:-1]
    elif what == "nan_index":
        rows[3, 0] = np.nan
        m = block_message(*rows.T)
    elif what == "fraction_index":
        rows[3, 0] += 0.5
        m = block_message(*rows.T)
    elif what == "decreasing":
        rows[[2, 3], 0] = rows[[3, 2], 0]
        m = block_message(*rows.T)
    elif what == "dims":
        m.layout.dim = [MultiArrayDimension(label="sample", size=32, stride=32)]
    elif what == "column_major":
        m.layout.dim[0].stride, m.layout.dim[1].stride = 8, 1
    elif what == "empty":
        m = Float64MultiArray()
        m.layout.dim = [MultiArrayDimension(label="sample", size=0, stride=0),
                        MultiArrayDimension(label="signal", size=4, stride=4)]
    out = _feed(s, [m] * 3, 1 * MS)
    assert out is None and s.block["malformed"] == 3 and s.counters.received[0] == 0
    assert sum("malformed block" in ev for ev in s.events) == 1            # throttled: one line
    assert _feed(s, [good], 2 * MS) is not None                             # and the input goes on


def test_queue_bound_drops_oldest_blocks_counted_as_gap():
    s = _sync(max_queue=100)
    msgs = [_blk(10 * j, 10) for j in range(20)]                  # 200 rows queued before the worker runs
    for m in msgs:
        s.enqueue(m, 1 * MS)
    out = s.collect(1 * MS, ros_now_s=100.0)
    assert s.counters.queue_dropped[0] >= 100 and len(out) + s.counters.queue_dropped[0] == 200
    assert s.block["gaps"] == 0          # the oldest blocks went: the stream starts later, nothing is skipped inside
    assert any("queue of /block full" in ev for ev in s.events)


def test_invariant_flags_swapped_columns():
    sc = scenarios.build("paper_example", duration_s=20.0, seed=1)
    cfg = MonitorConfig.from_params(load_params_file(PAPER))
    k = np.arange(sc.t.size, dtype=float)
    ok = _sync(controller=cfg.controller, silent_s=5.0)                # blocks of 50 rows cover 2.5 s
    _feed(ok, [block_message(k[j:j + 50], sc.r[j:j + 50], sc.u[j:j + 50], sc.y[j:j + 50])
               for j in range(0, k.size, 50)], 1 * MS)
    assert ok.invariant_relative < 1e-12 and ok.lasting_reasons() == []
    bad = _sync(controller=cfg.controller, silent_s=30.0)
    _feed(bad, [block_message(k, sc.r, sc.y, sc.u)], 1 * MS)          # input and output swapped
    assert bad.invariant_relative > blocks.INVARIANT_WARN
    assert len(bad.lasting_reasons()) == 1 and "column order" in bad.lasting_reasons()[0]
    assert isinstance(cfg.controller, DiscreteController)


def _block_samples(sc, ros_now_s: float, keep: np.ndarray | None = None):
    """What the node's BlockSync releases for the scenario's rows (all, or only ``keep``), by the same arithmetic."""
    k = np.arange(sc.t.size, dtype=np.int64)
    keep = np.ones(k.size, dtype=bool) if keep is None else keep
    t = ros_now_s + (k - k[0]).astype(np.float64) / RATE
    return t[keep], sc.r[keep], sc.u[keep], sc.y[keep]


def test_block_path_equals_per_sample_path_in_the_core():
    """The same samples through the per-sample path's pipeline (stream aligner on) and the block path's (off):
    equal reports. The aligner only re-pairs; on aligned data it must release every sample unchanged."""
    sc = scenarios.build("paper_example", duration_s=90.0, seed=2)
    cfg = MonitorConfig.from_params(load_params_file(PAPER))
    t, r, u, y = _block_samples(sc, 1000.0)
    per_sample = MonitorPipeline(cfg)
    assert per_sample.aligner is not None
    rep_a = per_sample.push(t, r, u, y) + per_sample.flush()
    block = MonitorPipeline(cfg.with_block_input())
    assert block.aligner is None
    rep_b = []
    for j in range(0, t.size, 100):
        rep_b += block.push(t[j:j + 100], r[j:j + 100], u[j:j + 100], y[j:j + 100])
    assert len(rep_a) == len(rep_b) and rep_b[-1].estimating
    for a, b in zip(rep_a, rep_b, strict=True):
        assert a.time_s == b.time_s
        np.testing.assert_allclose(b.modal, a.modal, rtol=1e-12, atol=0.0, equal_nan=True)


# ------------------------------------------------------------------------------------------- node over DDS
class _BlockClient(Client):
    """Client with a block publisher and a constant /clock (the node runs with use_sim_time)."""

    def __init__(self, dom: int, clock_s: int) -> None:
        super().__init__(dom, Float64MultiArray)
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock

        self.block = self.node.create_publisher(Float64MultiArray, "/block", QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        self.clock = self.node.create_publisher(Clock, "/clock", 10)
        self._msg = Clock(clock=Time(sec=clock_s, nanosec=0))
        self._stop = threading.Event()
        self._tick = threading.Thread(target=self._clock_loop, daemon=True)
        self._tick.start()

    def _clock_loop(self) -> None:
        while not self._stop.wait(0.05):
            try:
                self.clock.publish(self._msg)
            except Exception:  # noqa: BLE001 - context shut down
                return

    def close(self) -> None:
        self._stop.set()
        self._tick.join(2.0)
        super().close()


CLOCK_S = 1000
BLOCK_ARGS = ("block.topic:=block", "use_sim_time:=true", "stale_timeout_s:=30.0", "qos_depth:=30000")


def _wait_block_matched(cli: _BlockClient) -> None:
    cli.wait_for(lambda: cli.block.get_subscription_count() > 0 and cli.clock.get_subscription_count() > 0, 30,
                 "the node's /block and /clock subscriptions")
    # the node's time must be the constant clock before the first block (a block stamped at ROS time 0 and the next
    # at the clock would be a time jump): its /diagnostics carry the node's time in their stamps
    cli.wait_for(lambda: any(d.header.stamp.sec == cli._msg.clock.sec for d in list(cli.diags)), 30,
                 "the node's clock at the constant /clock (its /diagnostics stamps)")


def _est(cli: Client) -> dict:
    st = cli.status("estimator")
    return {} if st is None else st["values"]


def _reference(sc, keep=None):
    """The per-sample path's pipeline (aligner on) fed the samples the node's block input releases."""
    cfg = MonitorConfig.from_params(load_params_file(PAPER))
    pipe = MonitorPipeline(cfg)
    ros_now = CLOCK_S * 1_000_000_000 * 1e-9          # the node's expression (ns * 1e-9)
    reports = pipe.push(*_block_samples(sc, ros_now, keep))
    reports += pipe.flush()
    return pipe, reports


def test_node_block_input_equals_per_sample_path(ros_env):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("paper_example", duration_s=90.0, seed=3)
    n = sc.t.size
    _, reports = _reference(sc)
    ref = reports[-1]
    assert ref.estimating
    proc = start_node(ros_env, PAPER, *BLOCK_ARGS)
    cli = _BlockClient(dom, CLOCK_S)
    try:
        _wait_block_matched(cli)
        k = np.arange(n, dtype=float)
        for j in range(0, n, 100):
            cli.block.publish(block_message(k[j:j + 100], sc.r[j:j + 100], sc.u[j:j + 100], sc.y[j:j + 100]))

        def caught_up() -> bool:
            return bool(cli.modes) and np.allclose(np.asarray(cli.modes[-1].data), ref.modal.ravel(), rtol=1e-9,
                                                   atol=0.0, equal_nan=True)
        cli.wait_for(caught_up, 60, "~/modes equal to the per-sample path's last report")
        cli.wait_for(lambda: int(_est(cli).get("samples_aligned", 0)) == n, 20, "every row on /diagnostics")
        e = _est(cli)
        assert int(e["samples_received"]) == n and int(e["samples_dropped"]) == 0
        assert int(e["block_gaps"]) == 0 and int(e["gaps"]) == 0 and e["alignment"] == "off"
        assert float(e["block_invariant_relative_residual"]) < 1e-12
    finally:
        cli.close()
        rc, out = stop_node(proc, "TERM")
    assert rc == 0, out
    assert "Traceback" not in out and "block rows paired by the controller's index" in out


def _malformed_set() -> list[Float64MultiArray]:
    bad = []
    m = _blk(0, 4)
    m.layout.dim[0].label = "row"
    bad.append(m)
    m = _blk(0, 4)
    m.data = m.data[:-2]
    bad.append(m)
    rows = _rows(_blk(0, 4)).copy()
    rows[1, 0] = math.inf
    bad.append(block_message(*rows.T))
    rows[1, 0] = 0.25
    bad.append(block_message(*rows.T))
    return bad


def test_node_block_gap_duplicate_malformed_restart(ros_env):
    """A lost block is one counted gap (the estimator re-primes as on every path; the estimate equals the per-sample
    pipeline's on the same samples with the hole), a retransmitted block is dropped, malformed blocks are counted with
    one log line, a controller restart is counted and estimation goes on."""
    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("paper_example", duration_s=90.0, seed=4)
    n = sc.t.size
    lost = slice(1400, 1500)                      # after the initialization (50 s = 1000 samples)
    keep = np.ones(n, dtype=bool)
    keep[lost] = False
    pipe, reports = _reference(sc, keep)
    ref = reports[-1]
    assert ref.estimating and pipe.counters.gaps == 1
    proc = start_node(ros_env, PAPER, *BLOCK_ARGS)
    cli = _BlockClient(dom, CLOCK_S)
    bad = _malformed_set()
    try:
        _wait_block_matched(cli)
        k = np.arange(n, dtype=float)
        for j in range(0, n, 100):
            if j == lost.start:
                for m in bad:
                    cli.block.publish(m)
                continue
            msg = block_message(k[j:j + 100], sc.r[j:j + 100], sc.u[j:j + 100], sc.y[j:j + 100])
            cli.block.publish(msg)
            if j == 600:
                cli.block.publish(msg)            # retransmitted

        def caught_up() -> bool:
            return bool(cli.modes) and np.allclose(np.asarray(cli.modes[-1].data), ref.modal.ravel(), rtol=1e-9,
                                                   atol=0.0, equal_nan=True)
        try:
            cli.wait_for(caught_up, 60, "~/modes equal to the per-sample path's last report with the same hole")
        except AssertionError as exc:   # say what the node did (a rare CI timeout left nothing to go on)
            last = np.asarray(cli.modes[-1].data) if cli.modes else None
            keys = ("samples_aligned", "block_gaps", "block_missing_samples", "block_duplicate_samples", "gaps",
                    "malformed_messages", "phase", "initializations", "reinitializations")
            raise AssertionError(f"{exc}; node ~/modes {last} vs reference {ref.modal.ravel()}; node estimator "
                                 f"status { {k: _est(cli).get(k) for k in keys} }") from None
        cli.wait_for(lambda: int(_est(cli).get("samples_aligned", 0)) == n - 100, 20, "every row on /diagnostics")
        e = _est(cli)
        assert int(e["block_gaps"]) == 1 and int(e["block_missing_samples"]) == 100
        assert int(e["gaps"]) == 1                           # the pipeline's own data gap: re-primed, on health
        assert int(e["block_duplicate_samples"]) == 100 and int(e["malformed_messages"]) == len(bad)
        assert e["phase"] != "initializing"
        # controller restart: the counter starts again at 0 with new data; estimation continues
        sc2 = scenarios.build("paper_example", duration_s=20.0, seed=5)
        k2 = np.arange(sc2.t.size, dtype=float)
        for j in range(0, k2.size, 100):
            cli.block.publish(block_message(k2[j:j + 100], sc2.r[j:j + 100], sc2.u[j:j + 100], sc2.y[j:j + 100]))
        cli.wait_for(lambda: int(_est(cli).get("samples_aligned", 0)) == n - 100 + k2.size, 30, "the new run")
        e = _est(cli)
        assert int(e["block_restarts"]) == 1 and int(e["gaps"]) == 2 and e["phase"] != "initializing"
        assert int(e["initializations"]) == 1                 # re-primed, not re-initialized
        cli.wait_for(lambda: np.all(np.isfinite(np.asarray(cli.modes[-1].data))), 20, "finite estimates")
    finally:
        cli.close()
        rc, out = stop_node(proc, "TERM")
        print(out[-6000:])    # the node's log, shown by pytest when the test fails
    assert rc == 0, out
    assert "Traceback" not in out
    assert sum("malformed block" in ln for ln in out.splitlines()) == 1, out
    assert "controller restart" in out and "index gap" in out


def test_block_input_runtime_change_applies_the_silence_as_at_start_up():
    """Block input takes stale_timeout_s without the Float64 stall floor, at start-up and at runtime alike, and
    ignores the Float64-only settings (backlog, quiet, hold) as its start-up does."""
    s = _sync(silent_s=1.0)
    assert s.settings.silent_ns == 1_000_000_000
    before = (s.settings.max_backlog, s.settings.quiet_ns, s.settings.hold_ns, s.settings.persist_ns)
    s.update(silent_s=0.3, gap_s=0.2, max_backlog=3, quiet_s=9.0, hold_s=1.0)
    fresh = _sync(silent_s=0.3, gap_s=0.2)
    assert ((s.settings.silent_ns, s.settings.gap_ns) == (fresh.settings.silent_ns, fresh.settings.gap_ns)
            == (300_000_000, 200_000_000))
    assert (s.settings.max_backlog, s.settings.quiet_ns, s.settings.hold_ns, s.settings.persist_ns) == before



def test_blocks_slower_than_loop_rate_hz_are_a_rate_error():
    """120-row blocks every 0.12 s (a 1 kHz loop) into an input configured for 4096 Hz: the arrival rate is judged per
    row although blocks arrive more than the data gap (0.1 s) apart, and the mismatch is the input's rate error
    (nothing is published then); the same blocks at 1 kHz configured are fine."""
    for rate, bad in ((4096.0, True), (1000.0, False)):
        s = BlockSync(rate, closed_loop=True, label="/block", convert=block_rows, reorder_s=0.05)
        now = 1_000 * MS
        for j in range(60):                        # 7.2 s of blocks
            now += 120 * MS
            _feed(s, [_blk(120 * j, 120)], now, ros_now_s=100.0 + 0.12 * j)
            if j % 10 == 9:
                s.check_rates(now)
        assert s.measured_rate[0] == pytest.approx(1000.0, rel=0.02)
        assert bool(s.rate_error) is bad
        if bad:
            assert "loop_rate_hz disagrees with the data's timing" in s.rate_error and "1000 Hz" in s.rate_error


def test_node_block_input_slower_than_configured_is_an_error_with_nothing_published(ros_env):
    """The node configured for 4096 Hz, fed 100-row blocks of a 1 kHz loop in real time: an ERROR naming the rate,
    mode statuses without numbers, and no number on ~/modes once the rate is judged (a 2 s window)."""
    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("beam_fault", duration_s=12.0, seed=1)
    proc = start_node(ros_env, str(REPO / "config" / "beam_fault.yaml"), "block.topic:=block", "init_duration_s:=0.5",
                      "stale_timeout_s:=30.0")
    cli = Client(dom, Float64MultiArray)
    block = cli.node.create_publisher(Float64MultiArray, "/block", QoSProfile(depth=100,
                                                                            reliability=ReliabilityPolicy.RELIABLE))
    try:
        cli.wait_for(lambda: block.get_subscription_count() > 0, 30, "the node's /block subscription")
        k = np.arange(sc.t.size, dtype=float)
        t_next, n_at_error = time.monotonic(), None
        for j in range(0, 100 * 100, 100):          # 10 s of a 1 kHz loop, one block per 0.1 s
            block.publish(block_message(k[j:j + 100], sc.r[j:j + 100], sc.u[j:j + 100], sc.y[j:j + 100]))
            t_next += 0.1
            time.sleep(max(0.0, t_next - time.monotonic()))
            est = cli.status("estimator")
            if n_at_error is None and est is not None and est["level"] == 2:
                n_at_error = len(cli.modes)
        est = cli.status("estimator")
        assert est is not None and est["level"] == 2 and "loop_rate_hz disagrees" in est["message"], est
        mode = cli.status("mode 2")
        assert mode["level"] == 2 and mode["values"]["natural_frequency_hz"] == "nan", mode
        # found within the rate window (2 s of arrivals, two windows); from then on no estimate is published
        assert n_at_error is not None
        later = np.array([m.data for m in cli.modes[n_at_error + 2:]], dtype=float)
        assert later.size == 0 or not np.isfinite(later).any(), later
    finally:
        cli.close()
        rc, out = stop_node(proc, "TERM")
    assert rc == 0 and "Traceback" not in out, out
