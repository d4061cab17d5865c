"""``rsrivc_monitor``: the ROS 2 lifecycle node that runs :class:`MonitorPipeline` on live r, u, y topics.

A thin shell (../shared/CONTRACT.md, docs/ARCHITECTURE.md): subscription callbacks only append
``(value, arrival)`` to per-topic deques; an estimation worker thread aligns the streams
(:mod:`.ros.sync`), feeds the samples in blocks to the pipeline (validation, recursive additive SRIVC of
000 Algorithm 2, fault logic) and publishes ``/diagnostics`` and ``~/modes``. The executor is
``rclpy.experimental.EventsExecutor`` driven by ``spin_once`` (in this rclpy build ``spin()`` of the
EventsExecutor never returns control to Python timers or other threads; ``spin_once`` does), because the
default executor loses Float64 messages above ~1 kHz (../shared/NOTES.md).

Inputs (../shared/CONTRACT.md): Float64 topics are aligned by arrival order on a nominal sample grid,
JointState topics by header stamp (exact: unmatched or out-of-order stamps are dropped); see
:mod:`.ros.sync` for pauses, count mismatches and resynchronization. Limitation: Float64 carries no
sequence information, so a single message lost on one topic while all topics keep streaming is only
detected at the next moment all topics go quiet (``sync.quiet_s``) or when the imbalance lasts; use
JointState (stamped) inputs or block input when that matters, and give the controller's publishers a RELIABLE
history deep enough for the longest expected stall (a KEEP_LAST writer silently overwrites unacknowledged samples;
DDS reports no "message lost" event for that, measured).

Block input (``block.topic``, issue 14): one ``Float64MultiArray`` of N rows ``index, reference, input, output``
per message instead of the three topics; rows are paired by the controller's index, and missing, repeated, late or
restarted indices are handled by :mod:`.ros.blocks` (the pipeline's stream aligner is not used on them).

Outputs: ``/diagnostics`` (one ``<node>: mode <i>`` status per mode with exactly the CONTRACT keys, one
``<node>: estimator`` status with counters, condition numbers, real-time factor, CPU, and the delay from a
sample's arrival to the return of the pipeline update that includes it), ``~/modes``; services ``~/reset``,
``~/rebaseline``, ``~/save_state``; ``state_file`` persistence across restarts. ``<node>`` is the node name in the
root namespace and the full name without its leading '/' under a namespace (``axis1/additive_rsrivc_monitor``).

Names (issue 14): the input topics are relative by default (``reference``, ``plant_input``, ``plant_output``),
resolved in the node's namespace and remapped by ``-r from:=to``; every check and message (wrong type, silence,
rates, queues) names the resolved topic. Parameters the node does not know are warned about in one line unless they
lie in one of its own groups (``modes.*`` ...: a misspelling, rejected), so a shared ``/**`` params file works. A
missing ``loop_rate_hz`` names the params-file keys that would reach this node.

QoS of the signal subscriptions: RELIABLE, KEEP_LAST with a depth of five seconds of samples (param
``qos_depth``); per subscription overridable by the standard ``qos_overrides.<resolved topic>.subscription.``
``{reliability,history,depth}`` parameters (rclpy ``QoSOverridingOptions``). Reliable delivery over loopback never
drops a sample by itself; the only loss left is a reader history overflow when the executor falls behind (a loaded
CPU), and five seconds of history cover such stalls (Float64 messages are 8 bytes of payload; 4096 Hz x 3 topics x
5 s is a few MB). The EventsExecutor serves bursts topic by topic (measured: 3000 messages of one topic before the
next), so the alignment tolerates large temporary count differences between the topics.

Resources and timing (issue 13): every input queue is bounded (``sync.max_queue_s``, oldest dropped, counted per
topic, one log line per episode); a separate publisher thread publishes every report's estimate on ``~/modes`` (in
order, once per ``1/publish_rate_hz`` cycle) and one ``/diagnostics`` array per ``diagnostics_period_s`` (1 s by
default) from the newest report, so publishing never holds up the consumption of the inputs (``~/modes`` messages are
coalesced, and counted, only past ``MODES_QUEUE``). Each topic's arrival rate is compared with ``loop_rate_hz``
(``sync.rate_window_s``, ``sync.rate_tolerance``): a mismatch is a WARN naming the topic. The node measures its own
loop: a topic is silent (STALE) only when the executor was spinning for longer than ``stale_timeout_s`` and nothing
arrived; a late burst caused by the node's own stall (start-up, GC, a busy worker) is not an input pause.
``state_file``: a file refused at start (other model, rate or corrupt) is never overwritten; this run's state is
saved beside it (``<stem>.<UTC time>.json``). SIGINT/SIGTERM only set a flag.
"""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

_STOP_REQUESTED = threading.Event()
_SIGNAL_NAME = [""]


def _request_stop(signum: int, frame: Any) -> None:
    """SIGINT/SIGTERM: only set a flag; the spin loop returns within one ``spin_once`` timeout.

    rclpy's own handlers end in an asynchronous ``KeyboardInterrupt``; raised inside a ``with lock:`` it can
    leave the lock held (measured: a SIGINT during activation deadlocked the shutdown in ``Event.set``).
    ``Event.set`` here runs in the signal handler, between bytecodes of the main thread, never inside another
    lock operation of this module."""
    _SIGNAL_NAME[0] = {int(signal.SIGINT): "SIGINT", int(signal.SIGTERM): "SIGTERM"}.get(signum, str(signum))
    _STOP_REQUESTED.set()


# The console script imports this module first: take over SIGINT/SIGTERM before anything slow is imported (a
# signal during the imports would otherwise end in a KeyboardInterrupt traceback). Only for rsrivc_monitor itself.
if sys.argv and sys.argv[0].rsplit("/", 1)[-1] == "rsrivc_monitor" and threading.current_thread() is \
        threading.main_thread():
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)

USAGE = """usage: rsrivc_monitor [-h] [--ros-args [--params-file FILE.yaml] [-p NAME:=VALUE] [-r __node:=NAME]]

ROS 2 lifecycle node: online closed-loop additive recursive SRIVC of mechanical resonances with fault
diagnosis. Subscribes reference, plant_input, plant_output (relative names: /reference ... in the root
namespace, /<ns>/reference ... under -r __ns:=/<ns>; std_msgs/msg/Float64 or sensor_msgs/msg/JointState) or,
with -p block.topic:=block, Float64MultiArray blocks of rows index, reference, input, output,
publishes /diagnostics and ~/modes, serves ~/reset, ~/rebaseline, ~/save_state (std_srvs/srv/Trigger).
Default node name: additive_rsrivc_monitor. Parameters: see config/template.yaml (the YAML key must match
the node's full name: additive_rsrivc_monitor, /**/additive_rsrivc_monitor, /<ns>/additive_rsrivc_monitor or
/**). QoS per subscription: -p qos_overrides./<ns>/plant_output.subscription.reliability:=best_effort.

example:
  rsrivc_monitor --ros-args --params-file my_plant.yaml
  rsrivc_monitor --ros-args --params-file my_plant.yaml -p use_sim_time:=true -p state_file:=/tmp/s.json
  rsrivc_monitor --ros-args -r __ns:=/axis1 --params-file axes.yaml -r plant_output:=/axis1/encoder
"""

