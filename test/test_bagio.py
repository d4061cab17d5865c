"""rosbag2 round trip (mcap, sqlite3), determinism, third-party readability and bag validation (io/bagio.py)."""
import json
import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_typestore

from additive_rsrivc_ros.config import MonitorConfig, validate_params
from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.io.bagio import (
    DEFAULT_T0_NS,
    BagError,
    bag_info,
    float64_cdr,
    read_signals,
    write_bag,
    write_bag_atomic,
)
from additive_rsrivc_ros.sim.plants import PAPER_PID
from additive_rsrivc_ros.sim.simulate import (
    ModalChange,
    PlantMode,
    SensorFault,
    simulate_modes,
    square_wave,
    time_vector,
    white_noise,
)

TS = get_typestore(Stores.ROS2_JAZZY)
RATE = 4096.0
PD = DiscreteController((2.0, -1.9), (1.0, -0.5))


def _cfg(rate: float = RATE, closed: bool = True, **over) -> MonitorConfig:
    p = {"loop_rate_hz": rate, "closed_loop": closed, "controller.numerator": [0.02329, -0.02058, 0.00454],
         "controller.denominator": [1.0, -1.0, 0.0], "modes.natural_frequency_hz": [3.0],
         "modes.damping_ratio": [0.2], "modes.gain": [1.0], **over}
    return MonitorConfig.from_params(validate_params(p))


@pytest.fixture(scope="module")
def sim():
    """Two seconds of a two-mode plant at 4096 Hz in closed loop with a frequency change and NaN samples."""
    modes = [PlantMode(3.25, 0.235, 11.81), PlantMode(33.0, 0.0171, 0.159)]
    t = time_vector(RATE, 2.0)
    r = square_wave(t, 2.0, 0.05)
    v = white_noise(t.size, 1e-3, np.random.default_rng(2))
    ctrl = PAPER_PID
    return simulate_modes(modes, RATE, r=r, controller=ctrl, noise=v, input_delay=4,
                          changes=[ModalChange(1, "frequency", -0.05, 1.0)],
                          sensor_faults=[SensorFault("nan", 1.5, 0.2, fraction=0.05)],
                          rng=np.random.default_rng(3))


EVENTS = [{"time_s": 0.0, "event": "start", "active": []},
          {"time_s": 1.0, "event": "onset", "fault": {"mode": 2, "quantity": "frequency"}, "active": [{"mode": 2}]}]


def _bits(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).view(np.uint64)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_round_trip_is_bit_exact(tmp_path, sim, storage):
    bag = write_bag(tmp_path / "b", RATE, sim.u, sim.y, sim.r, truth_modal=sim.modal, truth_rate_hz=10.0,
                    fault_events=EVENTS, storage=storage)
    sig = read_signals(bag, _cfg())
    assert sig.storage == storage
    np.testing.assert_array_equal(_bits(sig.r), _bits(sim.r))
    np.testing.assert_array_equal(_bits(sig.u), _bits(sim.u))
    np.testing.assert_array_equal(_bits(sig.y), _bits(sim.y))  # NaN samples included, bit for bit
    assert sig.nonfinite == np.count_nonzero(np.isnan(sim.y)) > 0
    assert sig.nonfinite_by_signal["output"] == sig.nonfinite
    assert sig.t0_ns == DEFAULT_T0_NS
    # integer-ns log times: t_k = k/rate to within half a nanosecond
    np.testing.assert_allclose(sig.t, sim.t, rtol=0, atol=0.5e-9 + 1e-15 * sim.t[-1])
    # truth: one message every 0.1 s with the simulator's modal values at that sample
    idx = np.flatnonzero(np.abs(sim.t * 10 - np.rint(sim.t * 10)) < 0.5 / RATE * 10)  # samples nearest j/10 s
    assert idx.size == 20
    np.testing.assert_allclose(sig.truth_t, sim.t[idx], atol=1e-9)
    assert sig.truth_modes.shape == (idx.size, 2, 6)
    np.testing.assert_array_equal(sig.truth_modes[:, :, :3], sim.modal[:, idx, :].transpose(1, 0, 2))
    np.testing.assert_array_equal(sig.truth_modes[:, :, 3:], 0.0)
    assert sig.truth_modes[-1, 1, 0] == pytest.approx(33.0 * 0.95, rel=1e-12)
    assert sig.truth_fault == EVENTS


def test_bytes_are_deterministic(tmp_path, sim):
    for name in ("a", "b"):
        write_bag(tmp_path / name / "bag", RATE, sim.u, sim.y, sim.r, truth_modal=sim.modal, fault_events=EVENTS)
    files = sorted(p.name for p in (tmp_path / "a" / "bag").iterdir())
    assert files == ["bag.mcap", "metadata.yaml"]
    for f in files:
        assert (tmp_path / "a" / "bag" / f).read_bytes() == (tmp_path / "b" / "bag" / f).read_bytes()


