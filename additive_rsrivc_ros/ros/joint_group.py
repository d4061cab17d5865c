"""``JointGroupNode``: one lifecycle node monitoring N joints from the shared multi-joint topics robots publish.

A robot's controller publishes every joint in one ``sensor_msgs/JointState`` per loop sample (``/joint_commands``,
``/joint_states``). This node subscribes once per distinct topic (:class:`.joint_fanout.SharedJointTopic`; the
callback only queues the message), and one worker thread converts each message once for all joints and hands each
joint's samples to that joint's own machinery (:class:`.joint_channel.JointChannel`: the monitor's input stage,
:class:`..core.pipeline.MonitorPipeline`, statuses, ``~/<joint>/modes``, services). A joint with ``block.topic`` reads
its own block topic instead (N block-input axes in one process). Parameters: :mod:`..joint_params` (``joints`` and one
section per joint); the executor is the monitor's (:func:`.monitor_node.spin`: EventsExecutor driven by ``spin_once``).

Threads: the executor (callbacks append to bounded deques), one worker (every ``block_period_s``: fan-out, then each
joint's step in turn), one publisher (each joint's ``~/<joint>/modes`` and ``/diagnostics`` on its own schedule).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from .. import joint_params as jp
from ..config import MonitorConfig, ParamError, all_params, param_table
from ..core.monitor.pipeline import PipelineError
from ..warmup import is_warm, load_kernels
from . import convert as cv
from . import joint_cdr
from .channel import Activity
from .inputs import first_line, reader_depth
from .joint_channel import JointChannel
from .joint_fanout import Reader, SharedJointTopic
from .params import REQUIRED_PARAMS, checked_config, missing_required, unknown_warning


class JointGroupNode(LifecycleNode):
    """Managed node around one :class:`JointChannel` per joint; see the module docstring."""

    def __init__(self, node_name: str = jp.JOINT_GROUP_NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._table = param_table()
        self.joints: list[str] = []
        self._own: dict[str, set[str]] = {}       # joint -> names it has its own parameter for
        self._declare_error = ""
        self._declare_all()
        self.add_pre_set_parameters_callback(self._pre_set)
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._post_set)
        self.channels: dict[str, JointChannel] = {}
        self.shared: dict[str, SharedJointTopic] = {}
        self.config_error = ""
        self.activity = Activity()               # shared by the joints: active, the executor's idle and looking times
        self.active_since = time.monotonic()
        self._subs: list[Any] = []
        self._diag_pub = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._graph: dict[str, list[str]] = {}
        self._graph_ns = 0
        self._period_s = 0.05
        self._raw = False
        self._closed = False

    # ------------------------------------------------------------------------------------ parameters
    def _declare_all(self) -> None:
        """Declare ``joints``, every shared row (group defaults, :data:`..joint_params.JOINT_DEFAULTS`) and each
        joint's own rows that the params give; a problem is kept for ``configure`` to report (one line). A missing
        shared ``loop_rate_hz`` raises ParamError naming the params-file keys that would reach the node."""
        ov = self._parameter_overrides
        for name in REQUIRED_PARAMS:      # shared by the joints (a joint may still give its own)
            if name not in ov:
                raise ParamError(missing_required(name, self.get_fully_qualified_name(), ov, self._table)
                                 .replace("parameter '", "shared parameter '", 1))
        for name in list(ov):
            row = self._table.get(name.partition(".")[2]) if name not in self._table else self._table[name]
            if row is not None:
                ov[name] = cv.coerce_int_to_double(row, ov[name])
        self._declare_names("joints", "Names of the joints to monitor; a joint's own parameters go under '<joint>.'")
        self._declare_names("monitor_joints", "Monitor only these of 'joints' (empty: all); the launch argument joints")
        self.declare_parameter("joint_count", 0, ParameterDescriptor(
            name="joint_count", type=Parameter.Type.INTEGER.value, read_only=True,
            description="Monitor the first N of the joints (0: all of them); the launch argument count"))
        for p in all_params():
            if p.name not in jp.PER_JOINT_ONLY:
                self._declare_row(p.name, p, jp.JOINT_DEFAULTS.get(p.name, p.default))
        try:
            listed = jp.check_joint_names(self.get_parameter("joints").value)
            given = {n: cv.plain(v.value) for n, v in ov.items()}
            _, own, foreign = jp.split_given(given, listed)
            subset = list(self.get_parameter("monitor_joints").value or [])
            self.joints = jp.monitored_joints(listed, subset, int(self.get_parameter("joint_count").value))
        except ParamError as exc:
            self._declare_error = str(exc)
            return
        if foreign:
            self.get_logger().warning(unknown_warning(foreign, self._table))
        for j in self.joints:
            names = own[j]
            self._own[j] = set(names)
            for name in names:
                self._declare_row(jp.joint_param_name(j, name), self._table[name], self._table[name].default)

    def _declare_names(self, name: str, description: str) -> None:
        """A read-only string[] parameter, [] when not given (an untyped empty list cannot be declared)."""
        self.declare_parameter(name, Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            name=name, type=Parameter.Type.STRING_ARRAY.value, read_only=True, description=description))
        if self.get_parameter_or(name).type_ == Parameter.Type.NOT_SET:
            self._parameters[name] = Parameter(name, Parameter.Type.STRING_ARRAY, [])

    def _declare_row(self, full: str, p: Any, default: Any) -> None:
        desc = cv.descriptor(p)
        desc.name = full
        if isinstance(default, list) and not default:
            self.declare_parameter(full, cv.PARAM_TYPE[p.type], desc)
            if self.get_parameter_or(full).type_ == Parameter.Type.NOT_SET:
                self._parameters[full] = Parameter(full, cv.PARAM_TYPE[p.type], [])
        else:
            self.declare_parameter(full, default, desc)

    def joint_values(self, joint: str, changes: dict[str, Any] | None = None) -> dict[str, Any]:
        """A joint's effective values (own, else shared, else the group default), with candidate ``changes``
        (full parameter names) applied."""
        changes = changes or {}

        def get(full: str) -> Any:
            return changes[full] if full in changes else cv.plain(self.get_parameter(full).value)
        own = self._own.get(joint, set())
        out = {}
        for name in self._table:
            if name in own:
                out[name] = get(jp.joint_param_name(joint, name))
            elif name in jp.PER_JOINT_ONLY:
                out[name] = joint
            else:
                out[name] = get(name)
        return out

    def _split_change(self, names: list[str]) -> dict[str, list[str]]:
        """Joint -> the changed full names that reach it (a shared name reaches the joints without their own)."""
        out: dict[str, list[str]] = {}
        for full in names:
            head, _, rest = full.partition(".")
            if head in self._own and rest in self._own[head]:
                out.setdefault(head, []).append(full)
            elif full in self._table:
                for j in self.joints:
                    if full not in self._own.get(j, set()):
                        out.setdefault(j, []).append(full)
        return out

    def _pre_set(self, params: list[Parameter]) -> list[Parameter]:
        out = []
        for p in params:
            row = self._table.get(p.name) or self._table.get(p.name.partition(".")[2])
            out.append(cv.coerce_int_to_double(row, p) if row is not None else p)
        return out

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Accept a change only when every joint it reaches passes the configuration checks with it."""
        changes = {p.name: cv.plain(p.value) for p in params}
        for joint in self._split_change(list(changes)):
            try:
                checked_config(self.joint_values(joint, changes), strict=False)
            except (ParamError, ValueError) as exc:
                return SetParametersResult(successful=False, reason=f"rejected for joint '{joint}': {exc}")
        return SetParametersResult(successful=True)

    def _post_set(self, params: list[Parameter]) -> None:
        """Apply an accepted change to each joint it reaches (the monitor's runtime changes, per joint)."""
        by_name = {p.name: p for p in params}
        for joint, names in self._split_change(list(by_name)).items():
            ch = self.channels.get(joint)
            if ch is not None:
                ch.parts.runtime.apply([Parameter(n.partition(".")[2] if n not in self._table else n,
                                                  value=by_name[n].value) for n in names])

    # ------------------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Check every joint's parameters, build the channels, subscribe once per topic; FAILURE with one log line."""
        try:
            if self._declare_error:
                raise ParamError(self._declare_error)
            checked = self._checked_joints()
        except (ParamError, ValueError) as exc:
            return self._reject(exc)
        self._load_kernels()
        try:
            for joint, (values, cfg) in checked.items():
                ch = JointChannel(self, joint)
                ch.configure(cfg, values, self._resolve(joint, cfg, values))
                self.channels[joint] = ch
            self._subscribe(checked)
        except (ParamError, PipelineError, ValueError) as exc:
            self._destroy_interfaces()
            return self._reject(exc)
        self._period_s = float(self.get_parameter("block_period_s").value)
        self._diag_pub = self.create_lifecycle_publisher(DiagnosticArray, "/diagnostics", 10)
        for ch in self.channels.values():
            ch.create_outputs(self._diag_pub)
        topics = ", ".join(f"{t} ({len(s.readers)} signals)" for t, s in self.shared.items())
        blocks = [j for j, ch in self.channels.items() if ch.parts.core.configured_cfg().block_input]
        self.get_logger().info(
            f"configured: {len(self.channels)} joints ({', '.join(self.channels)}); shared topics: {topics or 'none'}"
            + (f"; block input: {', '.join(blocks)}" if blocks else "") + f"; worker period {self._period_s:g} s"
            + ("" if self._raw or not self.shared else "; JointState deserialized by rclpy (CDR self-check failed)"))
        return TransitionCallbackReturn.SUCCESS

    def _checked_joints(self) -> dict[str, tuple[dict[str, Any], MonitorConfig]]:
        """Every joint's validated values and configuration, then the cross-joint checks (ParamError names the
        joint)."""
        if not self.joints:
            raise ParamError("parameter 'joints' is required: the list of joint names to monitor")
        out = {}
        for j in self.joints:
            values = self.joint_values(j)
            if not values["loop_rate_hz"]:
                raise ParamError(f"joint '{j}': parameter 'loop_rate_hz' is required (shared or {j}.loop_rate_hz)")
            try:
                out[j] = checked_config(values)
            except (ParamError, ValueError) as exc:
                raise ParamError(f"joint '{j}': {exc}") from None
        jp.check_group({j: v for j, (v, _) in out.items()})
        return out

    def _resolve(self, joint: str, cfg: MonitorConfig, values: dict[str, Any]) -> dict[str, str]:
        """Signal -> resolved topic of one joint (ParamError on an invalid name)."""
        names = {"block": values["block.topic"]} if cfg.block_input else \
            {s: cfg.signals[s].topic for s in jp.SIGNALS if s != "reference" or cfg.closed_loop}
        out = {}
        for s, topic in names.items():
            try:
                out[s] = self.resolve_topic_name(topic)
            except Exception as exc:  # noqa: BLE001 - rclpy raises RuntimeError / rcl errors for bad names
                raise ParamError(f"joint '{joint}': topic {topic!r} of {s} is not a valid topic name "
                                 f"({first_line(exc)})") from None
        return out

    def _qos(self, rate_hz: float) -> QoSProfile:
        v = {"qos_depth": int(self.get_parameter("qos_depth").value)}
        reliable = bool(self.get_parameter("qos_reliable").value)
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=reader_depth(v, rate_hz),
                          reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)

    def _subscribe(self, checked: dict[str, tuple[dict[str, Any], MonitorConfig]]) -> None:
        """One subscription per shared JointState topic (readers: every joint signal on it); one per block topic."""
        opts = QoSOverridingOptions.with_default_policies()
        self._raw = joint_cdr.checked_against_rclpy()
        rate: dict[str, float] = {}
        for ch in self.channels.values():
            core = ch.parts.core
            cfg, sync = core.configured_cfg(), core.configured_sync()
            r = cfg.loop_rate_hz
            if cfg.block_input:
                self._create_sub(Float64MultiArray, ch.topic_of["block"], ch.parts.inputs.block_cb(), self._qos(r),
                                 opts)
                continue
            for i, s in enumerate(core.signals):
                topic = ch.topic_of[s]
                if topic not in self.shared:
                    self.shared[topic] = SharedJointTopic(topic, sync.max_queue, raw=self._raw,
                                                          msg_type=JointState)
                self.shared[topic].max_queue = max(self.shared[topic].max_queue, sync.max_queue)
                sc = cfg.signals[s]
                self.shared[topic].add_reader(Reader(sync, ch.parts.stats, i, s, sc.joint, sc.field))
                rate[topic] = max(rate.get(topic, 0.0), r)
        for topic, shared in self.shared.items():
            self._create_sub(JointState, topic, self._shared_cb(shared), self._qos(rate[topic]), opts, raw=self._raw)

    def _create_sub(self, kind: Any, topic: str, cb: Any, qos: QoSProfile, opts: Any, raw: bool = False) -> None:
        try:
            self._subs.append(self.create_subscription(kind, topic, cb, qos, qos_overriding_options=opts, raw=raw))
        except Exception as exc:  # noqa: BLE001 - rclpy raises several types for a bad override value
            raise ParamError(f"QoS override for {topic} rejected: {first_line(exc)}") from None

    def _shared_cb(self, shared: SharedJointTopic) -> Any:
        enqueue, mono = shared.enqueue, time.monotonic_ns
        activity = self.activity

        def cb(msg: bytes | JointState) -> None:
            if activity.active:
                enqueue(msg, mono())
        return cb

    def _reject(self, exc: Exception) -> TransitionCallbackReturn:
        self.config_error = str(exc)
        self.get_logger().error(f"configuration rejected: {exc}")
        return TransitionCallbackReturn.FAILURE

    def _load_kernels(self) -> None:
        if not is_warm():
            self.get_logger().warning("the numba kernels of this version are not cached yet: compiling them now "
                                      "(once, about a minute; run rsrivc_warmup after installing to avoid this)")
        self.get_logger().info(f"kernels loaded in {load_kernels():.2f} s")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop.clear()
        self.activity.active = True
        self.active_since = time.monotonic()
        for ch in self.channels.values():
            ch.cpu_s = 0.0
        self._threads = [threading.Thread(target=self._run_worker, name="rsrivc_joints_worker", daemon=True),
                         threading.Thread(target=self._run_publisher, name="rsrivc_joints_publisher", daemon=True)]
        for th in self._threads:
            th.start()
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_threads()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_threads()
        for ch in self.channels.values():
            ch.save_state()
        self._destroy_interfaces()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.close()
        return TransitionCallbackReturn.SUCCESS

    def _stop_threads(self) -> None:
        self.activity.active = False
        self._stop.set()
        for th in self._threads:
            if th is not threading.current_thread():
                th.join(timeout=10.0)
        self._threads = []

    def _destroy_interfaces(self) -> None:
        for s in self._subs:
            self.destroy_subscription(s)
        for ch in self.channels.values():
            ch.destroy_outputs()
        if self._diag_pub is not None:
            self.destroy_lifecycle_publisher(self._diag_pub)
        self._subs, self._diag_pub, self.channels, self.shared = [], None, {}, {}

    def close(self) -> None:
        """Stop the threads and save every joint's state once; called on shutdown."""
        self._stop_threads()
        if not self._closed:
            self._closed = True
            for ch in self.channels.values():
                try:
                    ch.close()
                except OSError as exc:
                    self.get_logger().error(f"joint '{ch.joint}': saving state failed: {exc}")

    # ------------------------------------------------------------------------------------ threads
    def _run_worker(self) -> None:
        """Every ``block_period_s``: fan the shared topics out, then step each joint (its own pipeline)."""
        while not self._stop.wait(self._period_s):
            now = time.monotonic_ns()
            channels = list(self.channels.values())
            syncs = [ch.parts.core.sync for ch in channels]
            marks = [sync.n_events if sync is not None else 0 for sync in syncs]
            for shared in list(self.shared.values()):
                try:
                    shared.fan_out(now)
                except Exception as exc:  # noqa: BLE001 - reported on the joints that read the topic
                    for r in shared.readers:
                        r.stats.errors += 1
                        r.stats.last_error = f"fan-out of {shared.topic} failed: {type(exc).__name__}: {exc}"
            for ch, mark in zip(channels, marks, strict=True):
                sync = ch.parts.core.sync
                if sync is not None:
                    ch.parts.worker.log_events(sync, mark)     # what the fan-out found (a joint missing from messages)
                ch.guarded_step()

    def _run_publisher(self) -> None:
        """Each joint's ``~/<joint>/modes`` (publish_rate_hz) and /diagnostics (diagnostics_period_s), on its own
        schedule, no catch-up burst after falling behind."""
        start = time.monotonic()
        due: dict[tuple[str, str], float] = {}
        while not self._stop.is_set():
            now = time.monotonic()
            nxt = math.inf
            for ch in list(self.channels.values()):
                st = ch.parts.settings
                for out, period in (("modes", st.publish_period_s), ("diagnostics", st.diag_period_s)):
                    key = (ch.joint, out)
                    t = due.setdefault(key, start + period)
                    if now >= t:
                        ch.parts.publisher.publish_guarded(out)
                        t = due[key] = max(t + period, now)
                    nxt = min(nxt, t)
            if self._stop.wait(max(0.0, min(nxt, now + 1.0) - time.monotonic())):
                break

    def note_stall(self, start_ns: int, end_ns: int) -> None:
        """The executor did not run (called by :func:`.monitor_node.spin`): every joint's stall."""
        for ch in list(self.channels.values()):
            ch.parts.worker.note_stall(start_ns, end_ns)

    def graph(self) -> dict[str, list[str]]:
        """Topic names and types, read at most once a second for all joints."""
        now = time.monotonic_ns()
        if now - self._graph_ns > 900_000_000:
            self._graph = dict(self.get_topic_names_and_types())
            self._graph_ns = now
        return self._graph