ALLOWED_EXTRA_PARAMS = ("use_sim_time", "start_type_description_service")
REQUIRED_PARAMS = ("loop_rate_hz",)     # no usable default: absent means the params file did not reach the node
STALL_NS = 250_000_000     # the executor or the worker not running for this long is a stall of the node itself
BLOCK_IDLE_S = 0.05          # block input: longest worker sleep without a new block (reorder timeouts, rate checks)
MODES_QUEUE = 10_000        # ~/modes messages the publisher may fall behind before the oldest are coalesced (counted)


def split_unknown(names: Any, known: Any) -> tuple[list[str], list[str]]:
    """Parameter names the monitor does not declare, as ``(errors, warnings)``.

    A name inside one of the monitor's own groups (``modes.memory_sec``: the first dotted part of a known name) is a
    misspelling and an error; any other name (another node's parameter in a shared ``/**`` section, ROS's own
    ``qos_overrides.*``) is at most warned about: ROS params files are shared between nodes."""
    known = set(known)
    groups = {n.split(".", 1)[0] for n in known if "." in n}
    unknown = sorted(n for n in names if n not in known and n not in ALLOWED_EXTRA_PARAMS
                     and not n.startswith("qos_overrides."))
    errors = [n for n in unknown if "." in n and n.split(".", 1)[0] in groups]
    return errors, [n for n in unknown if n not in errors]


def unknown_warning(names: list[str], known: Any) -> str:
    """One log line about parameters the monitor ignores (with the closest own name when one is close)."""
    import difflib

    parts = []
    for n in names:
        close = difflib.get_close_matches(n, list(known), 1, 0.85)
        parts.append(f"{n} (did you mean {close[0]}?)" if close else n)
    return f"ignoring parameter(s) this node does not use (another node's, in a shared section?): {', '.join(parts)}"


def missing_required(name: str, fqn: str, given: Any, known: Any) -> str:
    """One-line error for a required parameter that no params section gave to the node ``fqn``."""
    ns, _, base = fqn.rpartition("/")
    own = [n for n in given if n in set(known) and n not in ("autostart",)]
    if own:
        return f"parameter '{name}' is required (the params for node '{fqn}' do not set it)"
    keys = (f"/**/{base}", fqn) if ns else (base, f"/**/{base}")
    return (f"parameter '{name}' is required (no params for node '{fqn}': the YAML key must be '{keys[0]}' or "
            f"'{keys[1]}')")


def _beside(path: str) -> str:
    """Where this run saves when ``path`` was refused: ``<stem>.<UTC time>.json`` next to it (never ``path``)."""
    p = Path(path)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    out = p.with_name(f"{p.stem}.{stamp}.json")
    k = 1
    while out.exists():
        out = p.with_name(f"{p.stem}.{stamp}-{k}.json")
        k += 1
    return str(out)


def _write_atomic(path: str, text: str) -> None:
    """Write ``text`` to ``path`` so that it is either the old or the complete new file (temp, fsync, replace)."""
    d = os.path.dirname(os.path.abspath(path))
    tmp = os.path.join(d, f".{os.path.basename(path)}.tmp{os.getpid()}")
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _import_ros() -> None:
    """Import rclpy and the message packages lazily (``--help`` must work without ROS)."""
    global rclpy, LifecycleNode, TransitionCallbackReturn, LifecycleState, EventsExecutor
    global ExternalShutdownException, QoSProfile, ReliabilityPolicy, HistoryPolicy, DurabilityPolicy
    global QoSOverridingOptions
    global Float64, JointState, Float64MultiArray, DiagnosticArray, Trigger, SetParametersResult, Parameter, cv, np
    import numpy as np
    import rclpy  # noqa: F401
    import rclpy.lifecycle
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.qos_overriding_options import QoSOverridingOptions
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Float64MultiArray
    from std_srvs.srv import Trigger

    from .ros import convert as cv


class _RingStats:
    """Last ``n`` values of a float series (delays) with median / percentile."""

    def __init__(self, n: int = 1 << 16) -> None:
        self.buf = np.empty(n)
        self.i = 0
        self.full = False

    def extend(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=float).ravel()[-self.buf.size:]
        n = x.size
        j = self.i + n
        if j <= self.buf.size:
            self.buf[self.i:j] = x
        else:
            k = self.buf.size - self.i
            self.buf[self.i:] = x[:k]
            self.buf[: n - k] = x[k:]
            self.full = True
        self.i = j % self.buf.size
        if j == self.buf.size:
            self.full = True

    def values(self) -> np.ndarray:
        return self.buf if self.full else self.buf[: self.i]

    def percentile(self, q: float) -> float:
        v = self.values()
        return float(np.percentile(v, q)) if v.size else math.nan


