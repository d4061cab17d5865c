"""Parameters of ``rsrivc_joints``: one node monitoring N joints, shared values and one section per joint (ROS-free).

The node reads the list ``joints`` and, for every parameter of the monitor's table (config.py), a shared value at the
top level and optionally a joint's own value under ``<joint>.`` (like a ros2_control controller's ``joints`` list and
per-joint gains; docs/joints.md has an example). A joint's effective parameters are the table defaults, then the
shared values, then its own section. Differences to ``rsrivc_monitor`` (:data:`JOINT_DEFAULTS`): the signals are
``sensor_msgs/JointState`` by default (reference = ``joint_commands`` position, input = ``joint_states`` effort,
output = ``joint_states`` position), and a signal's ``joint`` is the joint's own name unless its section says
otherwise (``elbow.output.joint: elbow_joint``). Parameters of the node as a whole (:data:`GROUP_ONLY`) have no
per-joint value. A joint with ``block.topic`` reads block input (rows ``index, reference, input, output``) instead.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Mapping
from typing import Any

from .config import ParamError, param_table

JOINT_GROUP_NODE_NAME = "additive_rsrivc_joints"
JOINT_STATE = "sensor_msgs/msg/JointState"
GROUP_ONLY = ("autostart", "qos_depth", "qos_reliable", "block_period_s", "use_sim_time")
# the group's own defaults where they differ from rsrivc_monitor's (signals from shared JointState topics; a worker
# period that lets one thread feed N pipelines in blocks)
JOINT_DEFAULTS: dict[str, Any] = {
    "reference.topic": "joint_commands", "reference.type": JOINT_STATE, "reference.field": "position",
    "input.topic": "joint_states", "input.type": JOINT_STATE, "input.field": "effort",
    "output.topic": "joint_states", "output.type": JOINT_STATE, "output.field": "position",
    "block_period_s": 0.05,
}
PER_JOINT_ONLY = ("reference.joint", "input.joint", "output.joint")   # default: the joint's name
NODE_EXTRA = ("use_sim_time", "start_type_description_service")      # rclpy's own parameters
SIGNALS = ("reference", "input", "output")
_TOKEN = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def table_groups() -> set[str]:
    """First dotted parts of the table's names (``modes``, ``faults``, ...): no joint may be called so."""
    return {n.split(".", 1)[0] for n in param_table()}


def check_joint_names(joints: Any) -> list[str]:
    """The ``joints`` list, checked: non-empty, unique, ROS name tokens, none a parameter group (ParamError)."""
    if not isinstance(joints, list | tuple) or not joints or not all(isinstance(j, str) for j in joints):
        raise ParamError("parameter 'joints' is required: the list of joint names to monitor (string[], e.g. "
                         "[shoulder, elbow])")
    dup = sorted({j for j in joints if list(joints).count(j) > 1})
    if dup:
        raise ParamError(f"parameter 'joints' names {', '.join(dup)} more than once")
    bad = [j for j in joints if not _TOKEN.match(j)]
    if bad:
        raise ParamError(f"parameter 'joints': {', '.join(repr(b) for b in bad)} is not a valid name (letters, digits, "
                         "'_', starting with a letter; map another message name with <joint>.output.joint)")
    clash = sorted(set(joints) & (table_groups() | set(param_table())))
    if clash:
        raise ParamError(f"parameter 'joints': {', '.join(clash)} is the name of a parameter group; rename the joint "
                         "(and map the message's name with <joint>.output.joint)")
    return list(joints)


