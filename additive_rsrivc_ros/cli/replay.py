"""``rsrivc_replay BAG [--rate X] [--clock [HZ]] [--loop] [--topics ...] [--block N] [--stats]``.

Publishes a rosbag2 over DDS at its recorded timing, a stand-in for ``ros2 bag play`` (not on PyPI). Messages go out as
the raw CDR stored in the bag (no (de)serialization in Python), each at the deadline ``start + (log_time - bag_start) /
rate`` on the monotonic clock, due messages in one batch, so sleep overshoot never accumulates. ``--clock`` also
publishes ``/clock`` with the bag time for ``use_sim_time`` nodes; with ``--loop`` the bag time keeps increasing over
passes. ``--block N`` publishes the bag's r, u, y instead as ``Float64MultiArray`` blocks of N rows in the monitor's
block-input layout (docs/INTERFACE.md), read like ``rsrivc_diagnose`` reads them, ``index`` the sample's position on the
bag's grid (a pause in the recording is an index gap). Ctrl-C and SIGTERM stop playback cleanly (exit status 0, one line
on stderr).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..process_exit import console_entry
from ..signal_stop import SignalStop, StopFlag
from .parser import OneLineParser

if TYPE_CHECKING:
    from ..config import SignalConfig

#: the simulation's truth topics (bagio.TRUTH_MODES_TOPIC, TRUTH_FAULT_TOPIC; bagio is not imported here: it loads
#: rosbags): replayed, but --wait-for-subscribers does not wait for them (no monitor reads them)
TRUTH_TOPICS = ("/truth/modes", "/truth/fault")

PROG = "rsrivc_replay"


class ReplayError(RuntimeError):
    """A bag or option that cannot be replayed; the message is one line."""


@dataclass
class BagPlan:
    """What will be replayed: topic -> message type, message count, time span (ns)."""

    path: Path
    topics: dict[str, str]
    counts: dict[str, int]
    start_ns: int
    end_ns: int

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9

    @property
    def n_messages(self) -> int:
        return sum(self.counts.values())


@dataclass
class PlayStats:
    """Timing figures of one playback (wall clock, monotonic)."""

    published: int = 0
    batches: int = 0
    wall_s: float = 0.0
    bag_s: float = 0.0
    max_late_s: float = 0.0
    sum_late_s: float = 0.0
    passes: int = 0
    interrupted: bool = False
    per_topic: dict[str, int] = field(default_factory=dict)

    @property
    def msgs_per_s(self) -> float:
        return self.published / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def realtime_factor(self) -> float:
        """Bag time covered per wall second (1.0 = recorded speed)."""
        return self.bag_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def mean_late_s(self) -> float:
        return self.sum_late_s / self.published if self.published else 0.0


def _open_reader(path: Path) -> Any:
    """Open a rosbags reader; every failure becomes a one-line :class:`ReplayError`."""
    from rosbags.rosbag2 import Reader

    if not path.exists():
        raise ReplayError(f"bag not found: {path}")
    if path.is_dir() and not (path / "metadata.yaml").exists():
        raise ReplayError(f"{path} is a directory without metadata.yaml (not a rosbag2 bag)")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises several types for corrupt/truncated files
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ReplayError(f"cannot open bag {path}: {msg}") from None
    return reader


def inspect_bag(path: str | Path, topics: Iterable[str] | None = None) -> BagPlan:
    """Check that the bag opens and holds the requested topics; return the replay plan."""
    path = Path(path)
    reader = _open_reader(path)
    try:
        available = {c.topic: c.msgtype for c in reader.connections}
        if topics:
            wanted = list(dict.fromkeys(topics))
            missing = [t for t in wanted if t not in available]
            if missing:
                raise ReplayError(f"topic(s) not in bag {path}: {', '.join(missing)} "
                                  f"(bag has {', '.join(sorted(available)) or 'no topics'})")
        else:
            wanted = sorted(available)
        counts = dict.fromkeys(wanted, 0)
        for c in reader.connections:
            if c.topic in counts:
                counts[c.topic] += int(c.msgcount)
        if sum(counts.values()) == 0:
            raise ReplayError(f"bag {path} has no messages to replay")
        return BagPlan(path, {t: available[t] for t in wanted}, counts, int(reader.start_time), int(reader.end_time))
    finally:
        reader.close()


def iter_bag(plan: BagPlan) -> Iterator[tuple[str, int, bytes]]:
    """Yield ``(topic, log_time_ns, raw_cdr)`` in log-time order for the plan's topics."""
    reader = _open_reader(plan.path)
    try:
        conns = [c for c in reader.connections if c.topic in plan.topics]
        try:
            for conn, stamp, raw in reader.messages(connections=conns):
                yield conn.topic, int(stamp), bytes(raw)
        except Exception as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ReplayError(f"bag {plan.path} is truncated or corrupt: {msg}") from None
    finally:
        reader.close()


