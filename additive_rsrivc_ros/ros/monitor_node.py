"""``MonitorNode``: the ROS 2 lifecycle node that runs :class:`MonitorPipeline` on live r, u, y topics.

A thin shell of small parts (docs/ARCHITECTURE.md): :mod:`.params` (declaration, runtime changes), :mod:`.inputs`
(topics, callbacks that only queue), :mod:`.worker` (the thread that aligns the streams with :mod:`.sync` or
:mod:`.blocks` and feeds the pipeline in blocks), :mod:`.publishing` (``~/modes``, ``/diagnostics``), :mod:`.state`
(``state_file``). The executor is ``rclpy.experimental.EventsExecutor`` driven by ``spin_once`` (:func:`spin`; its
``spin()`` starves Python timers and threads in this rclpy build), because the default executor loses Float64 messages
above ~1 kHz. ``configure`` checks the parameters (one-line rejection), loads the kernels, restores or builds the
pipeline and creates the interfaces; ``activate`` / ``deactivate`` start and stop the threads; ``cleanup`` and
``shutdown`` save the state.
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

from ..config import DEFAULT_NODE_NAME, MonitorConfig, ParamError, param_table
from ..core.pipeline import MonitorPipeline, PipelineError
from ..signal_stop import StopFlag
from ..warmup import is_warm, load_kernels
from .inputs import InputsMixin, signal_names
from .params import ParametersMixin, checked_config, split_unknown, unknown_warning
from .publishing import PublishingMixin
from .rosout import FATAL_WAIT_S, last_words_publisher, one_line_error, publish_last_words
from .state import StateMixin
from .sync import InputSync
from .worker import STALL_NS, WorkerMixin


class MonitorNode(ParametersMixin, InputsMixin, StateMixin, WorkerMixin, PublishingMixin, LifecycleNode):
    """Managed node around :class:`MonitorPipeline`; see the module docstring."""

    _active: bool                      # activated: inputs are taken, outputs published
    idle_since_ns: int                 # the executor's last wait without work (spin)
    looking_since_ns: int              # start of the executor's current uninterrupted run (0: not yet)

    def __init__(self, node_name: str = DEFAULT_NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._table = param_table()
        self._rosout = last_words_publisher(self)
        try:
            self._declare_all()
        except Exception as exc:            # the node ends here: say why on /rosout too (the caller prints it)
            self.last_words("fatal", one_line_error(exc))
            raise
        self.add_pre_set_parameters_callback(self._pre_set)
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._post_set)
        self.lock = threading.RLock()
        self.pipeline: MonitorPipeline | None = None
        self.cfg: MonitorConfig | None = None
        self.sync: InputSync | None = None
        self.signals: tuple[str, ...] = ()
        self.topics: dict[str, str] = {}
        self.config_error = ""
        self._active = False
        self._subs: list[Any] = []
        self._srvs: list[Any] = []
        self._modes_pub = None
        self._modes_stamped_pub = None
        self._diag_pub = None
        self._worker: threading.Thread | None = None
        self._stop = threading.Event()
        self.idle_since_ns = 0
        self.looking_since_ns = 0          # start of the executor's current uninterrupted run (0: not yet)
        self._pub_thread: threading.Thread | None = None
        self._save_path = ""               # where save_state writes ("" -> the state_file parameter)
        self._closed = False
        self._reset_stats()

    # ------------------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Check the parameters, build (or restore) the pipeline and create the interfaces; FAILURE with one log
        line (and :attr:`config_error`) when the configuration is rejected."""
        unknown, foreign = split_unknown(self._parameter_overrides, self._table)
        if foreign:
            self.get_logger().warning(unknown_warning(foreign, self._table))
        try:
            if unknown:
                raise ParamError(f"unknown parameter(s): {', '.join(unknown)}")
            values, cfg = checked_config(self.values())
        except (ParamError, ValueError) as exc:
            return self._reject(exc)
        if cfg.block_input:       # block rows are paired by index: the pipeline's stream aligner stays off
            cfg = cfg.with_block_input()
        self.cfg = cfg
        self._load_kernels()
        pipeline = self._restore(cfg, values["state_file"])
        try:
            self.pipeline = pipeline or MonitorPipeline(cfg)
            self.signals = signal_names(cfg)
            self.topics = self._resolve_topics(cfg)
        except (PipelineError, ValueError) as exc:
            return self._reject(exc)
        self._configure_runtime(cfg, values)
        try:
            qos_text = self._subscribe(cfg, values)
        except ParamError as exc:
            self._destroy_interfaces()
            return self._reject(exc)
        self._create_outputs()
        sync = self.configured_sync()
        self.get_logger().info(
            f"configured: K={cfg.K or 'from the data'}, {cfg.loop_rate_hz:g} Hz, "
            f"{'closed' if cfg.closed_loop else 'open'} loop, "
            f"inputs {', '.join(self.topics[s] for s in self.signals)} ({sync.pairing}), QoS {qos_text}, input "
            f"queues bounded at {sync.max_queue} samples per topic (<= {sync.queue_bytes() / 1e6:.3g} MB)")
        self.warn_duplicate_name()       # again after activation, once discovery has seen the graph
        return TransitionCallbackReturn.SUCCESS

    def _reject(self, exc: Exception) -> TransitionCallbackReturn:
        self.config_error = str(exc)
        self.get_logger().error(f"configuration rejected: {exc}")
        return TransitionCallbackReturn.FAILURE

    def _create_outputs(self) -> None:
        self._modes_pub = self.create_lifecycle_publisher(Float64MultiArray, "~/modes", 10)
        self._modes_stamped_pub = self.create_lifecycle_publisher(PointCloud2, "~/modes_stamped", 10)
        self._diag_pub = self.create_lifecycle_publisher(DiagnosticArray, "/diagnostics", 10)
        self._srvs = [self.create_service(Trigger, "~/reset", self._srv_reset),
                      self.create_service(Trigger, "~/rebaseline", self._srv_rebaseline),
                      self.create_service(Trigger, "~/save_state", self._srv_save)]

    def _load_kernels(self) -> None:
        """numba's one-time start (1-2 s, or a compilation without the cache) before any data, not mid-stream."""
        if not is_warm():
            self.get_logger().warning("the numba kernels of this version are not cached yet: compiling them now "
                                      "(once, about a minute; run rsrivc_warmup after installing to avoid this)")
        seconds = load_kernels()
        self.get_logger().info(f"kernels loaded in {seconds:.2f} s")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop.clear()
        self._active = True
        self._worker = threading.Thread(target=self._run_worker, name="rsrivc_worker", daemon=True)
        self._worker.start()
        self._pub_thread = threading.Thread(target=self._run_publisher, name="rsrivc_publisher", daemon=True)
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
        for p in (self._modes_pub, self._modes_stamped_pub, self._diag_pub):
            if p is not None:
                self.destroy_lifecycle_publisher(p)
        self._subs, self._srvs, self._modes_pub, self._diag_pub = [], [], None, None
        self._modes_stamped_pub = None
        self.pipeline = self.sync = None

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
    """What :func:`spin` records on the node it spins (:class:`MonitorNode`, ``JointGroupNode``)."""

    idle_since_ns: int
    looking_since_ns: int

    def note_stall(self, start_ns: int, end_ns: int) -> None: ...


def spin(node: Spun, executor: Executor, started_ns: int, stop: StopFlag) -> None:
    """``spin_once`` loop until ``stop`` is set (see the module docstring); records when the executor was idle
    (input pause checks) and when it did not run (the node's own stalls, from ``started_ns``: start-up counts as
    one)."""
    last = started_ns
    node.looking_since_ns = 0
    while rclpy.ok() and not stop.is_set():
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