def monitored_joints(joints: list[str], subset: list[str], count: int) -> list[str]:
    """The joints monitored: ``monitor_joints`` (a subset of ``joints``, in its order; empty: all of ``joints``), then
    the first ``joint_count`` of them (0: all). ParamError (one line) for a name not in ``joints`` or a count beyond."""
    unknown = [j for j in subset if j not in joints]
    if unknown:
        raise ParamError(f"parameter 'monitor_joints': {', '.join(unknown)} not in 'joints' [{', '.join(joints)}]")
    chosen = list(dict.fromkeys(subset)) if subset else list(joints)
    if count < 0 or count > len(chosen):
        raise ParamError(f"parameter 'joint_count' = {count} but {len(chosen)} joint(s) are listed")
    return chosen[:count] if count else chosen


def split_given(given: Mapping[str, Any], joints: Iterable[str]) -> tuple[dict[str, Any], dict[str, dict[str, Any]],
                                                                          list[str]]:
    """Given parameter values -> (shared, per joint, names to warn about). ParamError (one line) for a joint's value
    of a group-only parameter, a per-joint-only parameter at the top level, a misspelt own parameter or a section of
    an unknown joint."""
    table = param_table()
    joints = list(joints)
    shared: dict[str, Any] = {}
    own: dict[str, dict[str, Any]] = {j: {} for j in joints}
    foreign: list[str] = []
    groups = table_groups()
    for name, value in given.items():
        head, _, rest = name.partition(".")
        if name in ("joints", "monitor_joints", "joint_count", *NODE_EXTRA) or name.startswith("qos_overrides."):
            continue
        if name in table:
            if name in PER_JOINT_ONLY:
                raise ParamError(f"parameter '{name}' is per joint: set it as <joint>.{name} (default: the joint's "
                                 "own name)")
            shared[name] = value
        elif head in own and rest:
            if rest in GROUP_ONLY:
                raise ParamError(f"parameter '{name}': {rest} is one value for the whole node (set it without "
                                 f"'{head}.')")
            if rest not in table:
                close = difflib.get_close_matches(rest, list(table), 1, 0.85)
                hint = f" (did you mean {head}.{close[0]}?)" if close else ""
                raise ParamError(f"unknown parameter '{name}'{hint}")
            own[head][rest] = value
        elif rest in table or head in groups:
            close = difflib.get_close_matches(head, joints, 1, 0.6)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ParamError(f"parameter '{name}': '{head}' is not one of the joints [{', '.join(joints)}]{hint}"
                             if rest in table else f"unknown parameter '{name}'")
        else:
            foreign.append(name)
    return shared, own, foreign


def joint_values(joint: str, shared: Mapping[str, Any], own: Mapping[str, Any]) -> dict[str, Any]:
    """The given values of one joint (before table defaults): the group defaults, the shared values, its own."""
    out: dict[str, Any] = {**JOINT_DEFAULTS, **{f"{s}.joint": joint for s in SIGNALS}}
    out.update(shared)
    out.update(own)
    return out


def check_group(values: Mapping[str, Mapping[str, Any]]) -> None:
    """Cross-joint checks on the validated values of every joint (ParamError, one line): one ``loop_rate_hz`` source
    is not required, but two joints must not share a block topic or a state file, and every signal is JointState
    unless the joint reads block input."""
    seen: dict[tuple[str, str], str] = {}
    for joint, v in values.items():
        if not v["block.topic"]:
            wrong = [s for s in SIGNALS if v[f"{s}.type"] != JOINT_STATE and (s != "reference" or v["closed_loop"])]
            if wrong:
                raise ParamError(f"joint '{joint}': {wrong[0]}.type must be {JOINT_STATE} (rsrivc_joints reads shared "
                                 "JointState topics or a block topic per joint; rsrivc_monitor reads Float64 topics)")
        for key in ("block.topic", "state_file"):
            if v[key]:
                other = seen.setdefault((key, v[key]), joint)
                if other != joint:
                    raise ParamError(f"joints '{other}' and '{joint}' have the same {key} '{v[key]}': give each "
                                     f"joint its own ({joint}.{key})")


def joint_param_name(joint: str, name: str) -> str:
    """``<joint>.<name>``: a joint's own parameter."""
    return f"{joint}.{name}"
