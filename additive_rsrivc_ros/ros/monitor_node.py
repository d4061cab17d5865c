"""``MonitorNode``: the ROS 2 lifecycle node that runs :class:`MonitorPipeline` on live r, u, y topics.

A thin shell that owns its parts (docs/ARCHITECTURE.md): :class:`.params.ParamsHandler` (declaration, checks of a
change) and :class:`.channel_parts.ChannelParts`, the parts of the one channel it monitors: :mod:`.inputs` (topics,
callbacks that only queue), :mod:`.worker` (the thread that aligns the streams with :mod:`.sync` or :mod:`.blocks` and
feeds the pipeline in blocks), :mod:`.publishing` (``~/modes``, ``/diagnostics``), :mod:`.state` (``state_file``),
:mod:`.params` (runtime changes). The executor is ``rclpy.experimental.EventsExecutor`` driven by ``spin_once``
(:func:`spin`; its ``spin()`` starves Python timers and threads in this rclpy build), because the default executor
loses Float64 messages above ~1 kHz. ``configure`` checks the parameters (one-line rejection), loads the kernels,
restores or builds the pipeline and creates the interfaces; ``activate`` / ``deactivate`` start and stop the threads;
``cleanup`` and ``shutdown`` save the state.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Protocol

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import Executor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ..config import DEFAULT_NODE_NAME, ParamError, param_table
from ..core.monitor.pipeline import MonitorPipeline, PipelineError
from ..signal_stop import StopFlag
from ..warmup import is_warm, load_kernels
from .channel import Activity, ChannelContext
from .channel_parts import ChannelParts
from .params import ParamsHandler, checked_config, split_unknown, unknown_warning
from .rosout import FATAL_WAIT_S, last_words_publisher, one_line_error, publish_last_words
from .worker import STALL_NS


class MonitorNode(LifecycleNode):
    """Managed node around :class:`MonitorPipeline`; see the module docstring."""

    def __init__(self, node_name: str = DEFAULT_NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        table = param_table()
        self._rosout = last_words_publisher(self)
        self.activity = Activity()
        ctx = ChannelContext(self.get_fully_qualified_name(), self.get_logger(), self.get_clock(),
                             self._parameter_value, self.activity)
        self.channel = ChannelParts(ctx, table, check_graph=self._check_graph)
        self.params = ParamsHandler(self, table, self.channel.runtime)
        try:
            self.params.declare_all()
        except Exception as exc:            # the node ends here: say why on /rosout too (the caller prints it)
            self.last_words("fatal", one_line_error(exc))
            raise
        self.params.install()
        self.config_error = ""
        self._subs: list[Any] = []
        self._srvs: list[Any] = []
        self._worker: threading.Thread | None = None
        self._pub_thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False

    @property
    def pipeline(self) -> MonitorPipeline | None:
        """The configured pipeline (None before configuration or after a rejected one)."""
        return self.channel.core.pipeline

    def _parameter_value(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _check_graph(self) -> None:
        self.channel.inputs.check_graph(dict(self.get_topic_names_and_types()))

    # ------------------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Check the parameters, build (or restore) the pipeline and create the interfaces; FAILURE with one log
        line (and :attr:`config_error`) when the configuration is rejected."""
        table = self.params.table
        unknown, foreign = split_unknown(self._parameter_overrides, table)
        if foreign:
            self.get_logger().warning(unknown_warning(foreign, table))
        try:
            if unknown:
                raise ParamError(f"unknown parameter(s): {', '.join(unknown)}")
            values, cfg = checked_config(self.params.values())
        except (ParamError, ValueError) as exc:
            return self._reject(exc)
        if cfg.block_input:       # block rows are paired by index: the pipeline's stream aligner stays off
            cfg = cfg.with_block_input()
        ch = self.channel
        self._load_kernels()
        try:
            ch.build_pipeline(cfg, values["state_file"])
            ch.core.topics = ch.inputs.resolve_topics(cfg, self)
        except (PipelineError, ValueError) as exc:
            return self._reject(exc)
        ch.configure_runtime(cfg, values)
        try:
            qos_text = ch.inputs.subscribe(self, cfg, values, self._subs)
        except ParamError as exc:
            self._destroy_interfaces()
            return self._reject(exc)
        self._create_outputs()
        sync = ch.core.configured_sync()
        self.get_logger().info(
            f"configured: K={cfg.K or 'from the data'}, {cfg.loop_rate_hz:g} Hz, "
            f"{'closed' if cfg.closed_loop else 'open'} loop, "
            f"inputs {', '.join(ch.core.topics[s] for s in ch.core.signals)} ({sync.pairing}), QoS {qos_text}, "
            f"input queues bounded at {sync.max_queue} samples per topic (<= {sync.queue_bytes() / 1e6:.3g} MB)")
        self.warn_duplicate_name()       # again after activation, once discovery has seen the graph
        return TransitionCallbackReturn.SUCCESS

    def _reject(self, exc: Exception) -> TransitionCallbackReturn:
        self.config_error = str(exc)
        self.get_logger().error(f"configuration rejected: {exc}")
        return TransitionCallbackReturn.FAILURE

    def _create_outputs(self) -> None:
        out, state = self.channel.outputs, self.channel.state
        out.modes = self.create_lifecycle_publisher(Float64MultiArray, "~/modes", 10)
        out.modes_stamped = self.create_lifecycle_publisher(PointCloud2, "~/modes_stamped", 10)
        out.diagnostics = self.create_lifecycle_publisher(DiagnosticArray, "/diagnostics", 10)
        self._srvs = [self.create_service(Trigger, "~/reset", state.srv_reset),
                      self.create_service(Trigger, "~/rebaseline", state.srv_rebaseline),
                      self.create_service(Trigger, "~/save_state", state.srv_save)]

    def _load_kernels(self) -> None:
        """numba's one-time start (1-2 s, or a compilation without the cache) before any data, not mid-stream."""
        if not is_warm():
            self.get_logger().warning("the numba kernels of this version are not cached yet: compiling them now "
                                      "(once, about a minute; run rsrivc_warmup after installing to avoid this)")
        seconds = load_kernels()
        self.get_logger().info(f"kernels loaded in {seconds:.2f} s")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop.clear()
        self.activity.active = True
        self._worker = threading.Thread(target=self.channel.worker.run, args=(self._stop,), name="rsrivc_worker",
                                        daemon=True)
        self._worker.start()
        self._pub_thread = threading.Thread(target=self.channel.publisher.run, args=(self._stop,
                                            self.warn_duplicate_name), name="rsrivc_publisher", daemon=True)
        self._pub_thread.start()
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_worker()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_worker()
        self.save_state()
        self._destroy_interfaces()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.close()
        return TransitionCallbackReturn.SUCCESS

    def _stop_worker(self) -> None:
        self.activity.active = False
        self._stop.set()
        for th in (self._worker, self._pub_thread):
            if th is not None and th is not threading.current_thread():
                th.join(timeout=10.0)
        self._worker = self._pub_thread = None

    def _destroy_interfaces(self) -> None:
        out = self.channel.outputs
        for s in self._subs:
            self.destroy_subscription(s)
        for s in self._srvs:
            self.destroy_service(s)
        for p in (out.modes, out.modes_stamped, out.diagnostics):
            if p is not None:
                self.destroy_lifecycle_publisher(p)
        self._subs, self._srvs, out.modes, out.diagnostics = [], [], None, None
        out.modes_stamped = None
        self.channel.unconfigure()

    def save_state(self) -> str:
        """Write the pipeline state to ``state_file`` (:meth:`.state.StateStore.save_state`); a one-line result."""
        return self.channel.state.save_state()

    def note_stall(self, start_ns: int, end_ns: int) -> None:
        """The executor did not run from ``start_ns`` to ``end_ns`` (called by :func:`spin`)."""
        self.channel.worker.note_stall(start_ns, end_ns)

    def warn_duplicate_name(self) -> bool:
        """Warn (once per call) when another node in the graph has this node's fully qualified name: their
        statuses, ~/modes, parameters and state files would be mixed up. True when one was found."""
        me = self.get_fully_qualified_name()
        same = [ns for name, ns in self.get_node_names_and_namespaces()
                if f"{ns.rstrip('/')}/{name}" == me]
        if len(same) > 1:
            self.get_logger().warning(f"{len(same)} nodes named {me} run in this ROS graph (domain): their "
                                      "/diagnostics, ~/modes, parameters and state files collide; give each a "
                                      "name or namespace of its own (-r __node:=... or -r __ns:=...)")
            return True
        return False

    def last_words(self, level: str, text: str, wait_s: float = FATAL_WAIT_S) -> bool:
        """``text`` on /rosout at ``level`` before the process ends (:mod:`.rosout`); True when a reader got it."""
        return publish_last_words(self, self._rosout, level, text, wait_s=wait_s)

    def close(self) -> None:
        """Stop the worker and save the state once; called on shutdown."""
        self._stop_worker()
        if not self._closed:
            self._closed = True
            self.save_state()


class Spun(Protocol):
    """What :func:`spin` records on the node it spins (:class:`MonitorNode`, ``JointGroupNode``): its
    :class:`.channel.Activity` and its stalls."""

    activity: Activity

    def note_stall(self, start_ns: int, end_ns: int) -> None: ...


def spin(node: Spun, executor: Executor, started_ns: int, stop: StopFlag) -> None:
    """``spin_once`` loop until ``stop`` is set (see the module docstring); records when the executor was idle
    (input pause checks) and when it did not run (the node's own stalls, from ``started_ns``: start-up counts as
    one)."""
    last = started_ns
    act = node.activity
    act.looking_since_ns = 0
    while rclpy.ok() and not stop.is_set():
        t0 = time.monotonic_ns()
        if t0 - last > STALL_NS:
            node.note_stall(last, t0)
            act.looking_since_ns = t0
        elif not act.looking_since_ns:
            act.looking_since_ns = t0
        executor.spin_once(timeout_sec=0.05)
        t1 = time.monotonic_ns()
        if t1 - t0 > STALL_NS + 50_000_000:
            node.note_stall(t0, t1)
            act.looking_since_ns = t1
        if t1 - t0 >= 40_000_000:
            act.idle_since_ns = t1
        last = t1
