"""``--start``/``--end``: the one rule (relative or Unix seconds), the reader skipping what lies outside, and the
one-line errors of bad ranges, on real rosbag2 files (MCAP through the bulk reader and through rosbags, sqlite3)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from additive_rsrivc_ros.cli import identify
from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.io import mcap_fast
from additive_rsrivc_ros.io.bagio import DEFAULT_T0_NS, BagError, read_signals, write_bag
from additive_rsrivc_ros.io.timerange import ABSOLUTE_FROM_S, TimeRange
from additive_rsrivc_ros.sim.experiments import close_pair_params_yaml

RATE = 1000.0
N = 20_000        # 20 s


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """The same 20 s of samples (the value of each sample is its index) as MCAP and sqlite3, with a params file."""
    d = tmp_path_factory.mktemp("range")
    k = np.arange(N, dtype=float)
    params = d / "params.yaml"
    params.write_text(close_pair_params_yaml(rate_hz=RATE))
    out = {"params": params}
    for storage in ("mcap", "sqlite3"):
        out[storage] = write_bag(d / storage, RATE, k + 0.25, k + 0.5, k, storage=storage)
    return out


def test_one_rule_relative_below_1e9_absolute_above():
    t0_ns = DEFAULT_T0_NS
    rel = TimeRange(5.0, 7.5).resolve(t0_ns, t0_ns + 19_999 * 10**6, 1e-3)
    ab = TimeRange(t0_ns * 1e-9 + 5.0, t0_ns * 1e-9 + 7.5).resolve(t0_ns, t0_ns + 19_999 * 10**6, 1e-3)
    assert (rel.start_s, rel.end_s) == (5.0, 7.5)
    assert math.isclose(ab.start_s, 5.0, abs_tol=1e-6) and math.isclose(ab.end_s, 7.5, abs_tol=1e-6)
    assert rel.start_ns == t0_ns + 5 * 10**9 and rel.to_dict()["record_duration_s"] == pytest.approx(20.0)
    mixed = TimeRange(5.0, t0_ns * 1e-9 + 7.5).resolve(t0_ns, t0_ns + 19_999 * 10**6, 1e-3)
    assert math.isclose(mixed.end_s, 7.5, abs_tol=1e-6)
    assert ABSOLUTE_FROM_S == 1e9


@pytest.mark.parametrize(("start", "end", "words"), [
    ("nan", None, "finite"), (None, "inf", "finite"), ("ten", None, "number"), ("5", "5", "after"),
    ("8", "3", "after"), ("-1", None, "before the record"), ("25", None, "beyond the record"),
    (None, "21", "beyond the record"), ("1000000000", None, "before the record"),
])
def test_bad_ranges_are_one_line_errors(bags, tmp_path, capsys, start, end, words):
    argv = [str(bags["mcap"]), "--params-file", str(bags["params"]), "--out", str(tmp_path / "id.json")]
    argv += (["--start", start] if start is not None else []) + (["--end", end] if end is not None else [])
    assert identify.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rsrivc_identify: error:") and words in err[0], err
    assert not (tmp_path / "id.json").exists()


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_range_reads_exactly_the_samples_in_it_in_record_time(bags, storage):
    cfg = load_config(bags["params"])
    whole = read_signals(bags[storage], cfg)
    part = read_signals(bags[storage], cfg, TimeRange(4.25, 9.0))
    keep = (whole.t >= 4.25 - 1e-9) & (whole.t < 9.0 - 1e-9)
    assert part.n == int(keep.sum()) == 4750
    np.testing.assert_array_equal(part.t, whole.t[keep])       # times stay the record's
    np.testing.assert_array_equal(part.y, whole.y[keep])
    np.testing.assert_array_equal(part.r, whole.r[keep])
    assert part.y[0] == 4250.5 and part.t0_ns == whole.t0_ns
    assert part.time_range["start_s"] == 4.25 and part.time_range["end_s"] == 9.0
    tail = read_signals(bags[storage], cfg, TimeRange(start=18.0))           # open end: to the record's end
    assert tail.n == 2000 and tail.y[-1] == N - 1 + 0.5


def test_the_bulk_mcap_reader_skips_the_chunks_outside_the_range(bags, monkeypatch):
    """Chunks outside the range are never decompressed (about 7 s of this bag per chunk)."""
    import mcap.stream_reader as sr

    calls = []
    real = sr.get_chunk_data_stream

    def counting(chunk, *a, **kw):
        calls.append((chunk.message_start_time, chunk.message_end_time))
        return real(chunk, *a, **kw)

    monkeypatch.setattr(sr, "get_chunk_data_stream", counting)
    files = sorted(bags["mcap"].glob("*.mcap"))
    mcap_fast.read_topics(files[0], {"/plant_output"})
    n_all = len(calls)
    calls.clear()
    lo = DEFAULT_T0_NS + 10 * 10**9
    out = mcap_fast.read_topics(files[0], {"/plant_output"}, lo, lo + 10**9)
    times = out["/plant_output"][0]
    assert times.size == 1000 and times[0] == lo and times[-1] == lo + 999 * 10**6
    assert n_all >= 3 and len(calls) <= 2 and len(calls) < n_all, (n_all, len(calls))
    assert all(e >= lo and s < lo + 10**9 for s, e in calls)


def test_range_errors_name_the_bag(bags):
    cfg = load_config(bags["params"])
    with pytest.raises(BagError, match="beyond the record"):
        read_signals(bags["sqlite3"], cfg, TimeRange(start=30.0))


def test_diagnose_with_a_range_reports_in_the_records_time(repo, tmp_path, capsys):
    """The bundled beam_fault bag (mode 2's frequency -5 % at 20 s) from 6 s on: the estimates start after 6 s, the
    event's onset is the record's 20 s (not 14 s), the verdict's intervals lie in the range, summary.json says which."""
    import csv

    from additive_rsrivc_ros.cli import diagnose

    bag, params = str(repo / "bags" / "beam_fault"), str(repo / "config" / "beam_fault.yaml")
    out = tmp_path / "d"
    assert diagnose.main([bag, "--params-file", params, "--out", str(out), "--no-report", "--quiet",
                          "--start", "6"]) == 0
    rows = list(csv.DictReader((out / "estimates.csv").open()))
    assert rows and min(float(r["time_s"]) for r in rows) >= 6.0
    events = list(csv.DictReader((out / "events.csv").open()))
    assert [(e["mode"], e["quantity"]) for e in events] == [("2", "natural_frequency")]
    assert 20.0 <= float(events[0]["onset_time_s"]) < 21.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["time_range"]["start_s"] == 6.0 and summary["duration_s"] == pytest.approx(24.0, abs=1e-3)
    assert all(b["start_s"] >= 6.0 for b in summary["blind_intervals"])
    assert "6-30 s of the 30 s record" in capsys.readouterr().out
    assert diagnose.main([bag, "--params-file", params, "--out", str(tmp_path / "e"), "--end", "31"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "beyond the record" in err[0] and not (tmp_path / "e").exists()


def test_fleet_passes_the_range_to_every_bag_and_keys_its_cache_by_it(repo, tmp_path):
    from additive_rsrivc_ros.cli.fleet import BagTask, run_bag
    from additive_rsrivc_ros.cli.fleet_cache import ResultCache

    bag, params = str(repo / "bags" / "beam_fault"), str(repo / "config" / "beam_fault.yaml")
    res = run_bag(BagTask("b", bag, params, str(tmp_path / "b"), report=False, start="15", end="25"))
    assert res["ok"], res
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["time_range"]["start_s"] == 15.0 and summary["time_range"]["end_s"] == 25.0
    cache = ResultCache(tmp_path)
    keys = {cache.key(bag, params, None, False, "o", r) for r in ((None, None), ("15", "25"), ("15", None))}
    assert len(keys) == 3
    assert cache.key(bag, params, None, False, "o") == cache.key(bag, params, None, False, "o", (None, None))
