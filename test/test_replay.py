"""rsrivc_replay: timing engine (ROS-free), DDS playback into a subscriber, clean stop, bad input."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from additive_rsrivc_ros.cli import replay

TOPICS = ("/reference", "/plant_input", "/plant_output")
T0_NS = 1_700_000_000_000_000_000


def write_float_bag(path: Path, rate_hz: float, duration_s: float, storage: str = "mcap") -> int:
    """Float64 on the three signal topics; message k of topic j carries 10 k + j. Returns samples per topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    f64 = ts.types["std_msgs/msg/Float64"]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    n = int(round(rate_hz * duration_s))
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = [w.add_connection(t, f64.__msgtype__, typestore=ts) for t in TOPICS]
        for k in range(n):
            tk = T0_NS + int(round(k * 1e9 / rate_hz))
            for j, c in enumerate(conns):
                w.write(c, tk, ts.serialize_cdr(f64(data=float(10 * k + j)), f64.__msgtype__))
    return n


def _fake_stream(n: int, period_ns: int) -> list[tuple[str, int, bytes]]:
    return [("/a", T0_NS + k * period_ns, bytes([k % 256])) for k in range(n)]


def test_play_never_early_keeps_order_and_keeps_up() -> None:
    """Deadlines are absolute: no message before its recorded time / rate, all in order, no drift."""
    n, period_ns = 2000, 250_000  # 4 kHz for 0.5 s
    msgs = _fake_stream(n, period_ns)
    sent: list[tuple[float, bytes]] = []
    t_start = time.monotonic()
    stats = replay.play(lambda: msgs, lambda _t, raw: sent.append((time.monotonic(), raw)), rate=1.0)
    assert stats.published == n and [r for _, r in sent] == [m[2] for m in msgs]
    rel = np.array([s for s, _ in sent]) - t_start
    due = np.arange(n) * period_ns * 1e-9
    # never early (tolerance: one monotonic-clock read between the two time bases)
    assert np.all(rel - due >= -1e-3)
    # no cumulative drift: the last message goes out within a scheduling hiccup of its deadline
    assert rel[-1] - due[-1] < 0.25
    assert stats.batches < n / 2, "must sleep in batches, not once per message"


def test_play_rate_scales_time() -> None:
    msgs = _fake_stream(201, 2_000_000)  # 0.4 s of bag time
    stats = replay.play(lambda: msgs, lambda _t, _r: None, rate=4.0)
    assert stats.wall_s >= 0.1 - 1e-3  # 0.4 s / 4
    assert stats.wall_s < 0.1 + 0.25
    with pytest.raises(replay.ReplayError):
        replay.play(lambda: msgs, lambda _t, _r: None, rate=0.0)


def test_play_loop_clock_monotonic_and_stop() -> None:
    msgs = _fake_stream(20, 1_000_000)  # 20 ms per pass
    stop = threading.Event()
    clocks: list[int] = []
    count = 0

    def publish(_t: str, _r: bytes) -> None:
        nonlocal count
        count += 1
        if count == 75:
            stop.set()

    stats = replay.play(lambda: msgs, publish, rate=1.0, loop=True, loop_period_ns=1_000_000, stop=stop,
                        clock=clocks.append, clock_period_s=0.002)
    assert stats.interrupted and stats.published == 75 and stats.passes == 3
    assert len(clocks) > 5 and np.all(np.diff(clocks) > 0)
    assert clocks[0] == T0_NS
    # passes continue bag time (20 messages per pass, 1 ms apart, next pass 1 ms after the last): the 75th and
    # last message is at 74 ms of bag time; the clock never passes it and ends well beyond one pass (19 ms)
    assert T0_NS + 60_000_000 <= clocks[-1] <= T0_NS + 74_000_000


def _run(args: list[str], env: dict, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.cli.replay", *args], env=env,
                          capture_output=True, text=True, timeout=60, **kw)


def _replay_while_spinning(ex, node, args: list[str], env: dict, enough) -> subprocess.CompletedProcess:
    """Run ``rsrivc_replay args`` while ``ex`` spins ``node`` in a thread (``spin_once``: ``spin()`` cannot be
    stopped from another thread); after the replay, wait up to 10 s for ``enough()``."""
    ex.add_node(node)
    done = threading.Event()

    def spin() -> None:
        while not done.is_set():
            ex.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    try:
        res = _run(args, env)
        deadline = time.monotonic() + 10.0
        while res.returncode == 0 and time.monotonic() < deadline and not enough():
            time.sleep(0.05)
    finally:
        done.set()
        spinner.join(5.0)
        ex.remove_node(node)
    return res


