"""Damaged copies of a record as real rosbag2 files: duplicated samples, NaNs, absurd values, a pause.

``write_stamped_bag`` writes Float64 topics with arbitrary log times (``bagio.write_bag`` spaces them evenly);
``damage`` applies one kind of damage to ``(t_ns, r, u, y)``. Used by test_offline_robustness.py and by hand:

    python -c "from test.bag_variants import *; ..."
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TOPICS = (("reference", "/reference"), ("input", "/plant_input"), ("output", "/plant_output"))


def write_stamped_bag(path: str | Path, t_ns: np.ndarray, r: np.ndarray | None, u: np.ndarray,
                      y: np.ndarray) -> Path:
    """An MCAP bag with /reference (if ``r``), /plant_input, /plant_output at log times ``t_ns`` (int ns)."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    from additive_rsrivc_ros.io.bagio import float64_cdr

    ts = get_typestore(Stores.ROS2_JAZZY)
    path = Path(path)
    t_list = [int(v) for v in np.asarray(t_ns, np.int64)]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = [(w.add_connection(topic, "std_msgs/msg/Float64", typestore=ts), float64_cdr(x))
                 for (_, topic), x in zip(TOPICS, (r, u, y), strict=True) if x is not None]
        for k, t in enumerate(t_list):      # interleaved in time order, as a recorder writes them
            for c, data in conns:
                w.write(c, t, data[k])
    return path


def damage(kind: str, t_ns: np.ndarray, r: np.ndarray | None, u: np.ndarray, y: np.ndarray, rate_hz: float,
           at_s: float = 12.0) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """One kind of damage at ``at_s`` seconds:

    * ``duplicate_stamp``: sample k recorded twice with the same stamp (a recorder duplicate);
    * ``held``: sample k repeated on the next stamp, the rest one sample later (a lost sample held by the receiver);
    * ``nan40``: 40 output samples NaN, spread over 1 s;
    * ``huge``: one output sample 1e300;
    * ``pause``: the samples after ``at_s`` arrive 2 s later (the loop paused, nothing recorded).
    """
    k = int(round(at_s * rate_hz))
    h_ns = int(round(1e9 / rate_hz))
    t, u, y = t_ns.copy(), u.copy(), y.copy()
    r = None if r is None else r.copy()
    if kind == "duplicate_stamp":
        ins = lambda x: None if x is None else np.insert(x, k + 1, x[k])  # noqa: E731
        return ins(t), ins(r), ins(u), ins(y)
    if kind == "held":
        ins = lambda x: None if x is None else np.insert(x, k + 1, x[k])  # noqa: E731
        t = t[0] + h_ns * np.arange(t.size + 1, dtype=np.int64)
        return t, ins(r), ins(u), ins(y)
    if kind == "nan40":
        y[k + np.arange(40) * max(1, int(rate_hz // 40))] = np.nan
    elif kind == "huge":
        y[k] = 1e300
    elif kind == "pause":
        t[k:] += 2 * 10**9
    else:
        raise ValueError(kind)
    return t, r, u, y


def write_topics(path, streams: dict[str, tuple[np.ndarray, np.ndarray]]):
    """A bag with Float64 topics given as (log times ns, values), as a recorder would have stored them."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from additive_rsrivc_ros.io.bagio import _typestore, float64_cdr
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {topic: w.add_connection(topic, "std_msgs/msg/Float64", typestore=_typestore()) for topic in streams}
        rows = sorted((int(t), topic, k) for topic, (ts, _) in streams.items() for k, t in enumerate(ts))
        payload = {topic: float64_cdr(v) for topic, (_, v) in streams.items()}
        for t, topic, k in rows:
            w.write(conns[topic], t, payload[topic][k])
    return path