def _tick(clock: Callable[[int], None], bag_ns: int, last_ns: int) -> int:
    """Publish the clock only forwards in time; return the last published value."""
    if bag_ns > last_ns:
        clock(bag_ns)
        return bag_ns
    return last_ns


def play(
    messages: Callable[[], Iterable[tuple[str, int, bytes]]],
    publish: Callable[[str, bytes], None],
    *,
    rate: float = 1.0,
    loop: bool = False,
    loop_period_ns: int = 0,
    stop: StopFlag | None = None,
    clock: Callable[[int], None] | None = None,
    clock_period_s: float = 0.01,
    min_sleep_s: float = 0.001,
    max_sleep_s: float = 0.1,
    now: Callable[[], float] = time.monotonic,
) -> PlayStats:
    """Publish messages at their recorded timing scaled by ``1/rate``; ROS-free (callbacks do the I/O).

    Deadlines are absolute (no drift); messages whose deadline has passed are published in one batch,
    then the loop sleeps until the next deadline but at least ``min_sleep_s``. ``clock(bag_time_ns)``
    is called before the first message and then every ``clock_period_s`` of wall time (never backwards).
    With ``loop``, each pass starts ``loop_period_ns`` after the previous pass's last message in bag
    time, so that the bag time stays monotonic.
    """
    if not rate > 0.0:
        raise ReplayError(f"--rate must be > 0, got {rate}")
    stop = stop or threading.Event()
    stats = PlayStats()
    t_wall0: float | None = None
    bag0: int | None = None
    last_clock = -1e300
    last_clock_ns = -1
    offset = 0
    last_bag_ns = 0
    while not stop.is_set():
        n_before = stats.published
        for topic, stamp, raw in messages():
            if stop.is_set():
                break
            if bag0 is None or t_wall0 is None:
                bag0, t_wall0 = stamp, now()
            bag_ns = stamp + offset
            deadline = t_wall0 + (bag_ns - bag0) * 1e-9 / rate
            t = now()
            if deadline > t:
                stats.batches += 1
                while not stop.is_set():  # sleep in slices so that a stop request is honoured quickly
                    if clock is not None and stats.published and t - last_clock >= clock_period_s:
                        last_clock_ns = _tick(clock, min(bag0 + int((t - t_wall0) * rate * 1e9), bag_ns), last_clock_ns)
                        last_clock = t
                    wait = deadline - t
                    if wait <= 0:
                        break
                    stop.wait(min(max(wait, min_sleep_s), max_sleep_s, clock_period_s if clock else max_sleep_s))
                    t = now()
                if stop.is_set():
                    break
                t = now()
            if clock is not None and (stats.published == 0 or t - last_clock >= clock_period_s):
                last_clock_ns = _tick(clock, bag_ns, last_clock_ns)
                last_clock = t
            publish(topic, raw)
            late = t - deadline
            stats.published += 1
            stats.per_topic[topic] = stats.per_topic.get(topic, 0) + 1
            stats.sum_late_s += max(late, 0.0)
            stats.max_late_s = max(stats.max_late_s, late)
            last_bag_ns = bag_ns
        if stop.is_set():
            break
        stats.passes += 1
        if not loop or stats.published == n_before or bag0 is None:
            break
        offset = last_bag_ns + max(loop_period_ns, 1) - bag0
    stats.interrupted = stop.is_set()
    if t_wall0 is not None:
        stats.wall_s = now() - t_wall0
        stats.bag_s = (last_bag_ns - bag0) * 1e-9 if bag0 is not None else 0.0
    return stats


