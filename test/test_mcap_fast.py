"""The bulk MCAP reader returns exactly what the generic rosbags reader returns."""
import numpy as np
import pytest

from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.io import bagio, mcap_fast


def _bits(a):
    return None if a is None else np.asarray(a).view(np.uint8)


def _read_both(bag, cfg, monkeypatch):
    fast = bagio.read_signals(bag, cfg)
    with monkeypatch.context() as m:
        m.setattr(bagio, "_read_fast", lambda *a: None)
        slow = bagio.read_signals(bag, cfg)
    return fast, slow


def _assert_same(fast, slow):
    for f in ("t", "r", "u", "y", "truth_t", "truth_modes"):
        np.testing.assert_array_equal(_bits(getattr(fast, f)), _bits(getattr(slow, f)), err_msg=f)
    assert fast.truth_fault == slow.truth_fault and fast.t0_ns == slow.t0_ns and fast.nonfinite == slow.nonfinite


@pytest.mark.parametrize("name", ["beam", "beam_fault"])
def test_bundled_bags_read_identically(repo, name, monkeypatch):
    cfg = load_config(repo / "config" / f"{name}.yaml")
    fast, slow = _read_both(repo / "bags" / name, cfg, monkeypatch)
    assert fast.n == slow.n > 0
    _assert_same(fast, slow)


def test_stream_walk_without_chunk_index_reads_identically(repo, monkeypatch):
    """Files without a summary are walked record by record (StreamReader): the same samples."""
    cfg = load_config(repo / "config" / "beam.yaml")
    bag = repo / "bags" / "beam"
    calls = []
    monkeypatch.setattr(mcap_fast, "_indexed_chunks", lambda fh, *window: calls.append(1))  # returns None
    fast, slow = _read_both(bag, cfg, monkeypatch)
    assert calls, "the bulk reader was not used"
    _assert_same(fast, slow)


def test_nan_samples_and_open_loop_bags(tmp_path, monkeypatch):
    """NaN payloads and a bag without /reference (open loop) agree bit for bit too."""
    from additive_rsrivc_ros.sim.scenarios import build

    data = build("sensor_fault", duration_s=400.0, seed=1, fault_time_s=20.0)
    path = data.write_bag(tmp_path / "sf")
    fast, slow = _read_both(path, data.config, monkeypatch)
    assert fast.nonfinite > 0
    _assert_same(fast, slow)
    ol = build("open_loop_multisine", duration_s=5.0, seed=2)
    path = ol.write_bag(tmp_path / "ol")
    fast, slow = _read_both(path, ol.config, monkeypatch)
    assert fast.r is None and fast.n == ol.t.size
    _assert_same(fast, slow)


def test_scan_records_stops_at_a_truncated_record():
    # a message record (opcode 5) whose length runs past the buffer: nothing is returned, used < size
    rec = bytes([5]) + (100).to_bytes(8, "little") + bytes(10)
    chan, logt, off, size, chrec, used = mcap_fast.scan_records(np.frombuffer(rec, dtype=np.uint8))
    assert chan.size == 0 and used == 0 < len(rec)


def test_a_message_record_shorter_than_its_header_goes_to_rosbags(repo, monkeypatch):
    """A message record whose length is below the 22-byte message header has a negative payload size: the bulk
    reader hands the file to rosbags (which judges it) instead of reading a payload from the wrong bytes."""
    cfg = load_config(repo / "config" / "beam.yaml")
    bag = repo / "bags" / "beam"
    scan = mcap_fast.scan_records

    def short_record(buf):
        chan, logt, off, size, chrec, used = scan(buf)
        size = size.copy()
        size[:1] = -3
        return chan, logt, off, size, chrec, used

    monkeypatch.setattr(mcap_fast, "scan_records", short_record)
    with pytest.raises(mcap_fast.FastPathUnsupported, match="shorter than its header"):
        mcap_fast.read_topics(next(bag.glob("*.mcap")), {"/plant_output"})
    fast, slow = _read_both(bag, cfg, monkeypatch)     # read_signals falls back to rosbags: the same samples
    _assert_same(fast, slow)