def test_bad_bags_one_line(tmp_path: Path, ros_env: dict) -> None:
    (tmp_path / "nometa").mkdir()
    (tmp_path / "garbage.mcap").write_bytes(b"not an mcap file at all" * 10)
    good = tmp_path / "good"
    write_float_bag(good, 100.0, 0.1)
    cases = [
        [str(tmp_path / "missing")],
        [str(tmp_path / "nometa")],
        [str(tmp_path / "garbage.mcap")],
        [str(good), "--topics", "/nope"],
        [str(good), "--rate", "-1"],
    ]
    for args in cases:
        res = _run(args, ros_env)
        assert res.returncode != 0, args
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("rsrivc_replay: error:"), (args, res.stderr)
        assert "Traceback" not in res.stderr


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_replay_into_subscriber(tmp_path: Path, ros_env: dict, storage: str) -> None:
    """All messages of 4096 Hz x 3 topics arrive in order at the recorded rate; /clock follows the bag."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64

    rate, dur = 4096.0, 1.0
    bag = tmp_path / "bag"
    n = write_float_bag(bag, rate, dur, storage)
    os.environ["ROS_DOMAIN_ID"] = ros_env["ROS_DOMAIN_ID"]
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    got: dict[str, list[tuple[float, float]]] = {t: [] for t in TOPICS}
    clocks: list[int] = []
    try:
        node = rclpy.create_node("replay_test_sub", context=ctx)
        qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
        for t in TOPICS:
            node.create_subscription(Float64, t, lambda m, t=t: got[t].append((time.monotonic(), m.data)), qos)
        node.create_subscription(Clock, "/clock", lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec),
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        res = _replay_while_spinning(EventsExecutor(context=ctx), node, [
            str(bag), "--stats", "--clock", "200", "--wait-for-subscribers", "20"], ros_env,
            lambda: all(len(v) >= n for v in got.values()))
        assert res.returncode == 0, res.stderr
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    for j, t in enumerate(TOPICS):
        vals = np.array([v for _, v in got[t]])
        assert len(vals) == n, f"{t}: received {len(vals)} of {n}"
        np.testing.assert_array_equal(vals, 10.0 * np.arange(n) + j)  # complete and in order
    arrival = np.array([s for s, _ in got["/plant_output"]])
    span = arrival[-1] - arrival[0]
    nominal = (n - 1) / rate
    # not faster than recorded (one batch sleep of slack) and keeping up (scheduler hiccups on a busy box)
    assert span > nominal - 0.01, span
    assert span < nominal + 0.5, span
    # the clock carries bag time: monotonic, from the first stamp to about the last one
    assert clocks and clocks[0] == T0_NS and np.all(np.diff(clocks) > 0)
    assert abs(clocks[-1] - (T0_NS + nominal * 1e9)) < 0.05e9
    assert "msg/s" in res.stdout and f"/plant_output: {n}" in res.stdout


def test_without_ros_one_line_says_what_to_install(tmp_path: Path, ros_env: dict) -> None:
    """With rclpy and the message packages unimportable, rsrivc_replay answers in one line naming the install."""
    good = tmp_path / "good"
    write_float_bag(good, 100.0, 0.1)
    block = ("import sys\nfor m in ('rclpy', 'std_msgs', 'rosgraph_msgs', 'builtin_interfaces'):\n"
             "    sys.modules[m] = None\nfrom additive_rsrivc_ros.cli.replay import main\n"
             "sys.exit(main(sys.argv[1:]))\n")
    r = subprocess.run([sys.executable, "-c", block, str(good)], capture_output=True, text=True, timeout=60,
                       env=ros_env)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "ROS 2 Jazzy is not installed" in lines[0] and "[ros]" in lines[0], r.stderr


def test_wait_for_subscribers_on_a_simulated_bag_skips_its_truth_topics(tmp_path: Path, ros_env: dict) -> None:
    """A simulated bag also holds /truth/modes and /truth/fault, which no monitor reads: --wait-for-subscribers
    waits for the signal topics only, then plays every topic."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from additive_rsrivc_ros.io import bagio
    from additive_rsrivc_ros.sim import scenarios

    assert set(replay.TRUTH_TOPICS) == {bagio.TRUTH_MODES_TOPIC, bagio.TRUTH_FAULT_TOPIC}
    sc = scenarios.build("paper_example", duration_s=5.0, seed=1)
    bag = sc.write_bag(tmp_path / "sim")
    assert set(replay.inspect_bag(str(bag), None).topics) >= {*TOPICS, *replay.TRUTH_TOPICS}
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    got: dict[str, list[float]] = {t: [] for t in TOPICS}
    try:
        node = rclpy.create_node("replay_truth_test_sub", context=ctx)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        for t in TOPICS:
            node.create_subscription(Float64, t, lambda m, t=t: got[t].append(m.data), qos)
        res = _replay_while_spinning(EventsExecutor(context=ctx), node, [
            str(bag), "--rate", "20", "--wait-for-subscribers", "20"], ros_env,
            lambda: all(len(v) >= sc.t.size for v in got.values()))
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    assert res.returncode == 0, res.stderr
    np.testing.assert_array_equal(got["/plant_output"], sc.y)