BLOCK_SIGNAL_TOPICS = ("/reference", "/plant_input", "/plant_output")


@dataclass
class BlockPlan:
    """The bag's samples on its grid for ``--block``: index, r (NaN in open loop), u, y, log times (ns)."""

    index: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    log_ns: np.ndarray
    rate_hz: float

    @property
    def n(self) -> int:
        return int(self.index.size)


@dataclass(frozen=True)
class _TopicsView:
    """The block topics of a bag as :func:`..bagio.read_signals` reads a configuration (``bagio.SignalSource``)."""

    closed_loop: bool
    loop_rate_hz: float
    signals: dict[str, SignalConfig]


def plan_blocks(plan: BagPlan, topics: list[str] | None) -> BlockPlan:
    """Read r, u, y of the bag for ``--block`` (one-line :class:`ReplayError` on failure); see the module docstring.

    ``topics``: ``[reference,] input, output`` topics (default ``/reference`` when the bag has it, ``/plant_input``,
    ``/plant_output``)."""
    from ..config import SignalConfig
    from ..io.bagio import FLOAT64, BagError, mean_sample_spacing, read_signals

    names = list(topics) if topics else [t for t in BLOCK_SIGNAL_TOPICS if t in plan.topics or t != "/reference"]
    if len(names) not in (2, 3):
        raise ReplayError(f"--block needs 2 (input, output) or 3 (reference, input, output) topics, got {len(names)}")
    closed = len(names) == 3
    sig_names = ("reference", "input", "output") if closed else ("input", "output")
    missing = [t for t in names if t not in plan.topics]
    if missing:
        raise ReplayError(f"topic(s) not in bag {plan.path}: {', '.join(missing)}")
    n_out = plan.counts[names[-1]]
    if n_out < 2 or plan.end_ns <= plan.start_ns:
        raise ReplayError(f"bag {plan.path}: {names[-1]} has {n_out} message(s): no sample grid for --block")
    out_ns = np.fromiter((stamp for _, stamp, _ in iter_bag(BagPlan(plan.path, {names[-1]: ""}, {}, 0, 0))),
                         dtype=np.int64)
    view = _TopicsView(closed_loop=closed, loop_rate_hz=1.0 / mean_sample_spacing(out_ns),
                       signals={s: SignalConfig(t, FLOAT64) for s, t in zip(sig_names, names, strict=True)})
    try:
        sig = read_signals(plan.path, view)
    except BagError as exc:
        raise ReplayError(str(exc)) from None
    t = np.asarray(sig.t, dtype=np.float64)
    h = 1.0 / view.loop_rate_hz
    index = np.rint(t / h) if h > 0 else np.full(t.size, np.nan)
    if not (np.all(np.isfinite(index)) and np.all(np.diff(index) > 0) and np.all(np.abs(t - index * h) < 0.5 * h)):
        raise ReplayError(f"bag {plan.path}: the samples do not lie on a uniform grid (jitter above half a sample "
                          "period, or repeated times): no index for --block")
    r = np.full(t.size, np.nan) if sig.r is None else np.asarray(sig.r, dtype=np.float64)
    log_ns = int(sig.t0_ns) + np.rint(t * 1e9).astype(np.int64)
    return BlockPlan(index, r, np.asarray(sig.u, float), np.asarray(sig.y, float), log_ns, 1.0 / h)


