"""rsrivc_joints' parameters and fan-out without DDS: joints list, shared and per-joint values, one-line errors, the
conversion of each JointState message once for all joints (message objects stand in for the received ones)."""
import array
from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest

from additive_rsrivc_ros import joint_params as jp
from additive_rsrivc_ros.config import ParamError, validate_params
from additive_rsrivc_ros.ros.joint_fanout import Reader, SharedJointTopic, field_matrix


def test_joint_values_layer_group_defaults_shared_and_own():
    shared, own, foreign = jp.split_given({"joints": ["a", "b"], "loop_rate_hz": 1000.0, "modes.memory_s": [5.0],
                                           "b.modes.memory_s": [2.0], "b.output.joint": "b_link",
                                           "other_node.gain": 3, "use_sim_time": True}, ["a", "b"])
    assert foreign == ["other_node.gain"]
    va, vb = jp.joint_values("a", shared, own["a"]), jp.joint_values("b", shared, own["b"])
    assert va["modes.memory_s"] == [5.0] and vb["modes.memory_s"] == [2.0]
    assert va["output.joint"] == "a" and vb["output.joint"] == "b_link" and vb["input.joint"] == "b"
    assert va["input.field"] == "effort" and va["reference.topic"] == "joint_commands"
    assert va["output.type"] == jp.JOINT_STATE and va["block_period_s"] == 0.05
    validate_params(va)          # every name a row of the monitor's table


@pytest.mark.parametrize("given, text", [
    ({"c.modes.memory_s": [1.0]}, "'c' is not one of the joints [a, b]"),
    ({"a.qos_depth": 10}, "one value for the whole node"),
    ({"a.modes.memry_s": [1.0]}, "did you mean a.modes.memory_s"),
    ({"output.joint": "x"}, "is per joint"),
])
def test_misplaced_parameters_are_one_line_errors(given, text):
    with pytest.raises(ParamError, match=None) as e:
        jp.split_given(given, ["a", "b"])
    assert text in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("joints, text", [
    ([], "is required"), (["a", "a"], "more than once"), (["1st"], "not a valid name"),
    (["modes"], "name of a parameter group"),
])
def test_joint_names_are_checked(joints, text):
    with pytest.raises(ParamError) as e:
        jp.check_joint_names(joints)
    assert text in str(e.value)


def test_joint_count_and_group_checks():
    assert jp.monitored_joints(["a", "b", "c"], [], 2) == ["a", "b"]
    assert jp.monitored_joints(["a", "b", "c"], ["c", "a"], 0) == ["c", "a"]
    assert jp.monitored_joints(["a", "b", "c"], ["c", "a"], 1) == ["c"]
    with pytest.raises(ParamError, match="2 joint"):
        jp.monitored_joints(["a", "b"], [], 3)
    with pytest.raises(ParamError, match="x not in 'joints'"):
        jp.monitored_joints(["a", "b"], ["x"], 0)
    base = validate_params({**jp.JOINT_DEFAULTS, "loop_rate_hz": 100.0})
    jp.check_group({"a": base, "b": base})
    with pytest.raises(ParamError, match="same state_file"):
        jp.check_group({"a": {**base, "state_file": "/s.json"}, "b": {**base, "state_file": "/s.json"}})
    with pytest.raises(ParamError, match="same block.topic"):
        jp.check_group({"a": {**base, "block.topic": "/blk"}, "b": {**base, "block.topic": "/blk"}})
    with pytest.raises(ParamError, match="input.type must be"):
        jp.check_group({"a": {**base, "input.type": "std_msgs/msg/Float64"}})


def test_field_matrix_marks_short_rows():
    rows = [array.array("d", [1.0, 2.0]), array.array("d", [3.0]), array.array("d", [5.0, 6.0])]
    mat, ok = field_matrix(rows, 2)
    assert ok.tolist() == [True, False, True] and mat[2].tolist() == [5.0, 6.0]
    mat, ok = field_matrix([rows[0], rows[2]], 2)
    assert ok is None and mat.tolist() == [[1.0, 2.0], [5.0, 6.0]]


def _msg(k: int, names: list[str], pos: list[float], eff: list[float]):
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=k, nanosec=5)), name=names,
                           position=array.array("d", pos), effort=array.array("d", eff))


def _channel():
    sync = SimpleNamespace(queues=[deque(maxlen=100), deque(maxlen=100)], overflow=[0, 0], events=[])
    sync._event = lambda now, text: sync.events.append(text)
    return SimpleNamespace(sync=sync, malformed={})      # the joint's input stage and statistics


