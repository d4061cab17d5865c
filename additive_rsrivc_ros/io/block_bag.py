"""Bags recorded on a block topic: ``Float64MultiArray`` rows ``index, reference, input, output`` -> samples.

The rows pass through the node's own :class:`.ros.blocks.BlockSync` (ROS-free) with each message's log time as its
arrival, so a bag is read exactly as the live node would have read the topic: samples timed by the controller's
index, duplicates dropped, a missing index a gap, a conflicting one a controller restart, malformed blocks counted.
``loop_rate_hz`` is checked against the rate at which the index advances over the log time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..config import MonitorConfig
from ..ros.blocks import BlockSync, block_rows

RATE_TOLERANCE = 0.02    # relative disagreement of the index rate (over log time) with loop_rate_hz


def block_samples(path: Path, config: MonitorConfig, messages: list[tuple[int, Any]],
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray, dict[str, int]]:
    """``(t_ns, r, u, y, counters)`` from ``(log time ns, deserialized message)`` pairs in log-time order.

    Raises ``ValueError`` (one line) when no valid row is found or when the index advances at a rate that
    contradicts ``loop_rate_hz`` (every frequency would be off by that factor)."""
    topic = str(config.params["block.topic"])
    reorder_s = float(config.params.get("block.reorder_s", 0.05))
    sync = BlockSync(config.loop_rate_hz, closed_loop=config.closed_loop, label=topic, convert=block_rows,
                     reorder_s=reorder_s, controller=config.controller if config.closed_loop else None)
    parts = []
    origin = messages[0][0] if messages else 0    # times in s relative to the first block: float64 keeps ns
    for log_ns, msg in messages:
        sync.enqueue(msg, log_ns)
        got = sync.collect(log_ns, ros_now_s=(log_ns - origin) * 1e-9)
        if got is not None:
            parts.append(got)
    if messages:
        last_ns = messages[-1][0]
        got = sync.flush(last_ns, (last_ns - origin) * 1e-9)
        if got is not None:
            parts.append(got)
    counters = dict(sync.block)
    if not parts:
        why = f" ({sync.last_malformed})" if sync.last_malformed else ""
        raise ValueError(f"{path}: block topic '{topic}' holds no valid row{why}")
    t = np.concatenate([p.t for p in parts])
    r = np.concatenate([p.r for p in parts]) if config.closed_loop else None
    u = np.concatenate([p.u for p in parts])
    y = np.concatenate([p.y for p in parts])
    _check_index_rate(path, topic, config.loop_rate_hz, messages, sync)
    return origin + np.round(t * 1e9).astype(np.int64), r, u, y, counters


def _check_index_rate(path: Path, topic: str, rate_hz: float, messages: list[tuple[int, Any]],
                      sync: BlockSync) -> None:
    """The controller's index advances at ``loop_rate_hz`` over the log time (the record's clock): the rows logged
    between the first and the last block, over the time between them."""
    ends = []
    for log_ns, msg in messages:
        rows, err = block_rows(msg)
        if rows is not None and not err:
            ends.append((log_ns, float(rows[-1, 0])))
    if len(ends) < 3 or sync.block["restarts"]:
        return                  # too few blocks to judge, or the index restarted within the record
    span_s = (ends[-1][0] - ends[0][0]) * 1e-9
    if span_s <= 0.0:
        return
    measured = (ends[-1][1] - ends[0][1]) / span_s
    if abs(measured / rate_hz - 1.0) > RATE_TOLERANCE:
        raise ValueError(f"{path}: loop_rate_hz {rate_hz:g} disagrees with the data's timing: the index on '{topic}' "
                         f"advances at {measured:.6g} Hz of log time")
