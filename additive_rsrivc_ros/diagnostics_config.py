"""diagnostic_aggregator analyzers for monitors in several namespaces (ROS-free; ``launch/multi_axis.launch.py``
starts the aggregator with them, ``config/diagnostic_aggregator.yaml`` is the same for ``axis1``, ``axis2``).

A monitor's /diagnostics statuses are named ``<prefix>: mode <i>`` and ``<prefix>: estimator``, ``<prefix>`` being
the node's full name without its leading '/' (``axis1/additive_rsrivc_monitor``; the node name alone in the root
namespace: ``ros/publishing.status_prefix``). One GenericAnalyzer per axis under one AnalyzerGroup gives each axis
its own branch (``Resonance monitor/axis1`` ...), so a fault of one axis shows under that axis only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .config import DEFAULT_NODE_NAME

GROUP_KEY = "resonance_monitor"
GROUP_PATH = "Resonance monitor"
AGGREGATOR_NODE = "analyzers"          # diagnostic_aggregator's aggregator_node: its node name and params key


def status_prefix(namespace: str, node_name: str = DEFAULT_NODE_NAME) -> str:
    """The status-name prefix of the monitor ``node_name`` in ``namespace`` ('' or '/' = root)."""
    ns = namespace.strip("/")
    return f"{ns}/{node_name}" if ns else node_name


def analyzer_key(namespace: str) -> str:
    """A parameter-name-safe key for one axis's analyzer (``left/arm`` -> ``left_arm``; root -> ``root``)."""
    return namespace.strip("/").replace("/", "_") or "root"


def aggregator_params(axes: Sequence[str], node_name: str = DEFAULT_NODE_NAME, timeout_s: float = 5.0,
                      modes: int = 0) -> dict[str, Any]:
    """The aggregator node's ``ros__parameters``: one branch per namespace of ``axes`` (path = the namespace) with
    that monitor's statuses, the prefix removed; ``modes`` > 0 lists its estimator and modes 1..``modes`` as
    ``expected`` (a missing one is reported). A status unseen for ``timeout_s`` turns STALE."""
    analyzers: dict[str, Any] = {}
    for ns in axes:
        prefix = status_prefix(ns, node_name)
        entry: dict[str, Any] = {"type": "diagnostic_aggregator/GenericAnalyzer", "path": ns.strip("/") or "root",
                                 "startswith": [f"{prefix}:"], "remove_prefix": [f"{prefix}: "],
                                 "timeout": float(timeout_s)}
        if modes > 0:
            entry["expected"] = [f"{prefix}: estimator", *(f"{prefix}: mode {i}" for i in range(1, modes + 1))]
        analyzers[analyzer_key(ns)] = entry
    return {"path": "Aggregation",
            GROUP_KEY: {"type": "diagnostic_aggregator/AnalyzerGroup", "path": GROUP_PATH, "analyzers": analyzers}}