def iter_blocks(bp: BlockPlan, rows: int, topic: str) -> Callable[[], Iterator[tuple[str, int, Any]]]:
    """A ``messages`` source for :func:`play`: blocks of ``rows`` rows at the log time of their last row; each pass
    (``--loop``) continues the index where the previous one ended."""
    from ..ros.convert import block_message

    passes = [0]

    def gen() -> Iterator[tuple[str, int, Any]]:
        shift = passes[0] * (int(bp.index[-1]) + 1)
        passes[0] += 1
        for j in range(0, bp.n, rows):
            sl = slice(j, min(j + rows, bp.n))
            yield topic, int(bp.log_ns[sl.stop - 1]), block_message(bp.index[sl] + shift, bp.r[sl], bp.u[sl],
                                                                     bp.y[sl])
    return gen


def _msg_class(msgtype: str) -> Any:
    """Import the rclpy message class of ``pkg/msg/Name``."""
    parts = msgtype.split("/")
    if len(parts) != 3:
        raise ReplayError(f"cannot handle message type {msgtype!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.{parts[1]}"), parts[2])
    except (ImportError, AttributeError):
        if importlib.util.find_spec("rclpy") is None:       # no ROS 2 at all: say how to get it
            from ..node import INSTALL_ROS

            raise ReplayError(f"message type {msgtype} is not installed in this environment (ROS 2 Jazzy is not "
                              f"installed for this Python: {INSTALL_ROS})") from None
        raise ReplayError(f"message type {msgtype} is not installed in this environment") from None


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog=PROG, description="Publish a rosbag2 (mcap/sqlite3) over DDS at its "
                                 "recorded timing (raw CDR); a stand-in for 'ros2 bag play'.")
    ap.add_argument("bag", help="bag directory (with metadata.yaml) or a single .mcap/.db3 file")
    ap.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1.0)")
    ap.add_argument("--clock", nargs="?", type=float, const=100.0, default=None, metavar="HZ",
                    help="also publish /clock (rosgraph_msgs/Clock) with the bag time at HZ (default 100)")
    ap.add_argument("--loop", action="store_true", help="replay the bag again and again until stopped")
    ap.add_argument("--topics", nargs="+", metavar="TOPIC", help="replay only these topics (default: all)")
    ap.add_argument("--qos-depth", type=int, default=30000,
                    help="KEEP_LAST depth of the reliable publishers (default 30000: 7 s at 4096 Hz, more than the "
                         "node's 5 s reader history, so a subscriber stalled for seconds loses nothing)")
    ap.add_argument("--delay", type=float, default=0.0, help="seconds to wait after creating publishers")
    ap.add_argument("--wait-for-subscribers", type=float, default=None, metavar="TIMEOUT_S", const=30.0,
                    nargs="?", help="before playing, wait until every signal topic has a subscriber (default 30 s; "
                                    "the simulation's truth topics /truth/*, which no monitor reads, are not waited "
                                    "for)")
    ap.add_argument("--block", type=int, default=0, metavar="N", help="publish the bag's r, u, y as "
                    "Float64MultiArray blocks of N rows (columns index, reference, input, output; the monitor's "
                    "block.topic input) instead of the recorded topics; --topics then names [reference] input output")
    ap.add_argument("--block-topic", default="/block", help="topic of --block (default /block)")
    ap.add_argument("--stats", action="store_true", help="print achieved message rate and lateness")
    ap.add_argument("--node-name", default="rsrivc_replay", help="ROS node name")
    return ap


