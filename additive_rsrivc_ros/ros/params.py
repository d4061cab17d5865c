"""Parameters of the monitor node: declared from the table in ``config.py``, checked, changed at runtime.

Parameters the node does not know are warned about in one line unless they lie in one of its own groups
(``modes.*`` ...: a misspelling, rejected), so a shared ``/**`` params file works. A missing ``loop_rate_hz``
names the params-file keys that would reach this node. A runtime change is validated as a whole (the same checks
as at configuration) and applied to the pipeline (``modes.memory_s``, ``publish_rate_hz``, ``faults.*``), the
publisher periods and the input stage (:meth:`.sync.InputSync.update`, with the floors of start-up).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..config import MonitorConfig, Param, ParamError, all_params, validate_params
from ..core.diagnosis.faults import FaultSettings
from ..core.monitor.pipeline import PipelineError
from . import convert as cv
from . import sync as input_sync
from .channel import ChannelContext, ChannelCore, ChannelSettings

ALLOWED_EXTRA_PARAMS = ("use_sim_time", "start_type_description_service")
REQUIRED_PARAMS = ("loop_rate_hz",)     # no usable default: absent means the params file did not reach the node
PIPELINE_RUNTIME = ("modes.memory_s", "publish_rate_hz")   # with faults.*: changed in the running pipeline


def split_unknown(names: Iterable[str], known: Iterable[str]) -> tuple[list[str], list[str]]:
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


def unknown_warning(names: list[str], known: Iterable[str]) -> str:
    """One log line about parameters the monitor ignores (with the closest own name when one is close)."""
    parts = []
    for n in names:
        close = difflib.get_close_matches(n, list(known), 1, 0.85)
        parts.append(f"{n} (did you mean {close[0]}?)" if close else n)
    return f"ignoring parameter(s) this node does not use (another node's, in a shared section?): {', '.join(parts)}"


def missing_required(name: str, fqn: str, given: Iterable[str], known: Iterable[str]) -> str:
    """One-line error for a required parameter that no params section gave to the node ``fqn``."""
    ns, _, base = fqn.rpartition("/")
    own = [n for n in given if n in set(known) and n not in ("autostart",)]
    if own:
        return f"parameter '{name}' is required (the params for node '{fqn}' do not set it)"
    keys = (f"/**/{base}", fqn) if ns else (base, f"/**/{base}")
    return (f"parameter '{name}' is required (no params for node '{fqn}': the YAML key must be '{keys[0]}' or "
            f"'{keys[1]}')")


def check_sync_params(v: Mapping[str, Any]) -> None:
    """sync.max_queue_s must exceed the stall and backlog allowances (ParamError, one line)."""
    q = v["sync.max_queue_s"]
    if q <= v["sync.stall_s"] or q <= 2 * v["sync.max_backlog_s"]:
        raise ParamError(f"sync.max_queue_s ({q:g}) must exceed sync.stall_s ({v['sync.stall_s']:g}) and "
                         f"2 x sync.max_backlog_s ({v['sync.max_backlog_s']:g})")


def checked_config(values: Mapping[str, Any], *, strict: bool = True) -> tuple[dict[str, Any], MonitorConfig]:
    """Validated parameter values and the configuration they give; ParamError / ValueError (one line) when the
    values, the fault settings for the configured modes or the sync allowances do not fit."""
    valid = validate_params(values, strict=strict)
    cfg = MonitorConfig.from_params(valid)
    FaultSettings.from_params(valid).check(cfg.K)
    check_sync_params(valid)
    return valid, cfg


class ParamsHandler:
    """A monitor node's parameters: declaration from the table, values, and the checks of a runtime change (the
    node's parameter callbacks); an accepted change goes to ``runtime`` (:class:`RuntimeChanges`)."""

    def __init__(self, node: Node, table: dict[str, Param], runtime: RuntimeChanges) -> None:
        self.node = node
        self.table = table
        self.runtime = runtime

    def declare_all(self) -> None:
        """Declare every Param row with its descriptor; integer YAML values of double params are coerced. A
        required parameter nobody gave raises ParamError naming it and the params-file key (one line)."""
        node, table = self.node, self.table
        overrides = node._parameter_overrides
        for name in REQUIRED_PARAMS:
            if name not in overrides:
                raise ParamError(missing_required(name, node.get_fully_qualified_name(), overrides, table))
        for name, ov in list(overrides.items()):
            if name in table:
                overrides[name] = cv.coerce_int_to_double(table[name], ov)
        for p in all_params():
            if isinstance(p.default, list) and not p.default:
                # an empty list has no inferable type: declare typed, then give it the typed empty default
                node.declare_parameter(p.name, cv.PARAM_TYPE[p.type], cv.descriptor(p))
                if node.get_parameter_or(p.name).type_ == Parameter.Type.NOT_SET:
                    node._parameters[p.name] = Parameter(p.name, cv.PARAM_TYPE[p.type], [])
            else:
                node.declare_parameter(p.name, p.default, cv.descriptor(p))

    def install(self) -> None:
        """The node's pre-set, on-set and post-set parameter callbacks."""
        self.node.add_pre_set_parameters_callback(self.pre_set)
        self.node.add_on_set_parameters_callback(self.on_set)
        self.node.add_post_set_parameters_callback(self.runtime.apply)

    def value(self, name: str) -> Any:
        """The current value of the node's parameter ``name``."""
        return self.node.get_parameter(name).value

    def values(self) -> dict[str, Any]:
        """Current parameter values, flat ``{name: plain value}``."""
        return {name: cv.plain(self.node.get_parameter(name).value) for name in self.table}

    def pre_set(self, params: list[Parameter]) -> list[Parameter]:
        return [cv.coerce_int_to_double(self.table[p.name], p) if p.name in self.table else p for p in params]

    def on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Accept a change only when the whole parameter set with it passes the configuration checks."""
        cand = self.values()
        for p in params:
            if p.name in self.table:
                cand[p.name] = cv.plain(p.value)
        try:
            checked_config(cand, strict=False)
        except (ParamError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=f"rejected: {exc}")
        return SetParametersResult(successful=True)


class RuntimeChanges:
    """Applies an accepted parameter change to a running channel: pipeline settings, publisher periods, the input
    stage (a part of :class:`.channel_parts.ChannelParts`)."""

    def __init__(self, ctx: ChannelContext, core: ChannelCore, settings: ChannelSettings,
                 table: Mapping[str, Param]) -> None:
        self.ctx = ctx
        self.core = core
        self.settings = settings
        self.table = table

    def apply(self, params: list[Parameter]) -> None:
        """Apply an accepted change: pipeline settings, publisher periods, the input stage."""
        changed = {p.name: cv.plain(p.value) for p in params if p.name in self.table}
        runtime = {k: v for k, v in changed.items() if k in PIPELINE_RUNTIME or k.startswith("faults.")}
        core, st, log = self.core, self.settings, self.ctx.logger
        with core.lock:
            if core.pipeline is not None and runtime:
                try:
                    core.pipeline.update_params(runtime)
                except PipelineError as exc:   # validated before; keep running and say so
                    log.error(f"runtime parameter change not applied: {exc}")
                else:
                    log.info("applied " + ", ".join(f"{k}={v}" for k, v in runtime.items()))
            if "publish_rate_hz" in changed:
                st.publish_period_s = 1.0 / float(changed["publish_rate_hz"])
            if "diagnostics_period_s" in changed:
                st.diag_period_s = float(changed["diagnostics_period_s"])
            if "stale_timeout_s" in changed:
                st.stale_timeout_s = float(changed["stale_timeout_s"])
            if core.sync is not None and core.cfg is not None:
                core.sync.update(**input_sync.settings(changed, core.cfg.loop_rate_hz))