def make_node_class() -> type:
    """Build the node class after rclpy has been imported (keeps ``--help`` free of ROS imports)."""
    _import_ros()
    from .config import DEFAULT_NODE_NAME, MonitorConfig, ParamError, all_params, param_table, validate_params
    from .core.faults import FaultSettings, Level
    from .core.pipeline import MonitorPipeline, PipelineError
    from .ros.blocks import BlockSync
    from .ros.sync import InputSync

    def _check_sync_params(v: dict[str, Any]) -> None:
        """sync.max_queue_s must exceed the stall and backlog allowances (ParamError, one line)."""
        q = v["sync.max_queue_s"]
        if q <= v["sync.stall_s"] or q <= 2 * v["sync.max_backlog_s"]:
            raise ParamError(f"sync.max_queue_s ({q:g}) must exceed sync.stall_s ({v['sync.stall_s']:g}) and "
                             f"2 x sync.max_backlog_s ({v['sync.max_backlog_s']:g})")

    class MonitorNode(LifecycleNode):
        """Managed node around :class:`MonitorPipeline`; see the module docstring."""

        def __init__(self, node_name: str = DEFAULT_NODE_NAME, **kwargs: Any) -> None:
            super().__init__(node_name, **kwargs)
            self._table = param_table()
            self._declare_all()
            self.add_pre_set_parameters_callback(self._pre_set)
            self.add_on_set_parameters_callback(self._on_set)
            self.add_post_set_parameters_callback(self._post_set)
            self.lock = threading.RLock()
            self.pipeline: MonitorPipeline | None = None
            self.cfg: MonitorConfig | None = None
            self.sync: InputSync | None = None
            self.config_error = ""
            self._active = False
            self._subs: list[Any] = []
            self._srvs: list[Any] = []
            self._modes_pub = None
            self._diag_pub = None
            self._worker: threading.Thread | None = None
            self._stop = threading.Event()
            self.idle_since_ns = 0
            self.looking_since_ns = 0          # start of the executor's current uninterrupted run (0: not yet)
            self._pub_thread: threading.Thread | None = None
            self._save_path = ""               # where save_state writes ("" -> the state_file parameter)
            self._closed = False
            self._reset_stats()

        # ------------------------------------------------------------------------------------ parameters
        def _declare_all(self) -> None:
            """Declare every Param row with its descriptor; integer YAML values of double params are coerced. A
            required parameter nobody gave raises ParamError naming it and the params-file key (one line)."""
            for name in REQUIRED_PARAMS:
                if name not in self._parameter_overrides:
                    raise ParamError(missing_required(name, self.get_fully_qualified_name(),
                                                      self._parameter_overrides, self._table))
            for name, ov in list(self._parameter_overrides.items()):
                if name in self._table:
                    self._parameter_overrides[name] = cv.coerce_int_to_double(self._table[name], ov)
            for p in all_params():
                if isinstance(p.default, list) and not p.default:
                    # an empty list has no inferable type: declare typed, then give it the typed empty default
                    self.declare_parameter(p.name, cv.PARAM_TYPE[p.type], cv.descriptor(p))
                    if self.get_parameter_or(p.name).type_ == Parameter.Type.NOT_SET:
                        self._parameters[p.name] = Parameter(p.name, cv.PARAM_TYPE[p.type], [])
                else:
                    self.declare_parameter(p.name, p.default, cv.descriptor(p))

        def values(self) -> dict[str, Any]:
            """Current parameter values, flat ``{name: plain value}``."""
            return {name: cv.plain(self.get_parameter(name).value) for name in self._table}

        def _pre_set(self, params: list) -> list:
            return [cv.coerce_int_to_double(self._table[p.name], p) if p.name in self._table else p for p in params]

        def _on_set(self, params: list) -> Any:
            cand = self.values()
            for p in params:
                if p.name in self._table:
                    cand[p.name] = cv.plain(p.value)
            try:
                valid = validate_params(cand, strict=False)
                cfg = MonitorConfig.from_params(valid)
                FaultSettings.from_params(valid).check(cfg.K)
                _check_sync_params(valid)
            except (ParamError, ValueError) as exc:
                return SetParametersResult(successful=False, reason=f"rejected: {exc}")
            return SetParametersResult(successful=True)

        def _post_set(self, params: list) -> None:
            changed = {p.name: cv.plain(p.value) for p in params if p.name in self._table}
            runtime = {k: v for k, v in changed.items()
                       if k in ("modes.memory_s", "publish_rate_hz") or k.startswith("faults.")}
            with self.lock:
                if self.pipeline is not None and runtime:
                    try:
                        self.pipeline.update_params(runtime)
                    except PipelineError as exc:   # validated before; keep running and say so
                        self.get_logger().error(f"runtime parameter change not applied: {exc}")
                    else:
                        self.get_logger().info("applied " + ", ".join(f"{k}={v}" for k, v in runtime.items()))
                if "publish_rate_hz" in changed:
                    self._publish_period_s = 1.0 / float(changed["publish_rate_hz"])
                if "diagnostics_period_s" in changed:
                    self._diag_period_s = float(changed["diagnostics_period_s"])
                if "stale_timeout_s" in changed:
                    self._stale_timeout_s = float(changed["stale_timeout_s"])
                    if self.sync is not None:
                        self.sync.silent_ns = int(self._stale_timeout_s * 1e9)
                if self.sync is not None and self.cfg is not None:
                    if "sync.max_backlog_s" in changed:
                        self.sync.max_backlog = self._backlog_samples(float(changed["sync.max_backlog_s"]))
                    if "sync.gap_s" in changed:
                        self.sync.gap_ns = int(self._gap_s(float(changed["sync.gap_s"])) * 1e9)
                    if "sync.quiet_s" in changed:
                        self.sync.quiet_ns = int(float(changed["sync.quiet_s"]) * 1e9)
                    if "sync.hold_s" in changed:
                        self.sync.hold_ns = int(float(changed["sync.hold_s"]) * 1e9)

        def _backlog_samples(self, s: float) -> int:
            return max(8, int(math.ceil(s * self.cfg.loop_rate_hz)))

        def _gap_s(self, s: float) -> float:
            return s if s > 0.0 else max(0.1, 10.0 / self.cfg.loop_rate_hz)

        # ------------------------------------------------------------------------------------ lifecycle
        def _load_kernels(self) -> None:
            """numba's one-time start (1-2 s, or a compilation without the cache) before any data, not mid-stream."""
            from .warmup import is_warm, load_kernels

            if not is_warm():
                self.get_logger().warning("the numba kernels of this version are not cached yet: compiling them now "
                                          "(once, about a minute; run rsrivc_warmup after installing to avoid this)")
            seconds = load_kernels()
            self.get_logger().info(f"kernels loaded in {seconds:.2f} s")

        def on_configure(self, state: Any) -> Any:
            unknown, foreign = split_unknown(self._parameter_overrides, self._table)
            if foreign:
                self.get_logger().warning(unknown_warning(foreign, self._table))
            try:
                if unknown:
                    raise ParamError(f"unknown parameter(s): {', '.join(unknown)}")
                values = validate_params(self.values())
                cfg = MonitorConfig.from_params(values)
                FaultSettings.from_params(values).check(cfg.K)
                _check_sync_params(values)
            except (ParamError, ValueError) as exc:
                self.config_error = str(exc)
                self.get_logger().error(f"configuration rejected: {exc}")
                return TransitionCallbackReturn.FAILURE
            if cfg.block_input:       # block rows are paired by index: the pipeline's stream aligner stays off
                cfg = cfg.with_block_input()
            self.cfg = cfg
            v = values
            self._load_kernels()
            pipeline = self._restore(cfg, v["state_file"])
            try:
                self.pipeline = pipeline or MonitorPipeline(cfg)
            except (PipelineError, ValueError) as exc:
                self.config_error = str(exc)
                self.get_logger().error(f"configuration rejected: {exc}")
                return TransitionCallbackReturn.FAILURE
            self.signals = ("block",) if cfg.block_input else \
                ("reference", "input", "output") if cfg.closed_loop else ("input", "output")
            try:
                self.topics = self._resolve_topics(cfg)
            except ParamError as exc:
                self.config_error = str(exc)
                self.get_logger().error(f"configuration rejected: {exc}")
                return TransitionCallbackReturn.FAILURE
            types = [cfg.signals[s].type for s in self.signals]
            self.sync = self._block_sync(cfg, v) if cfg.block_input else InputSync(
                self.signals, cfg.loop_rate_hz, stamped=all(t == "sensor_msgs/msg/JointState" for t in types),
                max_backlog=self._backlog_samples(v["sync.max_backlog_s"]),
                quiet_s=v["sync.quiet_s"], gap_s=self._gap_s(v["sync.gap_s"]), hold_s=v["sync.hold_s"],
                silent_s=v["stale_timeout_s"], stall_s=v["sync.stall_s"],
                max_queue=self._queue_samples(v), labels=tuple(self.topics[s] for s in self.signals),
                rate_window_s=v["sync.rate_window_s"], rate_tolerance=v["sync.rate_tolerance"])
            self._use_sim_time = bool(self.get_parameter("use_sim_time").value)
            if self.pipeline.t_last is not None:
                self.sync.set_time_floor(self.pipeline.t_last)
            self._stale_timeout_s = v["stale_timeout_s"]
            self._publish_period_s = 1.0 / cfg.publish_rate_hz
            self._diag_period_s = v["diagnostics_period_s"]
            self._block_period_s = v["block_period_s"]
            self._block_batch_s, self._block_step_due = v["block.batch_s"], 0.0
            self._reset_stats()
            try:
                qos_text = self._subscribe(cfg, v)
            except ParamError as exc:
                self._destroy_interfaces()
                self.config_error = str(exc)
                self.get_logger().error(f"configuration rejected: {exc}")
                return TransitionCallbackReturn.FAILURE
            self._modes_pub = self.create_lifecycle_publisher(Float64MultiArray, "~/modes", 10)
            self._diag_pub = self.create_lifecycle_publisher(DiagnosticArray, "/diagnostics", 10)
            self._srvs = [self.create_service(Trigger, "~/reset", self._srv_reset),
                          self.create_service(Trigger, "~/rebaseline", self._srv_rebaseline),
                          self.create_service(Trigger, "~/save_state", self._srv_save)]
            self.get_logger().info(
                f"configured: K={cfg.K or 'from the data'}, {cfg.loop_rate_hz:g} Hz, "
                f"{'closed' if cfg.closed_loop else 'open'} loop, "
                f"inputs {', '.join(self.topics[s] for s in self.signals)} "
                f"({getattr(self.sync, 'pairing', 'stamped' if self.sync.stamped else 'arrival order')}), "
                f"QoS {qos_text}, input queues "
                f"bounded at {self.sync.max_queue} samples per topic (<= {self.sync.queue_bytes() / 1e6:.3g} MB)")
            return TransitionCallbackReturn.SUCCESS

        def _block_sync(self, cfg: Any, v: dict[str, Any]) -> Any:
            """The input stage of block input (``block.topic``; ros/blocks.py)."""
            return BlockSync(cfg.loop_rate_hz, closed_loop=cfg.closed_loop, label=self.topics["block"],
                             convert=cv.block_rows, reorder_s=v["block.reorder_s"], controller=cfg.controller,
                             gap_s=self._gap_s(v["sync.gap_s"]), silent_s=v["stale_timeout_s"],
                             max_queue=self._queue_samples(v), rate_window_s=v["sync.rate_window_s"],
                             rate_tolerance=v["sync.rate_tolerance"])

        def _resolve_topics(self, cfg: Any) -> dict[str, str]:
            """The configured signal topics expanded in the node's namespace and remapped (``-r from:=to``), as
            the subscriptions will use them; every check and message names these (ParamError: invalid name)."""
            out = {}
            for s in self.signals:
                try:
                    out[s] = self.resolve_topic_name(cfg.signals[s].topic)
                except Exception as exc:  # noqa: BLE001 - rclpy raises RuntimeError / rcl errors for bad names
                    raise ParamError(f"parameter '{s}.topic' = {cfg.signals[s].topic!r} is not a valid topic name "
                                     f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
            return out

        def _subscribe(self, cfg: Any, v: dict[str, Any]) -> str:
            """Create the signal subscriptions: RELIABLE (``qos_reliable``), KEEP_LAST ``qos_depth``, each
            overridable by the standard ``qos_overrides.<resolved topic>.subscription.{history,depth,reliability}``
            parameters (rclpy QoSOverridingOptions). Returns a one-line QoS summary; ParamError on a bad override."""
            depth = v["qos_depth"] or max(100, int(math.ceil(5.0 * cfg.loop_rate_hz)))
            opts = QoSOverridingOptions.with_default_policies()
            for i, s in enumerate(self.signals):
                sc = cfg.signals[s]
                qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                                 reliability=ReliabilityPolicy.RELIABLE if v["qos_reliable"]
                                 else ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
                joint = sc.type == "sensor_msgs/msg/JointState"
                block = s == "block"
                cb = self._block_cb() if block else self._joint_cb(i, s, sc) if joint else self._float_cb(i)
                kind = Float64MultiArray if block else JointState if joint else Float64
                try:
                    sub = self.create_subscription(kind, self.topics[s], cb, qos, qos_overriding_options=opts)
                except Exception as exc:  # noqa: BLE001 - rclpy raises several types for a bad override value
                    raise ParamError(f"QoS override for {self.topics[s]} rejected: "
                                     f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
                self._subs.append(sub)
            self._warn_stray_qos_overrides()
            return ", ".join(f"{self.topics[s]} {q.reliability.name.lower()} {q.history.name.lower()} {q.depth}"
                             for s, q in zip(self.signals, (sub.qos_profile for sub in self._subs), strict=True))

        def _warn_stray_qos_overrides(self) -> None:
            """A ``qos_overrides.<topic>...`` for none of this node's subscriptions (e.g. the unnamespaced topic
            under a namespace) changes nothing: one warning line naming it and the resolved topics."""
            mine = {f"qos_overrides.{t}.subscription." for t in self.topics.values()}
            stray = sorted(n for n in self._parameter_overrides if n.startswith("qos_overrides.")
                           and ".subscription." in n and not any(n.startswith(m) for m in mine))
            if stray:
                self.get_logger().warning(f"QoS override(s) {', '.join(stray)} match no subscription of this node "
                                          f"(its topics: {', '.join(self.topics.values())})")

        def _queue_samples(self, v: dict[str, Any]) -> int:
            """sync.max_queue_s in samples; it must exceed the stall and backlog allowances (ParamError)."""
            q = v["sync.max_queue_s"]
            # never below the DDS reader history (qos_depth): the node holds no fewer samples than DDS already would
            depth = v["qos_depth"] or max(100, int(math.ceil(5.0 * self.cfg.loop_rate_hz)))
            return max(2 * self._backlog_samples(v["sync.max_backlog_s"]), int(math.ceil(q * self.cfg.loop_rate_hz)),
                       depth)

        def _restore(self, cfg: Any, state_file: str) -> Any:
            """The pipeline restored from ``state_file``, or None. A refused file (corrupt, other K, rate,
            controller, delay, loop or structures) is kept untouched: this run saves beside it (one log line)."""
            self._save_path = state_file
            if not state_file or not Path(state_file).exists():
                return None
            try:
                saved = json.loads(Path(state_file).read_text())
                pipeline = MonitorPipeline(cfg, state=saved["pipeline"])
            except (OSError, ValueError, KeyError, TypeError, PipelineError) as exc:
                reason = str(exc) if isinstance(exc, PipelineError) else f"unreadable: {type(exc).__name__}: {exc}"
                self._save_path = _beside(state_file)
                self.get_logger().warning(f"state file {state_file} refused ({reason}); starting fresh, the file is "
                                          f"kept unchanged and this run's state will be saved to {self._save_path}")
                return None
            self.get_logger().info(f"state restored from {state_file} (estimating: {pipeline.initialized})")
            return pipeline

        def on_activate(self, state: Any) -> Any:
            self._stop.clear()
            self._active = True
            self._worker = threading.Thread(target=self._run_worker, name="rsrivc_worker", daemon=True)
            self._worker.start()
            self._pub_thread = threading.Thread(target=self._run_publisher, name="rsrivc_publisher", daemon=True)
            self._pub_thread.start()
            return super().on_activate(state)

        def on_deactivate(self, state: Any) -> Any:
            self._stop_worker()
            return super().on_deactivate(state)

        def on_cleanup(self, state: Any) -> Any:
            self._stop_worker()
            self.save_state()
            self._destroy_interfaces()
            return TransitionCallbackReturn.SUCCESS

        def on_shutdown(self, state: Any) -> Any:
            self.close()
            return TransitionCallbackReturn.SUCCESS

        def _stop_worker(self) -> None:
            self._active = False
            self._stop.set()
            for th in (self._worker, self._pub_thread):
                if th is not None and th is not threading.current_thread():
                    th.join(timeout=10.0)
            self._worker = self._pub_thread = None

        def _destroy_interfaces(self) -> None:
            for s in self._subs:
                self.destroy_subscription(s)
            for s in self._srvs:
                self.destroy_service(s)
            for p in (self._modes_pub, self._diag_pub):
                if p is not None:
                    self.destroy_lifecycle_publisher(p)
            self._subs, self._srvs, self._modes_pub, self._diag_pub = [], [], None, None
            self.pipeline = self.sync = None

        def close(self) -> None:
            """Stop the worker and save the state once; called on shutdown."""
            self._stop_worker()
            if not self._closed:
                self._closed = True
                self.save_state()

        def save_state(self) -> str:
            """Write the pipeline state atomically (temp file, fsync, ``os.replace``) to ``state_file`` or, when
            that file was refused at start, beside it; returns a one-line result."""
            path = self._save_path if self.pipeline is not None else self.get_parameter("state_file").value
            if not path:
                return "state_file is empty: nothing saved"
            with self.lock:
                if self.pipeline is None:
                    return "not configured: nothing saved"
                doc = {"node": self.get_fully_qualified_name(), "saved_unix_s": time.time(),
                       "pipeline": self.pipeline.get_state()}
            _write_atomic(path, json.dumps(doc))
            self.get_logger().info(f"state saved to {path}")
            return f"state saved to {path}"

        # ------------------------------------------------------------------------------------ callbacks
        def _float_cb(self, i: int) -> Any:
            q = self.sync.queues[i]
            over, cap = self.sync.overflow, self.sync.max_queue
            mono = time.monotonic_ns

            def cb(msg: Any) -> None:
                if self._active:
                    if len(q) >= cap:          # the bounded deque drops its oldest item: count it
                        over[i] += 1
                    q.append((msg.data, mono()))
            return cb

        def _block_cb(self) -> Any:
            enqueue, mono = self.sync.enqueue, time.monotonic_ns

            def cb(msg: Any) -> None:
                if self._active:
                    enqueue(msg, mono())
            return cb

        def _joint_cb(self, i: int, sig: str, sc: Any) -> Any:
            q = self.sync.queues[i]
            over, cap = self.sync.overflow, self.sync.max_queue
            mono = time.monotonic_ns
            joint, fld = sc.joint, sc.field

            def cb(msg: Any) -> None:
                if not self._active:
                    return
                try:
                    k = msg.name.index(joint) if joint else 0
                    value = float(getattr(msg, fld)[k])
                except (ValueError, IndexError):
                    self._malformed[sig] = self._malformed.get(sig, 0) + 1
                    return
                st = msg.header.stamp
                if len(q) >= cap:
                    over[i] += 1
                q.append((value, mono(), st.sec * 1_000_000_000 + st.nanosec))
            return cb

        def _srv_reset(self, request: Any, response: Any) -> Any:
            with self.lock:
                if self.pipeline is None:
                    response.success, response.message = False, "not configured"
                    return response
                self.pipeline.reset()
                self.sync.resync(time.monotonic_ns(), "reset requested", count=False)
                self.sync.set_time_floor(None)
            response.success, response.message = True, "estimator, baseline and fault state reset"
            return response

        def _srv_rebaseline(self, request: Any, response: Any) -> Any:
            with self.lock:
                if self.pipeline is None:
                    response.success, response.message = False, "not configured"
                    return response
                closed = self.pipeline.rebaseline()
            response.success = True
            response.message = f"learning a new baseline; {len(closed)} open fault event(s) closed"
            return response

        def _srv_save(self, request: Any, response: Any) -> Any:
            path = self.get_parameter("state_file").value
            if not path:
                response.success, response.message = False, "parameter state_file is empty"
                return response
            try:
                response.message = self.save_state()
                response.success = True
            except OSError as exc:
                response.success, response.message = False, f"cannot write {path}: {exc}"
            return response

        # ------------------------------------------------------------------------------------ worker
        def _reset_stats(self) -> None:
            self.delays_ms = _RingStats()
            self._delay_cache = (math.nan, math.nan, math.nan)
            self._delay_cache_ns = 0
            self._busy_s = 0.0
            self._data_s = 0.0
            self._cpu0 = (time.process_time(), time.monotonic())
            self._cpu_fraction = math.nan
            self._malformed: dict[str, int] = {}
            self._wrong_types: list[str] = []
            self._errors = 0
            self._last_error = ""
            self._next_graph_ns = 0
            self._latest_report = None           # newest pipeline report (worker -> publisher)
            # every report's (K, 6) estimate for ~/modes, in order (a cheap message: none is coalesced unless the
            # publisher falls this far behind; /diagnostics is composed once per cycle from the newest report)
            self._modes_queue: deque = deque(maxlen=MODES_QUEUE)
            self._last_published = None
            self._reports_made = 0
            self._reports_published = 0
            self._snapshot: tuple[Any, Any] = (None, None)   # (last report, modal) the publisher can always use
            self._push_started_ns = 0
            self._last_step_ns = 0
            self.node_stalls = 0                 # executor stalls (the node did not look at its inputs)
            self.node_stall_max_s = 0.0
            self.worker_stalls = 0               # worker steps further apart than STALL_NS (GC, compile, ...)
            self.worker_stall_max_s = 0.0
            self._clock_pts: list[tuple[int, float]] = []

        def _run_worker(self) -> None:
            wake = getattr(self.sync, "wake", None)   # block input: woken per message, not polled every period
            while not (self._stop.wait(self._block_period_s) if wake is None else self._wait_block(wake)):
                try:
                    self.step()
                except Exception as exc:  # noqa: BLE001 - the node must keep running; the error is reported
                    self._errors += 1
                    msg = f"{type(exc).__name__}: {exc}"
                    if msg != self._last_error:
                        self.get_logger().error(f"estimation step failed ({msg}); continuing")
                    self._last_error = msg
                finally:
                    self._push_started_ns = 0

        def _wait_block(self, wake: threading.Event) -> bool:
            """Block input: sleep until a block arrives (or ``BLOCK_IDLE_S`` for timeouts, rates, the graph check),
            but step at most once per ``block.batch_s`` so that several blocks share one pipeline call; True when the
            worker is to stop. (Polling every 2 ms cost 0.05 core idle; each pipeline call has a fixed cost.)"""
            rest = self._block_step_due - time.monotonic()
            if rest > 0.0 and self._stop.wait(rest):
                return True
            wake.wait(BLOCK_IDLE_S)
            wake.clear()
            self._block_step_due = time.monotonic() + self._block_batch_s
            return self._stop.is_set()

        def _ros_now_s(self) -> float:
            return self.get_clock().now().nanoseconds * 1e-9

        def note_stall(self, start_ns: int, end_ns: int) -> None:
            """The executor did not run from ``start_ns`` to ``end_ns`` (called by :func:`spin`)."""
            self.node_stalls += 1
            self.node_stall_max_s = max(self.node_stall_max_s, (end_ns - start_ns) * 1e-9)
            sync = self.sync
            if sync is not None:
                sync.note_stall(start_ns, end_ns)

        def step(self) -> None:
            """Align what arrived and feed it to the pipeline; the publisher thread publishes (never this one)."""
            now = time.monotonic_ns()
            if self._last_step_ns and now - self._last_step_ns > STALL_NS:
                self.worker_stalls += 1
                self.worker_stall_max_s = max(self.worker_stall_max_s, (now - self._last_step_ns) * 1e-9)
            self._last_step_ns = now
            with self.lock:
                sync, pipe = self.sync, self.pipeline
                if sync is None or pipe is None:
                    return
                n_ev = sync.n_events
                blk = sync.collect(now, idle_since_ns=self.idle_since_ns, ros_now_s=self._ros_now_s())
                if blk is not None:
                    was_init = pipe.initialized
                    c0 = time.perf_counter()
                    self._push_started_ns = time.monotonic_ns()
                    reports = pipe.push(blk.t, blk.r, blk.u, blk.y)
                    self._push_started_ns = 0
                    self._busy_s += time.perf_counter() - c0
                    self._data_s += len(blk) / self.cfg.loop_rate_hz
                    if was_init and pipe.initialized:
                        self.delays_ms.extend((time.monotonic_ns() - blk.arrival_ns) * 1e-6)
                    if reports:
                        self._reports_made += len(reports)
                        self._modes_queue.extend(r.modal for r in reports if r.K)   # ~/modes once K is known
                        self._latest_report = reports[-1]
                        self._snapshot = (reports[-1], reports[-1].modal)
                    for note in (n for r in reports for n in r.notices):   # automatic start: found / failed
                        if pipe.K:
                            self.get_logger().info(note)
                        else:
                            self.get_logger().warning(note)
                if now >= self._next_graph_ns:
                    self._once_per_second(now, sync)
                self._log_events(sync, n_ev)
            self._last_step_ns = time.monotonic_ns()

        def _log_events(self, sync: Any, n_ev: int) -> None:
            """Log the sync events raised since ``n_ev`` (each is one line, once per episode)."""
            new = sync.n_events - n_ev
            if new > 0:
                for ev in list(sync.events)[-min(new, len(sync.events)):]:
                    self.get_logger().warning(f"input: {ev}")

        def _once_per_second(self, now: int, sync: Any) -> None:
            """Graph (wrong types), CPU, arrival rates."""
            self._next_graph_ns = now + 1_000_000_000
            self._check_graph()
            c = (time.process_time(), time.monotonic())
            if c[1] > self._cpu0[1]:
                self._cpu_fraction = (c[0] - self._cpu0[0]) / (c[1] - self._cpu0[1])
            self._cpu0 = c
            sync.check_rates(now, self._clock_speed(now))

        def _clock_speed(self, now: int) -> float:
            """Speed of the node clock vs wall time over the rate window (1 without sim time; nan when the sim
            clock does not advance: the rate check is then skipped)."""
            if not self._use_sim_time:
                return 1.0
            self._clock_pts.append((now, self._ros_now_s()))
            lo = now - self.sync.rate_window_ns
            while len(self._clock_pts) > 2 and self._clock_pts[1][0] <= lo:
                self._clock_pts.pop(0)
            (a0, r0), (a1, r1) = self._clock_pts[0], self._clock_pts[-1]
            if a1 - a0 < 0.5 * self.sync.rate_window_ns or r1 <= r0:
                return math.nan
            return (r1 - r0) / ((a1 - a0) * 1e-9)

        def _run_publisher(self) -> None:
            """Publish the newest report on ~/modes once per ``1/publish_rate_hz`` and one /diagnostics array once
            per ``diagnostics_period_s``, each on its own schedule (no catch-up burst after falling behind)."""
            start = time.monotonic()
            due = {"modes": start + self._publish_period_s, "diagnostics": start + self._diag_period_s}
            while not self._stop.is_set():
                now = time.monotonic()
                if self._stop.wait(max(0.0, min(due.values()) - now)):
                    break
                now = time.monotonic()
                for out, period in (("modes", self._publish_period_s), ("diagnostics", self._diag_period_s)):
                    if now < due[out]:
                        continue
                    due[out] = max(due[out] + period, now)   # fell behind (loaded CPU): no catch-up burst
                    self._publish_guarded(out)

        def _publish_guarded(self, out: str) -> None:
            """Publish ``out`` (modes | diagnostics); an exception is counted and logged once, never raised."""
            try:
                if out == "modes":
                    self._publish_modes()
                else:
                    self._publish_diagnostics()
            except Exception as exc:  # noqa: BLE001 - reported like a worker error
                self._errors += 1
                msg = f"publishing failed: {type(exc).__name__}: {exc}"
                if msg != self._last_error:
                    self.get_logger().error(msg)
                self._last_error = msg

        def _check_graph(self) -> None:
            """A configured topic carrying another message type: name the topic and both types."""
            found = dict(self.get_topic_names_and_types())
            wrong = []
            for s in self.signals:
                sc = self.cfg.signals[s]
                topic = self.topics[s]
                others = [t for t in found.get(topic, []) if t != sc.type]
                if others:
                    wrong.append(f"topic {topic} ({s}) carries {', '.join(others)} but {s}.type is {sc.type}")
            if wrong and wrong != self._wrong_types:
                for w in wrong:
                    self.get_logger().error(f"wrong message type: {w}")
            self._wrong_types = wrong

        # ------------------------------------------------------------------------------------ output
        def _current(self) -> tuple[Any, Any, bool]:
            """(report, modal, new) for /diagnostics: the newest report (new: not shown before; the same vetted
            estimate as the last ~/modes message), else, before any report
            (a state restored from ``state_file``), the live estimate when the worker lets go of the lock within
            20 ms, else the last snapshot."""
            rep = self._latest_report          # read once; the worker only ever replaces it (no lost update)
            if rep is not None and rep is not self._last_published:
                self._last_published = rep
                return rep, rep.modal, True
            if rep is not None:
                return rep, rep.modal, False
            if self.lock.acquire(timeout=0.02):
                try:
                    if self.pipeline is not None:
                        self._snapshot = (self.pipeline.last_report, self.pipeline._modal())
                finally:
                    self.lock.release()
            return self._snapshot[0], self._snapshot[1], False

        def _publish_modes(self) -> None:
            """~/modes: every report's estimate not published yet, in order."""
            modes_pub = self._modes_pub
            if self.sync is None or modes_pub is None or not self._active:
                return
            while self._modes_queue:
                modes_pub.publish(cv.modes_array(self._modes_queue.popleft()))
                self._reports_published += 1

        def _publish_diagnostics(self) -> None:
            """/diagnostics: one status per mode and the estimator status, always (STALE without data)."""
            sync, diag_pub = self.sync, self._diag_pub
            if sync is None or diag_pub is None or not self._active:
                return
            rep, modal, _ = self._current()
            silent = sync.silent(time.monotonic_ns(), self._stale_timeout_s, self.looking_since_ns)
            stale = bool(silent) or rep is None or not rep.estimating
            name, hw = self.status_prefix(), self.get_fully_qualified_name()
            arr = DiagnosticArray()
            arr.header.stamp = self.get_clock().now().to_msg()
            n_modes = self.cfg.K if modal is None else len(modal)   # 0 while the modes are being found
            for i in range(n_modes):
                vals = {f: math.nan for f in cv.MODE_FIELDS} if modal is None else \
                    {f: float(modal[i, j]) for j, f in enumerate(cv.MODE_FIELDS)}
                level, msg = int(Level.STALE), "initializing" if self.looking_since_ns else "starting"
                if rep is not None and rep.K == n_modes:
                    md = rep.mode_dict(i)
                    vals.update({k: md[k] for k in (*cv.BASELINE_FIELDS, *cv.FLAG_FIELDS)})
                    level, msg = int(rep.mode_levels[i]), self._mode_message(rep, i)
                if silent:
                    level, msg = int(Level.STALE), "no data on " + ", ".join(self.topics[s] for s in silent)
                elif rep is None or not rep.estimating:
                    level, msg = int(Level.STALE), "initializing"
                arr.status.append(cv.mode_status(f"{name}: mode {i + 1}", hw, vals, level, msg))
            arr.status.append(self._estimator_status(rep, silent, stale, hw))
            diag_pub.publish(arr)

        def status_prefix(self) -> str:
            """Name prefix of this node's /diagnostics statuses: the node name in the root namespace (as ever), the
            full name without its leading '/' under a namespace (``axis1/additive_rsrivc_monitor``), so that the
            monitors of several axes publishing on the one /diagnostics topic never share a status name."""
            return self.get_fully_qualified_name().lstrip("/")

        @staticmethod
        def _mode_message(rep: Any, i: int) -> str:
            q = ("natural_frequency", "damping", "gain")
            faults = [f"{q[j]} {rep.directions[i][j]}".strip() for j in range(3) if rep.flags[i, j]]
            if faults:
                return "fault: " + ", ".join(faults)
            return rep.phase

        def _delays(self) -> tuple[float, float, float]:
            """Median, p95, max of the delays; recomputed at most once a second (composition stays cheap)."""
            now = time.monotonic_ns()
            if now - self._delay_cache_ns > 1_000_000_000 or math.isnan(self._delay_cache[0]):
                d = self.delays_ms
                v = d.values().copy()
                self._delay_cache = tuple(float(x) for x in np.percentile(v, (50, 95, 100))) if v.size \
                    else (math.nan,) * 3
                self._delay_cache_ns = now
            return self._delay_cache

        def _estimator_values(self, rep: Any, h: dict[str, Any], silent: list[str]) -> dict[str, Any]:
            """Key/values of the estimator status (counters, health, timing)."""
            sync, pipe = self.sync, self.pipeline
            sc = sync.counters
            est = h.get("estimator", {}) or {}
            cond = [c for c in est.get("cond", []) if c is not None]
            rtf = self._data_s / self._busy_s if self._busy_s > 0 else math.nan
            d50, d95, dmax = self._delays()
            return {
                "phase": rep.phase if rep is not None else pipe.phase,
                "samples_received": sum(sc.received),
                "samples_aligned": sc.aligned,
                "samples_processed": int(h.get("samples_processed", 0)),
                "samples_dropped": int(h.get("samples_dropped", 0)) + sc.dropped,
                "samples_skipped": int(h.get("samples_skipped", 0)),
                "nonfinite_samples": int(h.get("nonfinite", 0)),
                "out_of_order": int(h.get("out_of_order", 0)) + sc.out_of_order,
                "duplicate_stamps": int(h.get("duplicates", 0)),
                "gaps": int(h.get("gaps", 0)),
                "input_pauses": sc.gaps,
                "misaligned_events": sc.mismatches,
                "unmatched_messages": sc.unmatched,
                "malformed_messages": sum(self._malformed.values()),
                "queue_backlog": max((len(q) + len(p) for q, p in zip(sync.queues, sync.pending, strict=True)),
                                     default=0),
                "queue_bound_samples": sync.max_queue,
                "queue_dropped": sum(sc.queue_dropped),
                "queue_dropped_per_topic": " ".join(f"{lb}={n}" for lb, n in zip(sync.labels, sc.queue_dropped,
                                                                                strict=True)),
                "arrival_rate_hz": " ".join(f"{lb}={cv.num(round(r, 1))}" for lb, r in zip(sync.labels,
                                                                                      sync.measured_rate, strict=True)),
                "rate_mismatches": sc.rate_mismatches,
                **_alignment_values(h.get("alignment") or {}),
                "node_stalls": self.node_stalls,
                "node_stall_max_s": float(self.node_stall_max_s),
                "node_stall_gaps": sc.node_stall_gaps,
                "worker_stalls": self.worker_stalls,
                "worker_stall_max_s": float(self.worker_stall_max_s),
                "reports_coalesced": max(0, self._reports_made - self._reports_published),
                "projections": int(sum(est.get("projections", []) or [0])),
                "reprimes": int(est.get("reprimes", 0) or 0),
                "condition_number": float(max(cond)) if cond else math.nan,
                "condition_number_per_mode": " ".join(cv.num(c) for c in cond),
                "residual_variance": float(est.get("residual_var", math.nan) or math.nan),
                "initializations": int(h.get("initializations", 0)),
                "reinitializations": int(h.get("reinitializations", 0)),
                "real_time_factor": float(rtf),
                "cpu_fraction": float(self._cpu_fraction),
                "delay_median_ms": d50,
                "delay_p95_ms": d95,
                "delay_max_ms": dmax,
                "internal_errors": self._errors,
                "silent_topics": " ".join(self.topics[s] for s in silent),
                "wrong_types": "; ".join(self._wrong_types),
                **(sync.extra_values() if hasattr(sync, "extra_values") else {}),
            }

        def _input_reasons(self, sync: Any) -> list[str]:
            """Open input problems that last (rate mismatch, queue overflow, a busy estimator): WARN reasons."""
            out = [sync.rate_reason(lb, r, sync.expected_rate) for lb, r in list(sync.rate_mismatch.items())]
            out += sync.lasting_reasons() if hasattr(sync, "lasting_reasons") else []
            out += [f"queue of {lb} full: dropping the oldest messages ({n} so far)"
                    for lb, n, ov in zip(sync.labels, sync.counters.queue_dropped, sync._overflowing, strict=True)
                    if ov]
            busy = self._push_started_ns
            if busy and time.monotonic_ns() - busy > 500_000_000:
                out.append(f"estimator busy for {(time.monotonic_ns() - busy) * 1e-9:.1f} s (the node, not the "
                           "inputs: samples wait in the queues)")
            return out

        def _estimator_status(self, rep: Any, silent: list[str], stale: bool, hw: str) -> Any:
            sync, pipe = self.sync, self.pipeline
            h = dict(rep.health) if rep is not None else {}
            h.update(pipe.counters.to_dict())      # live counters (the report may be older)
            vals = self._estimator_values(rep, h, silent)
            reasons = list(h.get("reasons", []))
            level = int(h.get("level", 0)) if rep is not None else int(Level.STALE)
            lasting = self._input_reasons(sync)
            recent = time.monotonic_ns() - sync.last_event_ns < 5e9 and sync.last_event_ns > 0
            if recent and sync.events and sync.events[-1] not in lasting:
                reasons.append(sync.events[-1])
            reasons += lasting
            if (recent or lasting) and level != int(Level.STALE):
                level = max(level, int(Level.WARN))
            elif lasting and not silent:       # no estimate yet but data flows: the input problem is the news
                level = int(Level.WARN)
            if self._errors and self._last_error:
                reasons.append(f"internal error: {self._last_error}")
                level = max(level, int(Level.ERROR)) if level != int(Level.STALE) else level
            if silent:
                reasons.insert(0, "no data on " + ", ".join(f"{self.topics[s]} for more than "
                                                            f"{self._stale_timeout_s:g} s" for s in silent))
                level = int(Level.STALE)
            elif stale and rep is None and not lasting:
                level = int(Level.STALE)
            if self._wrong_types:
                reasons.insert(0, "wrong message type: " + "; ".join(self._wrong_types))
                level = int(Level.ERROR)
            vals["reasons"] = "; ".join(reasons)
            msg = "; ".join(reasons) if reasons else (vals["phase"] if rep is not None else "no data")
            return cv.status(f"{self.status_prefix()}: estimator", hw, vals, level, msg)

    return MonitorNode


def _alignment_values(al: dict[str, Any]) -> dict[str, Any]:
    """Estimator-status values of the stream aligner (controller invariant; core/alignment.py)."""
    if al.get("mode") != "invariant":
        return {"alignment": al.get("mode", "off")}
    return {"alignment": "verified" if al.get("verified") else "approximate",
            "alignment_offset_u_r": " ".join(str(v) for v in al.get("offset", [])),
            "alignment_realignments": int(al.get("realignments", 0)),
            "alignment_refilled": int(al.get("reconstructed", 0)),
            "alignment_set_aside": int(al.get("invalidated", 0)) + int(al.get("late", 0)),
            "alignment_relative_residual": float(al.get("relative_residual", math.nan))}


def spin(node: Any, executor: Any, started_ns: int) -> None:
    """``spin_once`` loop (see module docstring); records when the executor was idle (input pause checks) and
    when it did not run (the node's own stalls, from ``started_ns``: start-up counts as one)."""
    last = started_ns
    node.looking_since_ns = 0
    while rclpy.ok() and not _STOP_REQUESTED.is_set():
        t0 = time.monotonic_ns()
        if t0 - last > STALL_NS:
            node.note_stall(last, t0)
            node.looking_since_ns = t0
        elif not node.looking_since_ns:
            node.looking_since_ns = t0
        executor.spin_once(timeout_sec=0.05)
        t1 = time.monotonic_ns()
        if t1 - t0 > STALL_NS + 50_000_000:
            node.note_stall(t0, t1)
            node.looking_since_ns = t1
        if t1 - t0 >= 40_000_000:
            node.idle_since_ns = t1
        last = t1


def main(argv: list[str] | None = None) -> int:
    """Console script ``rsrivc_monitor``."""
    args = list(sys.argv[1:] if argv is None else argv)
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    if "-h" in own or "--help" in own:
        print(USAGE)
        return 0
    if own:
        print(f"rsrivc_monitor: unknown argument(s) {' '.join(own)} (ROS arguments go after --ros-args; see --help)",
              file=sys.stderr)
        return 2
    started_ns = time.monotonic_ns()
    signal.signal(signal.SIGINT, _request_stop)      # first: a signal at any later moment only sets the flag
    signal.signal(signal.SIGTERM, _request_stop)
    _import_ros()
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=["rsrivc_monitor", *args], signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = 0
    try:
        node = make_node_class()()
        executor = EventsExecutor()
        executor.add_node(node)
        if node.get_parameter("autostart").value and not _STOP_REQUESTED.is_set():
            node.trigger_configure()
            if node.pipeline is None:
                print(f"rsrivc_monitor: configuration rejected: {node.config_error}", file=sys.stderr)
                return 1
            if not _STOP_REQUESTED.is_set():
                node.trigger_activate()
        if not _STOP_REQUESTED.is_set():
            spin(node, executor, started_ns)
        print(f"rsrivc_monitor: stopping ({_SIGNAL_NAME[0] or 'shutdown'})", file=sys.stderr)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # noqa: BLE001 - parameter declaration errors etc.: one line, non-zero exit
        from .config import ParamError
        kind = "" if isinstance(exc, ParamError) else f"{type(exc).__name__}: "
        print(f"rsrivc_monitor: {kind}{exc}", file=sys.stderr)
        code = 1
    finally:
        if node is not None:
            try:
                node.close()
            except Exception as exc:  # noqa: BLE001
                print(f"rsrivc_monitor: saving state failed: {exc}", file=sys.stderr)
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
