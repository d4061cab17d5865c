"""Conversions between the parameter table / status records / pipeline reports and ROS 2 messages."""

from __future__ import annotations

import array
import math
import sys
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..config import Param
from ..core.vocabulary import BASELINE_FIELDS, FLAG_FIELDS, MODE_FIELDS, MODE_KEYS, num  # noqa: F401 (cv.* in ros/)
from ..outputs.status import StatusRecord
from .blocks import BLOCK_COLUMNS, block_rows  # noqa: F401 (cv.block_rows; ROS-free, offline too)

PARAM_TYPE = {
    "bool": Parameter.Type.BOOL, "int": Parameter.Type.INTEGER, "double": Parameter.Type.DOUBLE,
    "string": Parameter.Type.STRING, "bool[]": Parameter.Type.BOOL_ARRAY, "int[]": Parameter.Type.INTEGER_ARRAY,
    "double[]": Parameter.Type.DOUBLE_ARRAY, "string[]": Parameter.Type.STRING_ARRAY,
}
_INT_MAX = 2**63 - 1


def descriptor(p: Param) -> ParameterDescriptor:
    """ParameterDescriptor of a table row: description, read-only, range (scalars) and constraints text."""
    d = ParameterDescriptor(name=p.name, type=PARAM_TYPE[p.type].value, description=p.description,
                            read_only=p.read_only)
    notes = []
    if p.min is not None or p.max is not None:
        lo = p.min if p.min is not None else -math.inf
        hi = p.max if p.max is not None else math.inf
        if p.type == "double":
            d.floating_point_range = [FloatingPointRange(from_value=float(max(lo, -sys.float_info.max)),
                                                         to_value=float(min(hi, sys.float_info.max)), step=0.0)]
        elif p.type == "int":
            d.integer_range = [IntegerRange(from_value=int(max(lo, -_INT_MAX)), to_value=int(min(hi, _INT_MAX)),
                                            step=0)]
        else:
            notes.append(f"every element in [{lo:g}, {hi:g}]")
    if p.choices:
        notes.append("one of: " + ", ".join(p.choices))
    if p.read_only:
        notes.append("read-only: changing it needs a restart")
    d.additional_constraints = "; ".join(notes)
    return d


def coerce_int_to_double(p: Param, param: Parameter) -> Parameter:
    """An integer (array) given for a double (array) parameter becomes a double (YAML ``3`` for ``3.0``)."""
    if p.type == "double" and param.type_ == Parameter.Type.INTEGER:
        return Parameter(param.name, Parameter.Type.DOUBLE, float(param.value))
    if p.type == "double[]" and param.type_ == Parameter.Type.INTEGER_ARRAY:
        return Parameter(param.name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in param.value])
    return param


def plain(value: Any) -> Any:
    """Parameter value as plain Python (arrays -> lists)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    return value


def mode_status(record: StatusRecord, hardware_id: str) -> DiagnosticStatus:
    """One ``<node>: mode <i>`` status with exactly the interface's keys (flags 'true'/'false')."""
    kv = []
    for k in MODE_KEYS:
        v = record.values.get(k, math.nan if k not in FLAG_FIELDS else False)
        kv.append(KeyValue(key=k, value=("true" if v else "false") if k in FLAG_FIELDS else num(v)))
    return DiagnosticStatus(level=bytes([int(record.level)]), name=record.name, message=record.message,
                            hardware_id=hardware_id, values=kv)


def status(record: StatusRecord, hardware_id: str) -> DiagnosticStatus:
    """A status with arbitrary key/values (numbers as decimal strings, bools as 'true'/'false')."""
    kv = []
    for k, v in record.values.items():
        if isinstance(v, bool):
            s = "true" if v else "false"
        elif isinstance(v, int | float):
            s = num(v) if isinstance(v, float) else str(v)
        else:
            s = str(v)
        kv.append(KeyValue(key=k, value=s))
    return DiagnosticStatus(level=bytes([int(record.level)]), name=record.name, message=record.message,
                            hardware_id=hardware_id, values=kv)


def modes_array(modal: Any) -> Float64MultiArray:
    """``~/modes``: dim[0] 'mode' (K), dim[1] 'field' (6), row-major (docs/INTERFACE.md)."""
    rows = [[float(x) for x in row[:6]] for row in modal]
    k = len(rows)
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="mode", size=k, stride=6 * k),
                      MultiArrayDimension(label="field", size=6, stride=6)]
    msg.layout.data_offset = 0
    msg.data = [x for row in rows for x in row]
    return msg


#: ``~/modes_stamped`` (sensor_msgs/msg/PointCloud2, one point per mode): field name, PointField datatype, offset
MODES_STAMPED_FIELDS = (("mode", 6, 0),                           # UINT32: the mode's number 1..K
                        *((name, 8, 8 * (j + 1)) for j, name in enumerate(MODE_FIELDS[:6])))   # FLOAT64
MODES_STAMPED_POINT_STEP = 8 * 7


def modes_stamped(modal: Any, stamp_ns: int, frame_id: str = "") -> Any:
    """``~/modes_stamped``: the ``~/modes`` estimate as a ``sensor_msgs/msg/PointCloud2`` table, one point per mode
    with the named fields :data:`MODES_STAMPED_FIELDS` (``mode`` uint32, then the six ``~/modes`` fields float64,
    little endian), ``header.stamp`` the data time of the estimate (the time of the last sample it includes, on the
    clock of the input samples: ROS time, or the inputs' stamps). ``is_dense`` is false when a value is NaN (an
    unknown std). Read it with ``sensor_msgs_py.point_cloud2.read_points`` or a numpy dtype built from its fields."""
    import numpy as np
    from sensor_msgs.msg import PointCloud2, PointField

    rows = np.asarray(modal, dtype=float).reshape(-1, np.shape(modal)[-1])[:, :6]
    k = rows.shape[0]
    table = np.zeros(k, dtype=np.dtype({"names": [f[0] for f in MODES_STAMPED_FIELDS],
                                        "formats": ["<u4"] + ["<f8"] * 6,
                                        "offsets": [f[2] for f in MODES_STAMPED_FIELDS],
                                        "itemsize": MODES_STAMPED_POINT_STEP}))
    table["mode"] = np.arange(1, k + 1)
    for j, name in enumerate(MODE_FIELDS[:6]):
        table[name] = rows[:, j]
    msg = PointCloud2()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.frame_id = frame_id
    msg.height, msg.width = 1, k
    msg.fields = [PointField(name=name, offset=off, datatype=dt, count=1) for name, dt, off in MODES_STAMPED_FIELDS]
    msg.is_bigendian = False
    msg.point_step, msg.row_step = MODES_STAMPED_POINT_STEP, MODES_STAMPED_POINT_STEP * k
    msg.data = table.tobytes()
    msg.is_dense = bool(np.all(np.isfinite(rows)))
    return msg


BLOCK_TYPE = "std_msgs/msg/Float64MultiArray"


def block_message(index: Any, r: Any, u: Any, y: Any) -> Float64MultiArray:
    """A block message in the contract layout from equal-length columns (``rsrivc_replay --block``, tests)."""
    import numpy as np

    rows = np.column_stack([np.asarray(c, dtype=np.float64) for c in (index, r, u, y)])
    n = rows.shape[0]
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="sample", size=n, stride=4 * n),
                      MultiArrayDimension(label="signal", size=4, stride=4)]
    msg.layout.data_offset = 0
    data = array.array("d")
    data.frombytes(np.ascontiguousarray(rows).tobytes())
    msg.data = data
    return msg