def test_sigterm_stops_cleanly(tmp_path: Path, ros_env: dict) -> None:
    bag = tmp_path / "bag"
    write_float_bag(bag, 1000.0, 0.5)
    proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "additive_rsrivc_ros.cli.replay", str(bag),
                             "--loop"], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3.0)
    assert proc.poll() is None, "--loop must keep playing"
    proc.send_signal(signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)      # faulthandler prints every thread's stack
        pytest.fail(f"no exit 15 s after SIGTERM; stacks:\n{proc.communicate()[1][-6000:]}")
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "stopped after" in err


def write_float_bag_skipping(path: Path, rate_hz: float, n: int, skip: range, topics=TOPICS) -> None:
    """Like :func:`write_float_bag` (message k of topic j carries 10 k + j) without the samples in ``skip`` on every
    topic (a pause of the recording)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    f64 = ts.types["std_msgs/msg/Float64"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = [w.add_connection(t, f64.__msgtype__, typestore=ts) for t in topics]
        for k in range(n):
            if k in skip:
                continue
            for c in conns:
                w.write(c, T0_NS + int(round(k * 1e9 / rate_hz)),
                        ts.serialize_cdr(f64(data=float(10 * k + TOPICS.index(c.topic))), f64.__msgtype__))


def test_block_plan_index_from_the_sample_grid(tmp_path: Path) -> None:
    """--block: the index is the position on the bag's grid (a pause is an index gap); open loop gives NaN r."""
    bag = tmp_path / "paused"
    write_float_bag_skipping(bag, 1000.0, 600, range(200, 300))
    bp = replay.plan_blocks(replay.inspect_bag(bag), None)
    k = np.r_[0:200, 300:600].astype(float)
    np.testing.assert_array_equal(bp.index, k)
    np.testing.assert_array_equal(bp.r, 10 * k)
    np.testing.assert_array_equal(bp.u, 10 * k + 1)
    np.testing.assert_array_equal(bp.y, 10 * k + 2)
    assert bp.rate_hz == pytest.approx(1000.0, rel=1e-9)
    ol = tmp_path / "open"
    write_float_bag_skipping(ol, 1000.0, 100, range(0), topics=TOPICS[1:])
    bo = replay.plan_blocks(replay.inspect_bag(ol), None)
    assert np.all(np.isnan(bo.r)) and np.array_equal(bo.u, 10 * np.arange(100.0) + 1)
    msgs = list(replay.iter_blocks(bo, 30, "/block")())
    assert [m.layout.dim[0].size for _, _, m in msgs] == [30, 30, 30, 10]
    assert [t for _, t, _ in msgs] == [T0_NS + k * 1_000_000 for k in (29, 59, 89, 99)]   # the last row's time
    with pytest.raises(replay.ReplayError):
        replay.plan_blocks(replay.inspect_bag(ol), ["/plant_output"])


def test_replay_block_into_subscriber(tmp_path: Path, ros_env: dict) -> None:
    """``rsrivc_replay --block 64`` over DDS: every sample arrives once, in order, in the contract layout."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray

    from additive_rsrivc_ros.ros.convert import block_rows

    rate = 1000.0
    bag = tmp_path / "bag"
    n = write_float_bag(bag, rate, 0.5)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    got: list[np.ndarray] = []
    errors: list[str] = []
    try:
        node = rclpy.create_node("replay_block_sub", context=ctx)

        def cb(m) -> None:
            rows, err = block_rows(m)
            (got.append(rows) if rows is not None else errors.append(err))
        node.create_subscription(Float64MultiArray, "/block", cb, QoSProfile(depth=1000,
                                                                             reliability=ReliabilityPolicy.RELIABLE))
        from rclpy.executors import SingleThreadedExecutor

        res = _replay_while_spinning(SingleThreadedExecutor(context=ctx), node, [
            str(bag), "--block", "64", "--stats", "--wait-for-subscribers", "20"], ros_env,
            lambda: sum(len(g) for g in got) >= n)
        assert res.returncode == 0, res.stderr
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    assert not errors
    assert [len(g) for g in got] == [64] * (n // 64) + ([n % 64] if n % 64 else [])
    rows = np.vstack(got)
    k = np.arange(n, dtype=float)
    np.testing.assert_array_equal(rows, np.column_stack([k, 10 * k, 10 * k + 1, 10 * k + 2]))
    assert "/block: 8" in res.stdout and "as blocks of 64 rows" in res.stderr
