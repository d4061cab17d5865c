"""rosbag2 (MCAP / sqlite3) reading and writing with ``rosbags`` 0.11; bag validation (docs/INTERFACE.md).

:func:`write_bag` writes one message per control sample, log time = sample time: ``/reference`` (closed loop),
``/plant_input``, ``/plant_output`` (``std_msgs/msg/Float64``); ``/truth/modes`` (``Float64MultiArray`` in the
``~/modes`` layout, std columns 0, the plant's modes with the estimated ones first) at ``truth_rate_hz``;
``/truth/fault`` (``std_msgs/msg/String``, one JSON object per change of the fault state: ``time_s``, ``event`` of
``start``, ``onset``, ``complete``, ``end``, ``fault``, ``active``). MCAP files carry the indexes Jazzy's rosbag2 needs;
no wall-clock time enters the files, so the same input gives the same bytes. :func:`read_signals` checks a bag before
use and raises :class:`BagError` with a one-line reason.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

from ..config import MonitorConfig
from ..core.estimation.estimator import SignalSettings
from ..core.vocabulary import one_line
from .timerange import ResolvedRange, TimeRange

FLOAT64 = "std_msgs/msg/Float64"
MULTIARRAY = "std_msgs/msg/Float64MultiArray"
STRING = "std_msgs/msg/String"
JOINTSTATE = "sensor_msgs/msg/JointState"
TRUTH_MODES_TOPIC = "/truth/modes"
TRUTH_FAULT_TOPIC = "/truth/fault"
DEFAULT_TOPICS = {"reference": "/reference", "input": "/plant_input", "output": "/plant_output"}
ERROR_CHARS = 300  # a reader's message quoted in a BagError is cut to this many characters
DEFAULT_T0_NS = 1_700_000_000 * 10**9  # fixed start time: bags are reproducible byte for byte
SIGNAL_QOS_DEPTH = 1000
SPACING_TOLERANCE = 0.002  # relative tolerance of the mean sample spacing against 1/loop_rate_hz (stated offline)

_CDR_LE = b"\x00\x01\x00\x00"  # CDR encapsulation header, little endian


@functools.cache
def _typestore() -> Any:
    """The ROS 2 Jazzy message types (imported on first use: a bag of Float64 signals read by the MCAP fast path
    needs none, and the type store costs about 0.2 s to import)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)

_ZERO_T = QosTime(0, 0)
_INF_T = QosTime(2147483647, 4294967295)  # rmw "infinite" duration as rosbag2 writes it


def _qos(history: QosHistory, depth: int, durability: QosDurability) -> Qos:
    return Qos(history, depth, QosReliability.RELIABLE, durability, _INF_T, _INF_T, QosLiveliness.AUTOMATIC,
               _INF_T, False)


SIGNAL_QOS = _qos(QosHistory.KEEP_LAST, SIGNAL_QOS_DEPTH, QosDurability.VOLATILE)
TRUTH_QOS = _qos(QosHistory.KEEP_ALL, 0, QosDurability.TRANSIENT_LOCAL)


class BagError(ValueError):
    """A bag that cannot be used; the message is one line naming the bag and the reason."""


@dataclass
class Signals:
    """Samples of a bag (docs/ARCHITECTURE.md). ``t`` is in s since the first output sample."""

    t: np.ndarray
    t0_ns: int
    r: np.ndarray | None
    u: np.ndarray
    y: np.ndarray
    truth_t: np.ndarray | None = None
    truth_modes: np.ndarray | None = None
    truth_fault: list | None = None
    nonfinite: int = 0
    nonfinite_by_signal: dict[str, int] = field(default_factory=dict)
    unmatched_by_signal: dict[str, int] = field(default_factory=dict)   # missing (NaN) + surplus, time alignment
    block: dict[str, int] = field(default_factory=dict)   # block-topic bags: the block counters (ros/blocks.py)
    storage: str = ""
    metadata: dict[str, str] = field(default_factory=dict)
    time_range: dict[str, Any] | None = None   # the range read (timerange.ResolvedRange.to_dict()); None: all

    @property
    def n(self) -> int:
        return int(self.t.size)


# ----------------------------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------------------------
def float64_cdr(values: np.ndarray) -> list[bytes]:
    """CDR bytes of ``std_msgs/msg/Float64`` messages (4-byte header + little-endian double), vectorized."""
    raw = np.ascontiguousarray(np.asarray(values, dtype="<f8")).view(np.uint8).reshape(-1, 8)
    return [_CDR_LE + row.tobytes() for row in raw]