@console_entry
def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 also after Ctrl-C/SIGTERM)."""
    args = _parser().parse_args(argv)
    try:
        if not args.rate > 0.0:
            raise ReplayError(f"--rate must be > 0, got {args.rate}")
        if args.clock is not None and not args.clock > 0.0:
            raise ReplayError(f"--clock rate must be > 0 Hz, got {args.clock}")
        if args.qos_depth < 1:
            raise ReplayError(f"--qos-depth must be >= 1, got {args.qos_depth}")
        if args.block < 0:
            raise ReplayError(f"--block must be >= 1 rows, got {args.block}")
        plan = inspect_bag(args.bag, None if args.block else args.topics)
        block = plan_blocks(plan, args.topics) if args.block else None
        classes = {t: _msg_class(m) for t, m in plan.topics.items()}
        if block is not None:
            classes = {args.block_topic: _msg_class("std_msgs/msg/Float64MultiArray")}
    except ReplayError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2

    stop = SignalStop()
    stop.install()

    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    context = rclpy.Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = rclpy.create_node(args.node_name, context=context)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=args.qos_depth,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        pubs = {t: node.create_publisher(classes[t], t, qos) for t in classes}
        clock_cb = None
        if args.clock is not None:
            from builtin_interfaces.msg import Time
            from rosgraph_msgs.msg import Clock

            clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=100,
                                                                           reliability=ReliabilityPolicy.RELIABLE))

            def clock_cb(bag_ns: int) -> None:
                clock_pub.publish(Clock(clock=Time(sec=bag_ns // 1_000_000_000, nanosec=bag_ns % 1_000_000_000)))

        if args.wait_for_subscribers is not None:
            t_end = time.monotonic() + args.wait_for_subscribers
            awaited = {t: p for t, p in pubs.items() if t not in TRUTH_TOPICS} or pubs
            while not stop.is_set() and any(p.get_subscription_count() == 0 for p in awaited.values()):
                if time.monotonic() > t_end:
                    missing = [t for t, p in awaited.items() if p.get_subscription_count() == 0]
                    print(f"{PROG}: error: no subscriber on {', '.join(missing)} within "
                          f"{args.wait_for_subscribers:g} s", file=sys.stderr)
                    return 3
                stop.wait(0.02)
        if args.delay > 0:
            stop.wait(args.delay)

        def publish(topic: str, raw: bytes) -> None:
            pubs[topic].publish(raw)

        print(f"{PROG}: playing {plan.path} ({plan.n_messages} messages on {len(plan.topics)} topic(s), "
              f"{plan.duration_s:.3f} s) at rate {args.rate:g}{', looping' if args.loop else ''}" + (
                  f" as blocks of {args.block} rows on {args.block_topic} ({block.n} samples, "
                  f"{-(-block.n // args.block)} blocks per pass)" if block is not None else ""), file=sys.stderr)
        period_ns = int(round((plan.end_ns - plan.start_ns) / max(plan.n_messages / len(plan.topics) - 1, 1)))
        source = (lambda: iter_bag(plan)) if block is None else iter_blocks(block, args.block, args.block_topic)
        if block is not None:
            period_ns = int(round(args.block * 1e9 / block.rate_hz))
        try:
            stats = play(source, publish, rate=args.rate, loop=args.loop, loop_period_ns=period_ns,
                         stop=stop, clock=clock_cb, clock_period_s=1.0 / args.clock if args.clock else 0.01)
        except ReplayError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
        for p in pubs.values():  # let reliable subscribers receive the tail before the process exits
            p.wait_for_all_acked(rclpy.duration.Duration(seconds=2.0))
        if stats.interrupted:
            print(f"{PROG}: stopped after {stats.published} messages", file=sys.stderr)
        if args.stats:
            n_msgs = plan.n_messages if block is None else -(-block.n // args.block)
            expected = n_msgs / plan.duration_s * args.rate if plan.duration_s > 0 else float("nan")
            print(f"published {stats.published} messages in {stats.wall_s:.3f} s: {stats.msgs_per_s:.0f} msg/s "
                  f"(recorded rate x {args.rate:g}: {expected:.0f} msg/s), realtime factor "
                  f"{stats.realtime_factor:.4f} (target {args.rate:g}), {stats.batches} sleeps, "
                  f"lateness mean {stats.mean_late_s * 1e3:.3f} ms max {stats.max_late_s * 1e3:.3f} ms, "
                  f"passes {stats.passes}")
            for t, n in stats.per_topic.items():
                print(f"  {t}: {n}")
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)


if __name__ == "__main__":
    sys.exit(main())
