"""Bags recorded on a block topic (rows ``index, r, u, y``) read by ``rsrivc_diagnose`` through the node's own block
logic: the same verdict as the per-sample bag, duplicates and gaps counted, and a loop rate that contradicts the
index's advance refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Writer

from additive_rsrivc_ros.cli import diagnose
from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.io.bagio import MULTIARRAY, BagError, _typestore, read_signals

TOPIC = "/controller/block"


def _block_cdr(k: np.ndarray, r: np.ndarray, u: np.ndarray, y: np.ndarray) -> bytes:
    types = _typestore().types
    dim = types["std_msgs/msg/MultiArrayDimension"]
    layout = types["std_msgs/msg/MultiArrayLayout"](
        dim=[dim(label="sample", size=k.size, stride=4 * k.size), dim(label="signal", size=4, stride=4)], data_offset=0)
    rows = np.column_stack([k.astype(float), r, u, y])
    return bytes(_typestore().serialize_cdr(types[MULTIARRAY](layout=layout, data=rows.ravel()), MULTIARRAY))


def write_block_bag(path: Path, r, u, y, *, log_rate_hz: float, rows: int = 100, skip: int | None = None,
                    repeat: int | None = None, t0_ns: int = 1_700_000_000 * 10**9) -> Path:
    """One block of ``rows`` rows per message, logged when its last row is taken at ``log_rate_hz``; block number
    ``skip`` is never written, block ``repeat`` is written twice (a retransmission)."""
    with Writer(path, version=8) as w:
        conn = w.add_connection(TOPIC, MULTIARRAY, typestore=_typestore())
        for b, a in enumerate(range(0, u.size - rows + 1, rows)):
            if b == skip:
                continue
            k = np.arange(a, a + rows)
            log_ns = t0_ns + int(round((a + rows - 1) / log_rate_hz * 1e9))
            data = _block_cdr(k, r[k], u[k], y[k])
            for _ in range(2 if b == repeat else 1):
                w.write(conn, log_ns, data)
    return path


@pytest.fixture
def block_params(repo, tmp_path) -> Path:
    doc = yaml.safe_load((repo / "config" / "beam_fault.yaml").read_text())
    node = next(iter(doc))
    doc[node]["ros__parameters"]["block"] = {"topic": TOPIC}
    p = tmp_path / "block.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_a_block_topic_bag_is_diagnosed_like_the_per_sample_bag(repo, tmp_path, block_params):
    cfg = load_config(block_params)
    sig = read_signals(repo / "bags" / "beam_fault", load_config(repo / "config" / "beam_fault.yaml"))
    bag = write_block_bag(tmp_path / "blocks", sig.r, sig.u, sig.y, log_rate_hz=4096.0, skip=500, repeat=800)
    got = read_signals(bag, cfg)
    assert got.block["duplicate_samples"] == 100 and got.block["missing_samples"] == 100
    assert got.block["gaps"] == 1 and got.block["malformed"] == 0
    n_blocks = sig.u.size // 100
    assert got.n == 100 * (n_blocks - 1)
    kept = np.ones(100 * n_blocks, bool)
    kept[50_000:50_100] = False
    np.testing.assert_array_equal(got.y, sig.y[:100 * n_blocks][kept])
    # samples timed by the index: the skipped block leaves a 100-sample hole, nothing else moves
    # (stamps are whole nanoseconds, as in every bag)
    np.testing.assert_allclose(np.diff(got.t)[:49_999], 1 / 4096, rtol=0, atol=1e-9)
    assert np.diff(got.t)[49_999] == pytest.approx(101 / 4096, abs=1e-9)
    out = tmp_path / "diag"
    assert diagnose.main([str(bag), "--params-file", str(block_params), "--out", str(out), "--no-report",
                          "--quiet"]) in (0, 2, 3)
    summary = json.loads((out / "summary.json").read_text())
    rows = list((out / "events.csv").read_text().splitlines())[1:]
    assert summary["verdict"] == "FAULT", summary["verdict_text"]
    assert rows and all(",2,natural_frequency,down," in f",{r}," or r.split(",")[1:3] == ["2", "natural_frequency"]
                        for r in rows), rows


def test_blocks_that_contradict_loop_rate_are_refused_in_one_line(repo, tmp_path, block_params):
    sig = read_signals(repo / "bags" / "beam_fault", load_config(repo / "config" / "beam_fault.yaml"))
    n = 4096 * 5
    bag = write_block_bag(tmp_path / "slow", sig.r[:n], sig.u[:n], sig.y[:n], log_rate_hz=1000.0)
    with pytest.raises(BagError, match=r"loop_rate_hz 4096 disagrees with the data's timing: the index on "
                                       r"'/controller/block' advances at 1000 Hz") as exc:
        read_signals(bag, load_config(block_params))
    assert "\n" not in str(exc.value)


def test_a_block_topic_of_another_type_or_absent_is_named(repo, tmp_path, block_params):
    with pytest.raises(BagError, match="configured block topic '/controller/block' is not in the bag"):
        read_signals(repo / "bags" / "beam_fault", load_config(block_params))