def sample_times_ns(n: int, rate_hz: float, t0_ns: int = DEFAULT_T0_NS) -> np.ndarray:
    """Log times ``t0 + round(k * 1e9 / rate)`` (integer ns; exact for rates dividing 1e9)."""
    k = np.arange(n, dtype=np.int64)
    if float(rate_hz).is_integer() and 10**9 % int(rate_hz) == 0:
        return t0_ns + k * (10**9 // int(rate_hz))
    return t0_ns + np.rint(k * (1e9 / rate_hz)).astype(np.int64)


def truth_indices(n: int, rate_hz: float, truth_rate_hz: float) -> np.ndarray:
    """Samples nearest to ``j / truth_rate_hz`` (j = 0, 1, ...): where ``/truth/modes`` is published."""
    if not truth_rate_hz > 0:
        raise ValueError(f"truth_rate_hz must be > 0, got {truth_rate_hz}")
    j = np.arange(int(math.ceil(n / rate_hz * truth_rate_hz)) + 1)
    idx = np.unique(np.rint(j * (rate_hz / truth_rate_hz)).astype(np.int64))
    return idx[idx < n]


def _multiarray(values: np.ndarray) -> bytes:
    msgs = _typestore().types
    layout = msgs["std_msgs/msg/MultiArrayLayout"](
        dim=[msgs["std_msgs/msg/MultiArrayDimension"](label="mode", size=values.shape[0], stride=values.size),
             msgs["std_msgs/msg/MultiArrayDimension"](label="field", size=values.shape[1], stride=values.shape[1])],
        data_offset=0)
    msg = msgs[MULTIARRAY](layout=layout, data=np.ascontiguousarray(values, dtype=np.float64).ravel())
    return bytes(_typestore().serialize_cdr(msg, MULTIARRAY))


def _string(text: str) -> bytes:
    return bytes(_typestore().serialize_cdr(_typestore().types[STRING](data=text), STRING))


class _LittleCDR:
    """Reader of a little-endian CDR payload (alignment relative to the payload after the 4-byte header)."""

    def __init__(self, data: bytes) -> None:
        self.buf, self.pos = memoryview(data)[4:], 0

    def u32(self) -> int:
        self.pos = (self.pos + 3) & ~3
        if self.pos + 4 > len(self.buf):
            raise ValueError("truncated CDR message")
        v = int.from_bytes(self.buf[self.pos:self.pos + 4], "little")
        self.pos += 4
        return v

    def string(self) -> str:
        n = self.u32()    # length with the terminating NUL
        if n < 1 or self.pos + n > len(self.buf):
            raise ValueError("truncated CDR string")
        text = bytes(self.buf[self.pos:self.pos + n - 1]).decode("utf-8")
        self.pos += n
        return text

    def f64s(self) -> np.ndarray:
        n = self.u32()
        self.pos = (self.pos + 7) & ~7 if n else self.pos
        if self.pos + 8 * n > len(self.buf):
            raise ValueError("truncated CDR sequence")
        out = np.frombuffer(self.buf[self.pos:self.pos + 8 * n], dtype="<f8").astype(np.float64)
        self.pos += 8 * n
        return out


def _decode_multiarray(data: bytes) -> tuple[list[int], np.ndarray]:
    """``(dimension sizes, data)`` of a ``std_msgs/msg/Float64MultiArray``: little-endian CDR read directly (no
    type store import), any other encapsulation by the type store."""
    if data[:4] != _CDR_LE:
        msg = _typestore().deserialize_cdr(data, MULTIARRAY)
        return [int(d.size) for d in msg.layout.dim], np.asarray(msg.data, dtype=np.float64)
    rd = _LittleCDR(data)
    sizes = []
    for _ in range(rd.u32()):
        rd.string()                        # label
        sizes.append(rd.u32())             # size
        rd.u32()                           # stride
    rd.u32()                               # data_offset
    return sizes, rd.f64s()


def _decode_string(data: bytes) -> str:
    """``data`` of a ``std_msgs/msg/String`` (as :func:`_decode_multiarray`)."""
    if data[:4] != _CDR_LE:
        return str(_typestore().deserialize_cdr(data, STRING).data)
    return _LittleCDR(data).string()


def write_bag(path: str | Path, rate_hz: float, u: np.ndarray, y: np.ndarray, r: np.ndarray | None = None, *,
              truth_modal: np.ndarray | None = None, truth_rate_hz: float = 10.0,
              fault_events: Sequence[dict[str, Any]] = (), storage: str = "mcap", compress: bool = True,
              t0_ns: int = DEFAULT_T0_NS, topics: dict[str, str] | None = None,
              custom_data: dict[str, str] | None = None) -> Path:
    """Write one rosbag2 directory at ``path`` (must not exist) and return it.

    ``u``, ``y`` (and ``r`` in closed loop) are the samples at ``rate_hz``; ``truth_modal`` ``(K, N, 3)`` is the
    per-sample modal truth (f_hz, zeta, gain) published on ``/truth/modes`` every ``1/truth_rate_hz`` s;
    ``fault_events`` are JSON-serializable dicts with a ``time_s`` key, published on ``/truth/fault``.
    ``storage``: ``mcap`` (default; zstd chunk compression when ``compress``) or ``sqlite3``.
    """
    path = Path(path)
    u, y = np.asarray(u, dtype=np.float64), np.asarray(y, dtype=np.float64)
    n = u.size
    if u.ndim != 1 or y.shape != u.shape or (r is not None and np.shape(r) != u.shape):
        raise ValueError("r, u and y must be one-dimensional arrays of equal length")
    if n == 0:
        raise ValueError("cannot write an empty bag")
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
    topics = {**DEFAULT_TOPICS, **(topics or {})}
    ts = sample_times_ns(n, rate_hz, t0_ns)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    if compress and storage == "mcap":
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for key, value in sorted((custom_data or {}).items()):
        writer.set_custom_data(key, value)
    writer.open()
    try:
        streams: list[tuple[Any, np.ndarray, list[bytes]]] = []
        signals = [("reference", r), ("input", u), ("output", y)]
        for name, values in signals:
            if values is None:
                continue
            conn = writer.add_connection(topics[name], FLOAT64, typestore=_typestore(),
                                         offered_qos_profiles=[SIGNAL_QOS])
            streams.append((conn, ts, float64_cdr(np.asarray(values, dtype=np.float64))))
        if truth_modal is not None:
            truth_modal = np.asarray(truth_modal, dtype=np.float64)
            if truth_modal.ndim != 3 or truth_modal.shape[1:] != (n, 3):
                raise ValueError(f"truth_modal must have shape (K, {n}, 3), got {truth_modal.shape}")
            idx = truth_indices(n, rate_hz, truth_rate_hz)
            conn = writer.add_connection(TRUTH_MODES_TOPIC, MULTIARRAY, typestore=_typestore(),
                                         offered_qos_profiles=[TRUTH_QOS])
            rows = np.zeros((truth_modal.shape[0], 6))
            data = []
            for k in idx:
                rows[:, :3] = truth_modal[:, k, :]
                data.append(_multiarray(rows))
            streams.append((conn, ts[idx], data))
        if fault_events:
            conn = writer.add_connection(TRUTH_FAULT_TOPIC, STRING, typestore=_typestore(),
                                         offered_qos_profiles=[TRUTH_QOS])
            ev_t = np.array([t0_ns + int(round(float(e["time_s"]) * 1e9)) for e in fault_events], dtype=np.int64)
            data = [_string(json.dumps(e, sort_keys=True, allow_nan=False)) for e in fault_events]
            streams.append((conn, ev_t, data))
        # interleave in time order (stable: topics in connection order at equal times), as a recorder would
        all_t = np.concatenate([s[1] for s in streams])
        which = np.concatenate([np.full(len(s[2]), j) for j, s in enumerate(streams)])
        pos = np.concatenate([np.arange(len(s[2])) for s in streams])
        order = np.lexsort((which, all_t))
        write = writer.write
        conns = [s[0] for s in streams]
        payloads = [s[2] for s in streams]
        for i in order.tolist():
            j = which[i]
            write(conns[j], int(all_t[i]), payloads[j][pos[i]])
    except BaseException:
        writer.close()
        shutil.rmtree(path, ignore_errors=True)
        raise
    writer.close()
    return path


def write_bag_atomic(path: str | Path, **kwargs: Any) -> Path:
    """:func:`write_bag` into a temporary directory next to ``path``, renamed at the end (never half-written)."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists already")
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir()
        write_bag(tmp / path.name, **kwargs)  # final name inside: metadata.yaml names the right file
        os.rename(tmp / path.name, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


# ----------------------------------------------------------------------------------------------------------------
# Reading and validation
# ----------------------------------------------------------------------------------------------------------------
def _resolve(bag: str | Path) -> Path:
    bag = Path(bag)
    if not bag.exists():
        raise BagError(f"bag not found: {bag}")
    if bag.is_file():
        if (bag.parent / "metadata.yaml").exists() and bag.name != "metadata.yaml":
            return bag.parent
        if bag.name == "metadata.yaml":
            return bag.parent
        raise BagError(f"{bag}: not a rosbag2 directory (give the directory that holds metadata.yaml)")
    if not (bag / "metadata.yaml").exists():
        raise BagError(f"{bag}: not a rosbag2 bag (no metadata.yaml in the directory)")
    return bag


def _decode_float64(raw: list[bytes] | np.ndarray, topic: str, bag: Path) -> np.ndarray:
    if len(raw) == 0:
        return np.zeros(0)
    if isinstance(raw, np.ndarray):  # (n, size) payloads from the bulk MCAP reader
        if raw.shape[1] != 12:
            raise BagError(f"{bag}: {topic}: messages are not std_msgs/msg/Float64 (wrong size)")
        raw = [r.tobytes() for r in raw] if not (np.all(raw[:, 0] == 0) and np.all(raw[:, 1] == 1)) else raw
        if isinstance(raw, np.ndarray):
            return raw[:, 4:].copy().view("<f8").ravel().astype(np.float64)
    blob = b"".join(raw)
    if len(blob) != 12 * len(raw) or any(len(m) != 12 for m in raw[:: max(1, len(raw) // 64)]):
        raise BagError(f"{bag}: {topic}: messages are not std_msgs/msg/Float64 (wrong size)")
    arr = np.frombuffer(blob, dtype=np.uint8).reshape(-1, 12)
    if not np.all(arr[:, 0] == 0) or not np.all(arr[:, 1] == 1):
        # big-endian or unknown encapsulation: fall back to the generic deserializer
        return np.array([_typestore().deserialize_cdr(m, FLOAT64).data for m in raw], dtype=np.float64)
    return arr[:, 4:].copy().view("<f8").ravel().astype(np.float64)


def _decode_joint(raw: list[bytes], sig: Any, topic: str, bag: Path) -> tuple[np.ndarray, np.ndarray]:
    vals = np.empty(len(raw))
    stamps = np.empty(len(raw), dtype=np.int64)
    for k, m in enumerate(raw):
        msg = _typestore().deserialize_cdr(m, JOINTSTATE)
        names = list(msg.name)
        arr = np.asarray(getattr(msg, sig.field))
        if sig.joint and sig.joint not in names:
            raise BagError(f"{bag}: {topic}: joint '{sig.joint}' not in message {k} (joints {names})")
        j = names.index(sig.joint) if sig.joint else 0
        if arr.size <= j:
            raise BagError(f"{bag}: {topic}: message {k} has no '{sig.field}' value for joint index {j}")
        vals[k] = arr[j]
        stamps[k] = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
    return vals, stamps


def _read_fast(path: Path, sigcfg: dict, topic_to_sig: dict, extra: list, by_topic: dict,
               window: tuple[ResolvedRange, int, int] | None = None) -> dict | None:
    """Bulk read (:mod:`mcap_fast`) of a single-file MCAP bag with Float64 signals; ``None``: use rosbags."""
    if not all(s.type == FLOAT64 for s in sigcfg.values()):
        return None
    files = sorted(path.glob("*.mcap"))
    if len(files) != 1 or any(path.glob("*.db3")):
        return None
    extra_topics = {c.topic for c in extra if {k.msgtype for k in by_topic[c.topic]} == {c.msgtype}}
    try:  # optional (setup.py extra `mcap`; rosdep has no key for it): without it, rosbags reads every bag
        import mcap  # noqa: F401  (mcap_fast imports it only inside its readers)

        from .mcap_fast import FastPathUnsupported, read_topics
    except ImportError:
        return None
    try:
        if window is None:
            return read_topics(files[0], set(topic_to_sig) | extra_topics)
        out = read_topics(files[0], set(topic_to_sig) | (extra_topics - {TRUTH_FAULT_TOPIC}), window[1], window[2])
        if TRUTH_FAULT_TOPIC in extra_topics:   # the fault schedule is a handful of messages: all of it
            out.update(read_topics(files[0], {TRUTH_FAULT_TOPIC}))
        return out
    except FastPathUnsupported:
        return None


class SignalSource(Protocol):
    """What :func:`read_signals` reads of a configuration (``config.MonitorConfig``, or a view of a bag's topics)."""

    @property
    def closed_loop(self) -> bool: ...
    @property
    def loop_rate_hz(self) -> float: ...
    @property
    def signals(self) -> Mapping[str, SignalSettings]: ...


def bag_topic(sig: Any) -> Any:
    """A bag stores absolute topic names: a relative configured topic ``name`` (the node resolves it in its
    namespace, /name in the root namespace) matches the bag's ``/name``."""
    topic = sig.topic.strip()
    return sig if topic.startswith("/") else replace(sig, topic="/" + topic)


def _connections_by_topic(reader: Any, path: Path) -> dict[str, list]:
    """The bag's connections per topic; an empty bag is refused."""
    if reader.message_count == 0:
        raise BagError(f"{path}: the bag is empty (no messages)")
    by_topic: dict[str, list] = {}
    for c in reader.connections:
        by_topic.setdefault(c.topic, []).append(c)
    return by_topic


RANGE_MARGIN_NS = 10**9   # a time range reads this much more on each side (JointState stamps lag log times), then trims


def _read_window(reader: Any, path: Path, sigcfg: dict, by_topic: dict, config: SignalSource,
                 time_range: TimeRange) -> tuple[ResolvedRange, int, int]:
    """The range against the record (its first output sample and its last message) and the log-time window to
    read (the range with :data:`RANGE_MARGIN_NS` on each side). Reads the first output message only."""
    out = sigcfg["output"]
    first = reader.messages(connections=by_topic[out.topic])
    try:
        _, log_t, data = next(first)
    except StopIteration:
        raise BagError(f"{path}: topic '{out.topic}' (output) has no messages") from None
    finally:
        first.close()
    origin = int(log_t) if out.type == FLOAT64 else int(_decode_joint([bytes(data)], out, out.topic, path)[1][0])
    try:
        rng = time_range.resolve(origin, int(reader.end_time) - 1, 1.0 / config.loop_rate_hz)
    except ValueError as exc:
        raise BagError(f"{path}: {exc}") from None
    return rng, rng.start_ns - RANGE_MARGIN_NS, rng.end_ns + RANGE_MARGIN_NS


def _messages(reader: Any, conns: list, window: tuple[ResolvedRange, int, int] | None) -> Any:
    """rosbags' messages of ``conns``; with a window, the signals only in it (the fault schedule whole)."""
    if window is None:
        return reader.messages(connections=conns)
    faults = [c for c in conns if c.topic == TRUTH_FAULT_TOPIC]
    inside = reader.messages(connections=[c for c in conns if c.topic != TRUTH_FAULT_TOPIC], start=window[1],
                             stop=window[2])
    return itertools.chain(inside, reader.messages(connections=faults) if faults else ())


def trimmed(sig: Signals, rng: ResolvedRange, path: Path | str = "") -> Signals:
    """The samples (and the truth of ``/truth/modes``) of ``sig`` in ``[rng.start_s, rng.end_s)``; ``BagError``
    when fewer than two samples are left."""
    eps = 1e-10
    keep = (sig.t >= rng.start_s - eps) & (sig.t < rng.end_s - eps)
    if np.count_nonzero(keep) < 2:
        raise BagError(f"{path}: no samples in the range {rng.start_s:.6g} to {rng.end_s:.6g} s of the record")
    r_in = None if sig.r is None else sig.r[keep]
    u_in, y_in = sig.u[keep], sig.y[keep]
    nonfinite = {name: int(np.count_nonzero(~np.isfinite(x))) for name, x in
                 (("reference", r_in), ("input", u_in), ("output", y_in)) if x is not None}
    truth_t, truth_modes = sig.truth_t, sig.truth_modes
    if truth_t is not None and truth_modes is not None:
        tk = (truth_t >= rng.start_s - eps) & (truth_t < rng.end_s - eps)
        truth_t, truth_modes = (truth_t[tk], truth_modes[tk]) if tk.any() else (None, None)
    return replace(sig, t=sig.t[keep], r=r_in, u=u_in, y=y_in, truth_t=truth_t, truth_modes=truth_modes,
                   nonfinite=sum(nonfinite.values()), nonfinite_by_signal=nonfinite, time_range=rng.to_dict())


def read_signals(bag: str | Path, config: SignalSource, time_range: TimeRange | None = None) -> Signals:
    """Read and check ``r``, ``u``, ``y`` (and the truth topics, if any) of a bag for ``config``.

    ``time_range`` (:mod:`.timerange`): only the samples in ``[start, end)`` are read (the reader skips the other
    messages; ``Signals.t`` stays in seconds from the record's first sample, ``Signals.time_range`` says which);
    a range outside the record raises :class:`BagError`.

    Raises :class:`BagError` (one line) when the bag is missing, has no metadata, is unreadable, truncated or
    corrupt (also: a topic yields fewer messages than its metadata records), is empty, lacks a configured topic, has
    a topic of the wrong type, has unequal sample counts that do not match by time (:func:`align_by_time`), or a
    median sample spacing inconsistent with ``loop_rate_hz``. Non-finite samples are kept (NaN in the arrays) and
    counted in ``nonfinite``: the caller decides.
    """
    path = _resolve(bag)
    if isinstance(config, MonitorConfig) and config.block_input:
        sig = _read_block_bag(path, config)
        if time_range is None:
            return sig
        try:
            rng = time_range.resolve(sig.t0_ns, sig.t0_ns + int(round(float(sig.t[-1]) * 1e9)),
                                     1.0 / config.loop_rate_hz)
        except ValueError as exc:
            raise BagError(f"{path}: {exc}") from None
        return trimmed(sig, rng, path)
    wanted = ["input", "output"] + (["reference"] if config.closed_loop else [])
    sigcfg = {name: bag_topic(config.signals[name]) for name in wanted}
    raw: dict[str, list[bytes]] = {name: [] for name in wanted}
    log_ns: dict[str, list[int]] = {name: [] for name in wanted}
    truth_raw: list[tuple[int, bytes]] = []
    fault_raw: list[tuple[int, bytes]] = []
    try:
        with Reader(path) as reader:
            by_topic = _connections_by_topic(reader, path)
            conns = []
            topic_to_sig: dict[str, list[str]] = {}
            for name, s in sigcfg.items():
                if s.topic not in by_topic:
                    have = ", ".join(sorted(by_topic)) or "none"
                    raise BagError(f"{path}: configured {name} topic '{s.topic}' is not in the bag (topics: {have})")
                types = {c.msgtype for c in by_topic[s.topic]}
                if types != {s.type}:
                    raise BagError(f"{path}: topic '{s.topic}' has type {', '.join(sorted(types))}, "
                                   f"configured {name}.type is {s.type}")
                if s.topic not in topic_to_sig:
                    conns += by_topic[s.topic]
                topic_to_sig.setdefault(s.topic, []).append(name)
            extra = []
            for topic, typ in ((TRUTH_MODES_TOPIC, MULTIARRAY), (TRUTH_FAULT_TOPIC, STRING)):
                for c in by_topic.get(topic, []):
                    if c.msgtype == typ:
                        extra.append(c)
            window = None if time_range is None else _read_window(reader, path, sigcfg, by_topic, config, time_range)
            fast = _read_fast(path, sigcfg, topic_to_sig, extra, by_topic, window)
            if fast is not None:
                for topic, names in topic_to_sig.items():
                    times, payload = fast[topic]
                    for name in names:
                        raw[name], log_ns[name] = payload, times
                for topic, sink in ((TRUTH_MODES_TOPIC, truth_raw), (TRUTH_FAULT_TOPIC, fault_raw)):
                    if topic in fast:
                        sink.extend((int(t), bytes(d)) for t, d in zip(*fast[topic], strict=True))
            for conn, timestamp, data in ([] if fast is not None else _messages(reader, conns + extra, window)):
                if conn.topic == TRUTH_MODES_TOPIC and conn in extra:
                    truth_raw.append((timestamp, bytes(data)))
                elif conn.topic == TRUTH_FAULT_TOPIC and conn in extra:
                    fault_raw.append((timestamp, bytes(data)))
                else:
                    for name in topic_to_sig.get(conn.topic, ()):
                        raw[name].append(bytes(data))
                        log_ns[name].append(timestamp)
            for topic, names in topic_to_sig.items():   # a damaged chunk can drop records without an exception
                declared = 0 if window else sum(int(getattr(c, "msgcount", 0) or 0) for c in by_topic[topic])
                got = len(raw[names[0]])
                if declared and got != declared:
                    raise BagError(f"{path}: corrupt or truncated bag: topic '{topic}' yields {got} of the {declared} "
                                   "messages its metadata records")
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises many types for damaged files
        raise BagError(f"{path}: unreadable, truncated or corrupt bag "
                       f"({type(exc).__name__}: {one_line(exc, ERROR_CHARS)})") from None
    if window is None:
        return _assemble(path, config, sigcfg, raw, log_ns, truth_raw, fault_raw)
    return trimmed(_assemble(path, config, sigcfg, raw, log_ns, truth_raw, fault_raw, window[0]), window[0], path)


def _assemble(path: Path, config: SignalSource, sigcfg: dict, raw: dict, log_ns: dict, truth_raw: list,
              fault_raw: list, rng: ResolvedRange | None = None) -> Signals:
    values: dict[str, np.ndarray] = {}
    stamps: dict[str, np.ndarray] = {}
    for name, s in sigcfg.items():
        if len(raw[name]) == 0:
            raise BagError(f"{path}: topic '{s.topic}' ({name}) has no messages")
        try:
            if s.type == FLOAT64:
                values[name] = _decode_float64(raw[name], s.topic, path)
                stamps[name] = np.asarray(log_ns[name], dtype=np.int64)
            else:
                values[name], stamps[name] = _decode_joint(raw[name], s, s.topic, path)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(f"{path}: {s.topic}: cannot decode {s.type} ({one_line(exc, ERROR_CHARS)})") from None
    for name, st in stamps.items():
        if st.size >= 2 and np.any(np.diff(st) < 0):
            raise BagError(f"{path}: {sigcfg[name].topic}: sample times go backwards")
    counts = {name: v.size for name, v in values.items()}
    nonfinite = {name: int(np.count_nonzero(~np.isfinite(v))) for name, v in values.items()}
    unmatched: dict[str, int] = {}
    if len(set(counts.values())) != 1:   # a lost message: match the samples by time instead of by order
        values, stamps, unmatched = align_by_time(values, stamps, config.loop_rate_hz, path,
                                                  {k: v.topic for k, v in sigcfg.items()})
    n = values["output"].size
    t_ns = stamps["output"]
    t0 = int(t_ns[0]) if rng is None else rng.origin_ns    # a range: times stay the record's
    if n >= 2:
        dt = mean_sample_spacing(t_ns)
        h = 1.0 / config.loop_rate_hz
        if abs(dt - h) > SPACING_TOLERANCE * h:
            raise BagError(f"{path}: the samples arrive at {1.0 / dt:.6g} Hz (mean spacing {dt * 1e3:.6g} ms), "
                           f"loop_rate_hz is {config.loop_rate_hz:g}: more than {SPACING_TOLERANCE:.1%} apart")
    truth_t, truth_modes, truth_fault = _truth(path, truth_raw, fault_raw, t0)
    return Signals(
        t=(t_ns - t0) * 1e-9, t0_ns=t0, r=values.get("reference"), u=values["input"], y=values["output"],
        truth_t=truth_t, truth_modes=truth_modes, truth_fault=truth_fault, nonfinite=sum(nonfinite.values()),
        nonfinite_by_signal=nonfinite, unmatched_by_signal=unmatched, **_metadata_info(path),
        time_range=None if rng is None else rng.to_dict())


def _truth(path: Path, truth_raw: list, fault_raw: list, t0: int) -> tuple[Any, Any, Any]:
    """``(truth_t, truth_modes, truth_fault)`` of the simulator's truth topics (None where absent)."""
    truth_t = truth_modes = None
    if truth_raw:
        rows = []
        for _, data in truth_raw:
            try:
                sizes, flat = _decode_multiarray(data)
            except Exception as exc:  # noqa: BLE001
                raise BagError(f"{path}: {TRUTH_MODES_TOPIC}: cannot decode ({one_line(exc, ERROR_CHARS)})") from None
            if len(sizes) != 2 or sizes[1] != 6 or flat.size != sizes[0] * 6:
                raise BagError(f"{path}: {TRUTH_MODES_TOPIC}: layout is not (mode K, field 6)")
            rows.append(flat.reshape(sizes[0], 6))
        if len({r.shape for r in rows}) != 1:
            raise BagError(f"{path}: {TRUTH_MODES_TOPIC}: the number of modes changes between messages")
        truth_modes = np.stack(rows)
        truth_t = (np.array([ts for ts, _ in truth_raw], dtype=np.int64) - t0) * 1e-9
    truth_fault = None
    if fault_raw:
        truth_fault = []
        for _, data in fault_raw:
            try:
                text = _decode_string(data)
                truth_fault.append(json.loads(text))
            except Exception as exc:  # noqa: BLE001
                raise BagError(f"{path}: {TRUTH_FAULT_TOPIC}: not JSON ({one_line(exc, ERROR_CHARS)})") from None
    return truth_t, truth_modes, truth_fault


def _read_block_bag(path: Path, config: MonitorConfig) -> Signals:
    """A bag recorded on ``block.topic`` (:mod:`.block_bag`: the node's own block logic, log time as arrival)."""
    from .block_bag import block_samples

    topic = str(config.params["block.topic"])
    messages: list[tuple[int, Any]] = []
    truth_raw: list[tuple[int, bytes]] = []
    fault_raw: list[tuple[int, bytes]] = []
    try:
        with Reader(path) as reader:
            by_topic = _connections_by_topic(reader, path)
            if topic not in by_topic:
                have = ", ".join(sorted(by_topic)) or "none"
                raise BagError(f"{path}: configured block topic '{topic}' is not in the bag (topics: {have})")
            types = {c.msgtype for c in by_topic[topic]}
            if types != {MULTIARRAY}:
                raise BagError(f"{path}: topic '{topic}' has type {', '.join(sorted(types))}, block input needs "
                               f"{MULTIARRAY}")
            conns = by_topic[topic] + [c for t, typ in ((TRUTH_MODES_TOPIC, MULTIARRAY), (TRUTH_FAULT_TOPIC, STRING))
                                       for c in by_topic.get(t, []) if c.msgtype == typ]
            store = _typestore()
            for conn, timestamp, data in reader.messages(connections=conns):
                if conn.topic == TRUTH_MODES_TOPIC:
                    truth_raw.append((timestamp, bytes(data)))
                elif conn.topic == TRUTH_FAULT_TOPIC:
                    fault_raw.append((timestamp, bytes(data)))
                else:
                    messages.append((int(timestamp), store.deserialize_cdr(bytes(data), MULTIARRAY)))
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises many types for damaged files
        raise BagError(f"{path}: unreadable, truncated or corrupt bag "
                       f"({type(exc).__name__}: {one_line(exc, ERROR_CHARS)})") from None
    messages.sort(key=lambda m: m[0])
    try:
        t_ns, r, u, y, counters = block_samples(path, config, messages)
    except ValueError as exc:
        raise BagError(str(exc)) from None
    t0 = int(t_ns[0])
    truth_t, truth_modes, truth_fault = _truth(path, truth_raw, fault_raw, t0)
    nonfinite = {name: int(np.count_nonzero(~np.isfinite(v)))
                 for name, v in (("reference", r), ("input", u), ("output", y)) if v is not None}
    return Signals(t=(t_ns - t0) * 1e-9, t0_ns=t0, r=r, u=u, y=y, truth_t=truth_t, truth_modes=truth_modes,
                   truth_fault=truth_fault, nonfinite=sum(nonfinite.values()), nonfinite_by_signal=nonfinite,
                   block=counters, **_metadata_info(path))


ALIGN_MIN_FRACTION = 0.9  # time alignment must find every topic in at least this fraction of the grid samples


def topic_offset_ns(stamps: np.ndarray, ref: np.ndarray) -> float:
    """Constant offset of a topic's stamps to the reference stamps: median distance to the nearest reference stamp.

    Nearest-neighbour distances do not depend on message order, so a message lost or repeated early does not
    shift every later sample (an index-wise median would: one lost message in the first samples made it a
    whole period).
    """
    st = stamps.astype(np.float64)
    rf = ref.astype(np.float64)
    if st.size == 0 or rf.size == 0:
        return 0.0
    j = np.clip(np.searchsorted(rf, st), 1, max(rf.size - 1, 1))
    left, right = rf[j - 1], rf[np.minimum(j, rf.size - 1)]
    near = np.where(np.abs(st - left) <= np.abs(st - right), left, right)
    return float(np.median(st - near))


def align_by_time(values: dict[str, np.ndarray], stamps: dict[str, np.ndarray], rate_hz: float, path: Path,
                  topics: dict[str, str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, int]]:
    """Pair r, u, y samples by time when their message counts differ (a message lost or repeated by the recorder).

    Each topic's constant offset to the output (publication order, transport) is removed
    (:func:`topic_offset_ns`); the stamps of all topics are then grouped into grid samples (stamps within half a
    period of each other). A signal without a sample in a group is NaN there (the pipeline skips the sample and
    keeps its grid, no gap); a second sample of one signal in a group is a surplus message and left out.
    Returns values and stamps on that grid (the output's stamp, or the group's mean stamp where the output is
    missing) and per signal the number of missing samples plus surplus messages. Raises :class:`BagError` when
    fewer than ``ALIGN_MIN_FRACTION`` of the grid samples have every signal.
    """
    h_ns = 1e9 / rate_hz
    names = list(values)
    ref = stamps["output"]
    shifted = {k: stamps[k].astype(np.float64) - (0.0 if k == "output" else topic_offset_ns(stamps[k], ref))
               for k in names}
    all_t = np.concatenate([shifted[k] for k in names])
    label = np.concatenate([np.full(shifted[k].size, i) for i, k in enumerate(names)])
    pos = np.concatenate([np.arange(shifted[k].size) for k in names])
    order = np.argsort(all_t, kind="stable")
    all_t, label, pos = all_t[order], label[order], pos[order]
    group = np.concatenate(([0], np.cumsum(np.diff(all_t) > 0.5 * h_ns)))
    n_grid = int(group[-1]) + 1 if group.size else 0
    out_v: dict[str, np.ndarray] = {}
    have = np.zeros((len(names), n_grid), dtype=bool)
    first_pos = np.full((len(names), n_grid), -1, dtype=np.int64)
    counts = {}
    for i, k in enumerate(names):
        sel = label == i
        g, p = group[sel], pos[sel]
        first = np.concatenate(([True], g[1:] != g[:-1]))      # one sample per signal and group
        counts[k] = int(np.count_nonzero(~first))
        first_pos[i, g[first]] = p[first]
        have[i, g[first]] = True
    complete = have.all(axis=0)
    if np.count_nonzero(complete) < ALIGN_MIN_FRACTION * n_grid:
        desc = ", ".join(f"{topics[k]}={v.size}" for k, v in values.items())
        raise BagError(f"{path}: sample counts differ between topics ({desc}) and fewer than "
                       f"{ALIGN_MIN_FRACTION:.0%} of the samples match by time; cannot align")
    gsum = np.bincount(group, weights=all_t, minlength=n_grid)
    gcnt = np.bincount(group, minlength=n_grid)
    t_grid = np.rint(gsum / np.maximum(gcnt, 1)).astype(np.int64)
    io = names.index("output")
    t_grid[have[io]] = stamps["output"][first_pos[io, have[io]]]
    out_t = {}
    missing = {}
    for i, k in enumerate(names):
        v = np.full(n_grid, np.nan)
        v[have[i]] = values[k][first_pos[i, have[i]]]
        out_v[k] = v
        out_t[k] = t_grid
        missing[k] = int(np.count_nonzero(~have[i])) + counts[k]
    return out_v, out_t, missing


def mean_sample_spacing(t_ns: np.ndarray) -> float:
    """Mean sample spacing in s, robust to pauses and lost samples.

    Each interval counts as ``round(dt / median dt)`` sample periods (a pause or a lost sample spans several),
    so the estimate is the record's duration over its number of periods: far more precise than the median of
    jittered receive stamps, and not fooled by gaps.
    """
    d = np.diff(t_ns.astype(np.int64)).astype(np.float64)
    med = float(np.median(d))
    if not med > 0.0:
        return med * 1e-9
    periods = np.maximum(np.rint(d / med), 1.0)
    return float(d.sum() / periods.sum()) * 1e-9


def _metadata_info(path: Path) -> dict[str, Any]:
    """Storage identifier and custom data from metadata.yaml (already parsed successfully by the reader)."""
    try:
        text = (path / "metadata.yaml").read_text()
        try:                  # libyaml when PyYAML has it (5x faster); the pure-Python parser if it has not or fails
            doc = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        except yaml.YAMLError:
            doc = yaml.safe_load(text)
        info = doc["rosbag2_bagfile_information"]
        return {"storage": str(info.get("storage_identifier", "")),
                "metadata": {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}}
    except Exception:  # noqa: BLE001 - informative only
        return {"storage": "", "metadata": {}}


def bag_info(bag: str | Path) -> dict[str, Any]:
    """Topics, types and message counts of a bag (``{"storage", "topics": {name: (type, count)}, ...}``)."""
    path = _resolve(bag)
    try:
        with Reader(path) as reader:
            return {"path": str(path), "message_count": reader.message_count, "duration_ns": reader.duration,
                    "start_time_ns": reader.start_time,
                    "topics": {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}}
    except Exception as exc:  # noqa: BLE001
        raise BagError(f"{path}: unreadable bag ({type(exc).__name__}: {one_line(exc, ERROR_CHARS)})") from None