def test_fan_out_by_name_in_any_order_and_missing_joints():
    """Each joint gets its own column whatever the order of the names; a message without the joint is malformed for
    that joint only (one event per episode, one when it is back)."""
    a, b = _channel(), _channel()
    topic = SharedJointTopic("/joint_states", 10)
    for ch, j in ((a, "a"), (b, "b")):
        topic.add_reader(Reader(ch.sync, ch, 0, "input", j, "effort"))
        topic.add_reader(Reader(ch.sync, ch, 1, "output", j, "position"))
    msgs = [_msg(0, ["a", "b"], [1.0, 2.0], [10.0, 20.0]), _msg(1, ["b", "a"], [2.1, 1.1], [20.1, 10.1]),
            _msg(2, ["a"], [1.2], [10.2]), _msg(3, ["a"], [1.3], [10.3]), _msg(4, ["b", "x", "a"], [2.4, 0.0, 1.4],
                                                                            [20.4, 0.0, 10.4])]
    for k, m in enumerate(msgs):
        topic.enqueue(m, 1000 + k)
    assert topic.fan_out(0) == 5
    stamps = [k * 10**9 + 5 for k in range(5)]
    assert list(a.sync.queues[1]) == list(zip([1.0, 1.1, 1.2, 1.3, 1.4], range(1000, 1005), stamps, strict=True))
    assert [v for v, _, _ in a.sync.queues[0]] == [10.0, 10.1, 10.2, 10.3, 10.4]
    assert [(v, s) for v, _, s in b.sync.queues[1]] == [(2.0, stamps[0]), (2.1, stamps[1]), (2.4, stamps[4])]
    assert b.malformed == {"input": 2, "output": 2} and not a.malformed
    assert len(b.sync.events) == 2 and "not in 2 message(s)" in b.sync.events[0] and "back" in b.sync.events[1]
    assert not a.sync.events


def test_fan_out_counts_the_queue_bound_for_every_reader():
    a = _channel()
    topic = SharedJointTopic("/joint_states", 3)
    topic.add_reader(Reader(a.sync, a, 1, "output", "a", "position"))
    for k in range(5):
        topic.enqueue(_msg(k, ["a"], [float(k)], [0.0]), k)
    topic.fan_out(0)
    assert a.sync.overflow[1] == 2 and [v for v, _, _ in a.sync.queues[1]] == [2.0, 3.0, 4.0]


def _random_joint_states(n: int, seed: int) -> list:
    from sensor_msgs.msg import JointState

    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9))
        m.header.frame_id = "f" * int(rng.integers(0, 7))
        width = int(rng.integers(1, 6))
        m.name = [f"j{'x' * int(rng.integers(0, 5))}{i}" for i in range(width)]
        for f in ("position", "velocity", "effort"):
            size = width if rng.random() < 0.7 else int(rng.integers(0, width + 1))
            setattr(m, f, rng.normal(size=size).tolist())
        out.append(m)
    return out


def test_cdr_layouts_decode_like_rclpy():
    """Serialized JointStates of random layouts (frame ids, name lengths, fields shorter than the names): the layout
    parse and the one-pass decode give rclpy's values; equal layouts match, other ones do not."""
    from rclpy.serialization import serialize_message

    from additive_rsrivc_ros.ros import joint_cdr

    msgs = _random_joint_states(300, 3)
    for m in msgs:
        raw = serialize_message(m)
        lay = joint_cdr.parse_layout(raw)
        assert lay is not None and list(lay.names) == list(m.name) and lay.matches(raw)
        stamps, mats = joint_cdr.decode_run([raw], lay, joint_cdr.FIELDS)
        assert stamps == [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec]
        for f in joint_cdr.FIELDS:
            mat, ok = mats[f]
            vals = list(getattr(m, f))
            if len(vals) == len(m.name):
                assert ok is None and mat[0].tolist() == vals
            else:
                assert not ok.any()
    raws = [serialize_message(m) for m in msgs[:40]]
    same = [joint_cdr.parse_layout(a).signature == joint_cdr.parse_layout(b).signature and len(a) == len(b)
            for a, b in zip(raws, raws[1:], strict=False)]
    assert [joint_cdr.parse_layout(a).matches(b) for a, b in zip(raws, raws[1:], strict=False)] == same
    assert joint_cdr.parse_layout(b"\x01\x00\x00\x00" + raws[0][4:]) is None       # big endian: rclpy decodes it
    assert joint_cdr.checked_against_rclpy()


def test_raw_fan_out_equals_the_object_fan_out():
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    msgs = _random_joint_states(200, 4)
    for m in msgs[50:120]:               # a long run of one layout, as a robot publishes
        m.name, m.header.frame_id = ["j0", "j1", "j2"], "base"
        m.position, m.effort = np.arange(3.0).tolist(), np.arange(3.0, 6.0).tolist()
    got = []
    for raw in (False, True):
        chans = {j: _channel() for j in ("j0", "j1", "jx2")}
        topic = SharedJointTopic("/joint_states", 1000, raw=raw, msg_type=JointState)
        for j, ch in chans.items():
            topic.add_reader(Reader(ch.sync, ch, 0, "input", j, "effort"))
            topic.add_reader(Reader(ch.sync, ch, 1, "output", j, "position"))
        for k, m in enumerate(msgs):
            topic.enqueue(serialize_message(m) if raw else m, k)
        topic.fan_out(0)
        got.append({j: ([list(q) for q in ch.sync.queues], ch.malformed, ch.sync.events) for j, ch in chans.items()})
        assert topic.deserialized == 0
    assert got[0] == got[1] and sum(len(q) for q in got[0]["j1"][0]) > 140