def test_float64_cdr_matches_typestore():
    vals = np.array([0.0, -1.5, 1e-300, np.inf, np.nan, 3.14159])
    ref = [bytes(TS.serialize_cdr(TS.types["std_msgs/msg/Float64"](data=v), "std_msgs/msg/Float64")) for v in vals]
    assert float64_cdr(vals) == ref


def test_mcap_library_reads_the_bag(tmp_path, sim):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = write_bag(tmp_path / "b", RATE, sim.u, sim.y, sim.r, truth_modal=sim.modal, fault_events=EVENTS)
    with open(bag / "b.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes and summary.statistics is not None
        assert summary.statistics.message_count == 3 * sim.t.size + 20 + len(EVENTS)
        got: dict[str, list] = {}
        times: dict[str, list] = {}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            if channel.topic == "/truth/modes":
                got.setdefault(channel.topic, []).append(list(decoded.data))
            elif channel.topic == "/truth/fault":
                got.setdefault(channel.topic, []).append(json.loads(decoded.data))
            else:
                got.setdefault(channel.topic, []).append(decoded.data)
                times.setdefault(channel.topic, []).append(message.log_time)
    np.testing.assert_array_equal(_bits(got["/plant_output"]), _bits(sim.y))
    np.testing.assert_array_equal(_bits(got["/plant_input"]), _bits(sim.u))
    np.testing.assert_array_equal(_bits(got["/reference"]), _bits(sim.r))
    assert times["/plant_output"][1] - times["/plant_output"][0] in (244140, 244141)
    assert got["/truth/fault"] == EVENTS
    assert np.asarray(got["/truth/modes"][0]).reshape(2, 6)[0, 0] == sim.modal[0, 0, 0]


def test_open_loop_needs_no_reference(tmp_path, sim):
    bag = write_bag(tmp_path / "b", RATE, sim.u, sim.y)
    sig = read_signals(bag, _cfg(closed=False))
    assert sig.r is None and sig.truth_modes is None and sig.truth_fault is None
    with pytest.raises(BagError, match="'/reference' is not in the bag"):
        read_signals(bag, _cfg(closed=True))


def test_joint_state_topics(tmp_path):
    n, rate = 50, 100.0
    bag = tmp_path / "js"
    js, hdr = TS.types["sensor_msgs/msg/JointState"], TS.types["std_msgs/msg/Header"]
    stamp = TS.types["builtin_interfaces/msg/Time"]
    rng = np.random.default_rng(0)
    pos, eff, r = rng.standard_normal((3, n))
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=TS)
        cr = w.add_connection("/reference", "std_msgs/msg/Float64", typestore=TS)
        for k in range(n):
            ns = DEFAULT_T0_NS + k * 10**7
            recv = ns + 123_456  # receive time differs from the header stamp
            msg = js(header=hdr(stamp=stamp(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=""),
                     name=["base", "arm"], position=np.array([0.0, pos[k]]), velocity=np.zeros(2),
                     effort=np.array([0.0, eff[k]]))
            w.write(cj, recv, TS.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
            w.write(cr, recv, float64_cdr(np.array([r[k]]))[0])
    cfg = _cfg(rate, **{"input.topic": "/joint_states", "input.type": "sensor_msgs/msg/JointState",
                        "input.joint": "arm", "input.field": "effort",
                        "output.topic": "/joint_states", "output.type": "sensor_msgs/msg/JointState",
                        "output.joint": "arm", "output.field": "position"})
    sig = read_signals(bag, cfg)
    np.testing.assert_array_equal(sig.y, pos)
    np.testing.assert_array_equal(sig.u, eff)
    np.testing.assert_array_equal(sig.r, r)
    assert sig.t0_ns == DEFAULT_T0_NS  # header stamp, not the log time
    cfg = _cfg(rate, **{**cfg.params, "output.joint": "wrist"})
    with pytest.raises(BagError, match="joint 'wrist'"):
        read_signals(bag, cfg)


def _raw_bag(path, counts: dict[str, int], rate: float = RATE, msgtype: str = "std_msgs/msg/Float64"):
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, count in counts.items():
            c = w.add_connection(topic, msgtype, typestore=TS)
            for k in range(count):
                w.write(c, DEFAULT_T0_NS + int(k * 1e9 / rate), float64_cdr(np.array([float(k)]))[0])
    return path


def test_validation_errors(tmp_path, sim):
    cfg = _cfg()
    good = write_bag(tmp_path / "good", RATE, sim.u, sim.y, sim.r)
    cases = {
        "not found": tmp_path / "missing",
        "no metadata.yaml": tmp_path,
    }
    for pattern, bag in cases.items():
        with pytest.raises(BagError, match=pattern):
            read_signals(bag, cfg)
    # truncated and corrupt storage files
    trunc = tmp_path / "trunc"
    shutil.copytree(good, trunc)
    data = (trunc / "good.mcap").read_bytes()
    (trunc / "good.mcap").write_bytes(data[: len(data) // 2])
    corrupt = tmp_path / "corrupt"
    shutil.copytree(good, corrupt)
    bad = bytearray(data)
    bad[len(bad) // 3: len(bad) // 3 + 4096] = b"\xff" * 4096
    (corrupt / "good.mcap").write_bytes(bytes(bad))
    missing_file = tmp_path / "nofile"
    shutil.copytree(good, missing_file)
    (missing_file / "good.mcap").unlink()
    for bag in (trunc, corrupt, missing_file):
        with pytest.raises(BagError, match="unreadable, truncated or corrupt") as exc:
            read_signals(bag, cfg)
        assert "\n" not in str(exc.value)
    empty = _raw_bag(tmp_path / "empty", {"/plant_input": 0, "/plant_output": 0})
    with pytest.raises(BagError, match="empty"):
        read_signals(empty, cfg)
    with pytest.raises(BagError, match="'/nope' is not in the bag"):
        read_signals(good, _cfg(**{"output.topic": "/nope"}))
    with pytest.raises(BagError, match="type std_msgs/msg/Float64"):
        read_signals(good, _cfg(**{"output.type": "sensor_msgs/msg/JointState"}))
    uneven = _raw_bag(tmp_path / "uneven", {"/reference": 100, "/plant_input": 100, "/plant_output": 50})
    with pytest.raises(BagError, match="counts differ .* cannot align"):
        read_signals(uneven, cfg)
    with pytest.raises(BagError, match="loop_rate_hz is 1000"):
        read_signals(good, _cfg(1000.0))
    # a rate within the tolerance of the mean spacing is accepted (jitter-free bag, exact rate)
    assert read_signals(good, cfg).n == sim.t.size


def test_atomic_writer_refuses_existing_and_cleans_up(tmp_path, sim):
    target = tmp_path / "bag"
    write_bag_atomic(target, rate_hz=RATE, u=sim.u, y=sim.y, r=sim.r)
    assert bag_info(target)["topics"]["/plant_output"] == ("std_msgs/msg/Float64", sim.t.size)
    assert sorted(p.name for p in target.iterdir()) == ["bag.mcap", "metadata.yaml"]
    with pytest.raises(FileExistsError):
        write_bag_atomic(target, rate_hz=RATE, u=sim.u, y=sim.y, r=sim.r)
    with pytest.raises(ValueError):
        write_bag_atomic(tmp_path / "bad", rate_hz=RATE, u=sim.u, y=sim.y[:-1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no temp or half-written bag left


@pytest.mark.parametrize("name,duration,overrides", [
    ("beam", 20, {"manipulation_start_s": 5.0, "manipulation_end_s": 19.0}),
    ("beam_fault", 30, {"fault_time_s": 20.0}),
])
def test_bundled_bags_match_their_scenario(repo, name, duration, overrides):
    """bags/ (scripts/make_bags.sh) holds exactly the scenario's samples and truth, within the size budget."""
    from additive_rsrivc_ros.config import load_config
    from additive_rsrivc_ros.sim.scenarios import build

    bag = repo / "bags" / name
    assert bag.is_dir(), "run: bash scripts/make_bags.sh"
    total = sum(p.stat().st_size for p in (repo / "bags").rglob("*") if p.is_file())
    assert total < 25e6
    sig = read_signals(bag, load_config(repo / "config" / f"{name}.yaml"))
    data = build(name, duration_s=float(duration), seed=0, **overrides)
    assert sig.n == data.t.size == duration * 4096 and sig.nonfinite == 0
    np.testing.assert_array_equal(_bits(sig.y), _bits(data.y))
    np.testing.assert_array_equal(_bits(sig.u), _bits(data.u))
    np.testing.assert_array_equal(_bits(sig.r), _bits(data.r))
    assert sig.truth_fault == data.fault_events
    k = np.rint(sig.truth_t * 4096).astype(int)
    np.testing.assert_array_equal(sig.truth_modes[:, :, :3], data.truth_all[:, k, :].transpose(1, 0, 2))


def _stamped_bag(path, stamps: dict[str, np.ndarray]):
    """Float64 topics with the given log times (ns); each message's value is its sample index k = (t - t0)/h."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, ts in stamps.items():
            c = w.add_connection(topic, "std_msgs/msg/Float64", typestore=TS)
            for t in ts:
                k = round((int(t) - DEFAULT_T0_NS) * RATE / 1e9)
                w.write(c, int(t), float64_cdr(np.array([float(k)]))[0])
    return path


def test_lost_messages_and_pauses_are_aligned_by_time(tmp_path):
    """The log time is the sample time (CONTRACT): a message lost on one topic no longer rejects the bag; the
    samples are matched by time (constant per-topic offsets allowed), the lost sample is NaN on a kept grid (no
    gap) and counted. A recording pause is a gap, not a wrong rate."""
    cfg = _cfg()
    n = 3000
    base = DEFAULT_T0_NS + (np.arange(n) * 1e9 / RATE).astype(np.int64)
    for k_lost in (5, 1234):     # early (inside the first samples that once fixed the offsets) and later
        lost = np.delete(base, k_lost)
        bag = _stamped_bag(tmp_path / f"lost{k_lost}", {"/reference": base + 30_000, "/plant_input": base + 60_000,
                                                        "/plant_output": lost})
        sig = read_signals(bag, cfg)
        assert sig.n == n and sig.unmatched_by_signal == {"output": 1, "reference": 0, "input": 0}
        assert np.flatnonzero(np.isnan(sig.y)).tolist() == [k_lost] and sig.nonfinite == 0
        ok = np.isfinite(sig.y)
        assert np.array_equal(sig.r, sig.u) and np.array_equal(sig.u[ok], sig.y[ok])   # r, u, y of one instant
        assert np.max(np.diff(sig.t)) < 1.5e9 / RATE * 1e-9
    dup = np.insert(base, 7, base[7])          # a message recorded twice: the surplus copy is left out
    bag = _stamped_bag(tmp_path / "dup", {"/reference": base, "/plant_input": dup, "/plant_output": base})
    sig = read_signals(bag, cfg)
    assert sig.n == n and sig.unmatched_by_signal["input"] == 1
    assert np.array_equal(sig.r, sig.u) and np.array_equal(sig.u, sig.y)
    pause = np.concatenate((base[:1000], base[1000:] + 2_000_000_000))     # 2 s pause in a 3 s record
    bag = _stamped_bag(tmp_path / "pause", {t: pause for t in ("/reference", "/plant_input", "/plant_output")})
    sig = read_signals(bag, cfg)
    assert sig.n == n and np.max(np.diff(sig.t)) == pytest.approx(2.0 + 1.0 / RATE)


def test_records_lost_inside_a_damaged_chunk_are_reported_as_corruption(tmp_path, sim):
    good = write_bag(tmp_path / "plain", RATE, sim.u, sim.y, sim.r, compress=False)
    data = bytearray((good / "plain.mcap").read_bytes())
    mid = len(data) // 2
    data[mid: mid + 2048] = bytes(range(256)) * 8
    (good / "plain.mcap").write_bytes(bytes(data))
    with pytest.raises(BagError, match="corrupt") as exc:
        read_signals(good, _cfg())
    assert "\n" not in str(exc.value)


def test_truth_messages_decoded_without_the_type_store_as_with_it():
    """The direct little-endian CDR reading of the truth topics gives what rosbags' type store gives (K = 1..4, the
    fault JSON with non-ASCII text); a truncated message is an error, not a short array."""
    from rosbags.typesys import Stores, get_typestore

    from additive_rsrivc_ros.io.bagio import (
        MULTIARRAY,
        STRING,
        _decode_multiarray,
        _decode_string,
        _multiarray,
        _string,
    )

    ts = get_typestore(Stores.ROS2_JAZZY)
    rng = np.random.default_rng(3)
    for k in (1, 2, 4):
        values = rng.normal(size=(k, 6))
        data = _multiarray(values)
        sizes, flat = _decode_multiarray(data)
        ref = ts.deserialize_cdr(data, MULTIARRAY)
        assert sizes == [d.size for d in ref.layout.dim] == [k, 6]
        np.testing.assert_array_equal(flat, ref.data)
        np.testing.assert_array_equal(flat.reshape(k, 6), values)
        with pytest.raises(ValueError, match="truncated"):
            _decode_multiarray(data[:-8])
    text = '{"mode": 2, "quantity": "natural frequency", "note": "Δf −5 %"}'
    assert _decode_string(_string(text)) == ts.deserialize_cdr(_string(text), STRING).data == text


def test_metadata_custom_data_is_read_when_libyaml_fails(repo, monkeypatch):
    """The storage and custom data come from metadata.yaml by libyaml when PyYAML has it; a document libyaml
    rejects is read by the pure-Python parser, never dropped in silence."""
    import yaml

    from additive_rsrivc_ros.io import bagio

    fast = bagio._metadata_info(repo / "bags" / "beam_fault")
    assert fast["storage"] == "mcap" and "additive_rsrivc.parameters" in fast["metadata"]

    class Refuses(yaml.SafeLoader):
        def __init__(self, stream):
            raise yaml.YAMLError("libyaml refused the document")

    monkeypatch.setattr(yaml, "CSafeLoader", Refuses, raising=False)
    assert bagio._metadata_info(repo / "bags" / "beam_fault") == fast
