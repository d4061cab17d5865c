"""The parts of one monitor channel, wired together: owned by :class:`.monitor_node.MonitorNode` (a node of its own)
and by each :class:`.joint_channel.JointChannel` (one joint of :class:`.joint_group.JointGroupNode`).

Each part receives in its constructor exactly the shared state it uses (:mod:`.channel`): :class:`.state.StateStore`
(``state_file``, services), :class:`.inputs.Inputs` (input stage, subscriptions, callbacks),
:class:`.worker.Worker` (the estimation steps), :class:`.publishing.Publisher` (``~/modes``, ``/diagnostics``) and
:class:`.params.RuntimeChanges` (runtime parameter changes). What differs between a node and a joint comes in as
callables: the graph check and extra estimator-status values.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from ..config import MonitorConfig, Param
from ..core.monitor.pipeline import MonitorPipeline
from .channel import ChannelContext, ChannelCore, ChannelSettings, ChannelStats, Outbox
from .inputs import Inputs, signal_names
from .params import RuntimeChanges
from .publishing import Outputs, Publisher
from .state import StateStore
from .worker import Worker


class ChannelParts:
    """One channel's shared state and parts; see the module docstring."""

    def __init__(self, ctx: ChannelContext, table: Mapping[str, Param], *, check_graph: Callable[[], None],
                 extra_values: Callable[[], dict[str, Any]] | None = None) -> None:
        self.ctx = ctx
        self.core = ChannelCore()
        self.settings = ChannelSettings()
        self.stats = ChannelStats()
        self.outbox = Outbox()
        self.outputs = Outputs()
        self.state = StateStore(ctx, self.core)
        self.inputs = Inputs(ctx, self.core, self.stats)
        self.worker = Worker(ctx, self.core, self.settings, self.stats, self.outbox, check_graph)
        self.publisher = Publisher(ctx, self.core, self.settings, self.stats, self.outbox, self.outputs,
                                   extra_values)
        self.runtime = RuntimeChanges(ctx, self.core, self.settings, table)

    def build_pipeline(self, cfg: MonitorConfig, state_file: str) -> None:
        """The configuration and the pipeline, restored from ``state_file`` when it fits (PipelineError /
        ValueError when the configuration cannot build one); the signals of the configuration."""
        core = self.core
        core.cfg = cfg
        pipeline = self.state.restore(cfg, state_file)
        core.pipeline = pipeline or MonitorPipeline(cfg)
        core.signals = signal_names(cfg)

    def configure_runtime(self, cfg: MonitorConfig, values: Mapping[str, Any]) -> None:
        """The input stage and the worker/publisher periods of a configuration; statistics start afresh."""
        core, st = self.core, self.settings
        sync = core.sync = self.inputs.make_sync(cfg, values)
        st.use_sim_time = bool(self.ctx.parameter("use_sim_time"))
        t_last = core.configured_pipeline().t_last
        if t_last is not None:
            sync.set_time_floor(t_last)
        st.stale_timeout_s = values["stale_timeout_s"]
        st.publish_period_s = 1.0 / cfg.publish_rate_hz
        st.diag_period_s = values["diagnostics_period_s"]
        st.hardware_id = values["hardware_id"]
        st.block_period_s = values["block_period_s"]
        st.block_batch_s = values["block.batch_s"]
        self.reset_stats()

    def reset_stats(self) -> None:
        """Statistics, reports and the worker's and publisher's own timing start afresh."""
        self.stats.reset()
        self.outbox.reset()
        self.worker.reset()
        self.publisher.reset()

    def unconfigure(self) -> None:
        """No pipeline, no input stage (cleanup: the interfaces are gone)."""
        self.core.pipeline = self.core.sync = None
