"""Record -> identify without guesses (``--modes auto --out-params``) -> monitor with the written params file."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from figure_checks import assert_figure_matches_table, parse_svg
from frf_cases import CONTROLLER, DELAY, FS, MODES, no_guess_params_yaml

from additive_rsrivc_ros.cli import diagnose, identify
from additive_rsrivc_ros.config import load_config, load_params_file
from additive_rsrivc_ros.io.bagio import write_bag
from additive_rsrivc_ros.sim.simulate import simulate_modes, square_wave, white_noise

PARAMS = no_guess_params_yaml()


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("automodes")
    rng = np.random.default_rng(21)
    t = np.arange(int(30 * FS)) / FS
    r = square_wave(t, 0.5, 1.0) + white_noise(t.size, 0.05, rng)
    sim = simulate_modes(MODES, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                         noise=white_noise(t.size, 0.01, rng), rng=rng)
    params = d / "params.yaml"
    params.write_text(PARAMS)
    return str(write_bag(d / "bag", FS, sim.u, sim.y, sim.r)), str(params)


def test_params_without_guesses_load_as_automatic(bag):
    assert load_config(bag[1]).auto_modes


def test_identify_finds_the_modes_and_writes_a_params_file_diagnose_runs_with(bag, tmp_path, capsys):
    bag_path, params = bag
    out, out_params = tmp_path / "id.json", tmp_path / "found.yaml"
    argv = [bag_path, "--params-file", params, "--out", str(out), "--modes", "auto", "--out-params",
            str(out_params), "--baseline"]
    assert identify.main(argv) == 0
    doc = json.loads(out.read_text())
    assert len(doc["modes"]) == 2 and doc["converged"]
    for m, truth in zip(doc["modes"], MODES, strict=True):
        assert abs(m["natural_frequency_hz"] / truth.natural_frequency_hz - 1.0) < 0.01
        assert abs(m["damping_ratio"] / truth.damping_ratio - 1.0) < 0.15
    table = doc["order_selection"]
    assert [row["K"] for row in table if row["accepted"]] == [2]
    # the order scan as a figure next to the JSON: one marker per fitted mode of each order, K = 2 marked
    figure = tmp_path / "id.order.svg"
    assert doc["order_selection_figure"] == str(figure)
    assert assert_figure_matches_table(parse_svg(figure.read_text()), table) == 2
    assert doc["frf"]["band_hz"][0] < 5.0 < 40.0 < doc["frf"]["band_hz"][1]
    assert any(abs(p / 40.0 - 1.0) < 0.02 for p in doc["frf"]["peaks_hz"])
    # the written params file: complete, the identified modes, the baseline, the input params kept
    p = load_params_file(out_params)
    assert p["modes.natural_frequency_hz"] == [m["natural_frequency_hz"] for m in doc["modes"]]
    assert p["faults.baseline.gain"] == [m["gain"] for m in doc["modes"]]
    assert p["modes.memory_s"] == [5.0, 5.0] and p["input_delay_samples"] == DELAY
    assert "# " in out_params.read_text()  # commented
    # the monitor (offline) runs with it and tracks the same modes
    ddir = tmp_path / "diag"
    assert diagnose.main([bag_path, "--params-file", str(out_params), "--out", str(ddir), "--no-report",
                          "--quiet"]) == 0
    rows = list(csv.DictReader((ddir / "estimates.csv").open()))
    last = {int(row["mode"]): row for row in rows}
    assert sorted(last) == [1, 2]
    for i, m in enumerate(doc["modes"], 1):
        f = float(last[i]["natural_frequency_hz"])
        std = float(last[i]["natural_frequency_hz_std"])
        assert abs(f - m["natural_frequency_hz"]) < max(0.01 * m["natural_frequency_hz"], 4 * std)
    summary = json.loads((ddir / "summary.json").read_text())
    assert summary["verdict"] == "OK"  # healthy plant, baseline from the identification: no structural alarm


def test_bad_modes_argument_and_baseline_without_out_params(bag, tmp_path, capsys):
    bag_path, params = bag
    with pytest.raises(SystemExit):
        identify.main([bag_path, "--params-file", params, "--out", str(tmp_path / "a.json"), "--modes", "zero"])
    assert identify.main([bag_path, "--params-file", params, "--out", str(tmp_path / "a.json"), "--baseline"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("rsrivc_identify: error:") and "out-params" in err


def test_diagnose_without_guesses_starts_from_the_data(bag, tmp_path, capsys):
    """rsrivc_diagnose with no guesses: modes found on the first init_duration_s, then tracked."""
    bag_path, params = bag
    ddir = tmp_path / "diag"
    assert diagnose.main([bag_path, "--params-file", params, "--out", str(ddir), "--quiet"]) == 0
    assert "no mode guesses: found 2 mode(s)" in capsys.readouterr().err
    # report.html shows why K = 2: the automatic start's order scan, as summary.json's mode_finding has it
    finding = json.loads((ddir / "summary.json").read_text())["mode_finding"]
    html = (ddir / "report.html").read_text()
    assert "Model order: why K modes" in html
    assert assert_figure_matches_table(parse_svg(html[html.index('<svg', html.index("why K modes")):]),
                                       finding["order_selection"]) == finding["K"] == 2
    rows = list(csv.DictReader((ddir / "estimates.csv").open()))
    last = {int(row["mode"]): row for row in rows}
    assert sorted(last) == [1, 2]
    for i, truth in enumerate(MODES, 1):
        assert abs(float(last[i]["natural_frequency_hz"]) / truth.natural_frequency_hz - 1.0) < 0.01
        assert abs(float(last[i]["damping_ratio"]) / truth.damping_ratio - 1.0) < 0.15
    summary = json.loads((ddir / "summary.json").read_text())
    assert summary["verdict"] != "FAULT" and summary["K"] == 2


def test_pipeline_with_empty_guesses_tracks_the_right_modes(bag):
    """The core path the node and rsrivc_diagnose share: the pipeline without guesses finds the modes on the init
    data itself (core/identification/autostart.py), then tracks them."""
    from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
    from additive_rsrivc_ros.io.bagio import read_signals

    cfg = load_config(bag[1])
    sig = read_signals(bag[0], cfg)
    pipe = MonitorPipeline(cfg)
    step = int(cfg.loop_rate_hz)
    for a in range(0, sig.t.size, step):
        pipe.push(sig.t[a:a + step], sig.r[a:a + step], sig.u[a:a + step], sig.y[a:a + step])
    assert pipe.K == 2 and [m.memory_s for m in pipe.cfg.modes] == [5.0, 5.0]
    modal = pipe.modal()
    for m, truth in zip(modal, MODES, strict=True):
        assert abs(m[0] / truth.natural_frequency_hz - 1.0) < 0.01
        assert abs(m[1] / truth.damping_ratio - 1.0) < 0.15


def test_estimator_without_guesses_is_a_clear_error(bag):
    from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC

    with pytest.raises(ValueError, match="no mode guesses"):
        RecursiveAdditiveSRIVC.from_config(load_config(bag[1]))
