"""``rsrivc_identify`` end to end: simulated bag with known truth -> JSON of ../shared/CONTRACT.md."""

from __future__ import annotations

import json

import numpy as np
import pytest

from additive_rsrivc_ros.cli.identify import main
from additive_rsrivc_ros.core.model import modal_from_theta
from additive_rsrivc_ros.io.bagio import write_bag
from additive_rsrivc_ros.sim.independent import MODE, PAPER_THETAS, PID_DEN, PID_NUM, simulate

RATE = 20.0
PARAMS = """additive_rsrivc_monitor:
  ros__parameters:
    loop_rate_hz: 20.0
    closed_loop: {closed}
    controller.numerator: [0.02329, -0.02058, 0.00454]
    controller.denominator: [1.0, -1.0, 0.0]
    modes.natural_frequency_hz: [{f1}, {f2}]
    modes.damping_ratio: [{z1}, {z2}]
    modes.gain: [3.1, 0.95]
"""


def _params(tmp_path, closed: bool) -> str:
    m1, m2 = (modal_from_theta(t) for t in PAPER_THETAS)
    text = PARAMS.format(closed=str(closed).lower(), f1=m1[0] * 1.05, f2=m2[0] * 0.95, z1=m1[1] * 1.1, z2=m2[1] * 0.9)
    p = tmp_path / f"params_{closed}.yaml"
    p.write_text(text)
    return str(p)


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("bags")
    rng = np.random.default_rng(7)
    n = 4000
    r = rng.standard_normal(n)
    v = 0.1 * rng.standard_normal(n)
    u, y = simulate(PAPER_THETAS, [MODE, MODE], 1 / RATE, r=r, controller=(PID_NUM, PID_DEN), noise=v)
    closed = write_bag(d / "closed", RATE, u, y, r)
    uo = rng.standard_normal(n)
    uo, yo = simulate(PAPER_THETAS, [MODE, MODE], 1 / RATE, u=uo, noise=v)
    opened = write_bag(d / "open", RATE, uo, yo)
    return {"closed": str(closed), "open": str(opened)}


@pytest.mark.parametrize("closed,method,expect", [(True, None, "additive-clsrivc"), (False, None, "additive-srivc"),
                                                  (True, "srivc", "srivc")])
def test_identify_writes_the_contract_json(tmp_path, bags, capsys, closed, method, expect):
    out = tmp_path / "model.json"
    argv = [bags["closed" if closed else "open"], "--params-file", _params(tmp_path, closed), "--out", str(out)]
    if method:
        argv += ["--method", method]
    assert main(argv) == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == expect and doc["converged"] is True and doc["iterations"] >= 1
    assert set(doc) >= {"method", "converged", "iterations", "modes", "residual_variance"}
    assert len(doc["modes"]) == 2
    for mode, truth in zip(doc["modes"], PAPER_THETAS, strict=True):
        for key in ("theta", "theta_std", "natural_frequency_hz", "damping_ratio", "gain",
                    "natural_frequency_hz_std", "damping_ratio_std", "gain_std"):
            assert key in mode
        th, sd = np.array(mode["theta"]), np.array(mode["theta_std"])
        assert np.all(sd > 0)
        # the truth lies within 5 reported standard deviations (a 5-sigma miss has probability ~6e-7)
        assert np.all(np.abs(th - truth) <= 5 * sd), (th, truth, sd)
        f_true = modal_from_theta(truth)[0]
        assert abs(mode["natural_frequency_hz"] - f_true) <= 5 * mode["natural_frequency_hz_std"]
    assert doc["residual_variance"] == pytest.approx(0.01, rel=0.15)
    assert "rsrivc_identify:" in capsys.readouterr().out


def test_bad_inputs_give_one_line_and_nonzero_exit(tmp_path, bags, capsys):
    out = str(tmp_path / "m.json")
    params = _params(tmp_path, True)
    cases = [
        [str(tmp_path / "missing_bag"), "--params-file", params, "--out", out],
        [bags["closed"], "--params-file", str(tmp_path / "nope.yaml"), "--out", out],
        [bags["open"], "--params-file", params, "--out", out],          # closed-loop params, no /reference
        [bags["closed"], "--params-file", params, "--out", str(tmp_path / "no" / "dir" / "m.json")],
    ]
    for argv in cases:
        assert main(argv) != 0
        err = capsys.readouterr().err.strip()
        assert err.startswith("rsrivc_identify: error:") and "\n" not in err and "Traceback" not in err


def test_unknown_method_is_rejected(tmp_path, bags):
    with pytest.raises(SystemExit) as exc:
        main([bags["closed"], "--params-file", _params(tmp_path, True), "--out", str(tmp_path / "x.json"),
              "--method", "magic"])
    assert exc.value.code != 0


def test_controller_that_does_not_stabilize_the_guess(tmp_path, bags, capsys):
    p = _params(tmp_path, True).replace(".yaml", "")
    text = open(p + ".yaml").read().replace("[0.02329, -0.02058, 0.00454]", "[2.0, -0.02058, 0.00454]")
    path = tmp_path / "bad_ctrl.yaml"
    path.write_text(text)
    assert main([bags["closed"], "--params-file", str(path), "--out", str(tmp_path / "x.json")]) == 2
    assert "does not stabilize" in capsys.readouterr().err


def test_a_bag_with_a_pause_is_identified_on_its_longest_gap_free_segment(tmp_path, capsys):
    """Evenly spaced samples are what the filters need: across a pause the data would be glued together and the
    estimate silently wrong. The longest gap-free segment is used, said on stderr and in the JSON."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    from additive_rsrivc_ros.io.bagio import DEFAULT_T0_NS, float64_cdr

    rng = np.random.default_rng(8)
    n, cut = 5000, 1500
    r = rng.standard_normal(n)
    u, y = simulate(PAPER_THETAS, [MODE, MODE], 1 / RATE, r=r, controller=(PID_NUM, PID_DEN),
                    noise=0.1 * rng.standard_normal(n))
    keep = np.r_[0:cut, cut + 400:n]                 # 20 s of the loop not recorded
    t_ns = DEFAULT_T0_NS + (keep * 1e9 / RATE).astype(np.int64)
    ts = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / "paused"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, x in (("/reference", r), ("/plant_input", u), ("/plant_output", y)):
            c = w.add_connection(topic, "std_msgs/msg/Float64", typestore=ts)
            for t, v in zip(t_ns, float64_cdr(x[keep]), strict=True):
                w.write(c, int(t), v)
    out = tmp_path / "m.json"
    assert main([str(bag), "--params-file", _params(tmp_path, True), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["data_gaps"] == 1 and "longest gap-free segment" in doc["message"]
    assert "data gap" in capsys.readouterr().err
    for mode, truth in zip(doc["modes"], PAPER_THETAS, strict=True):
        assert np.all(np.abs(np.array(mode["theta"]) - truth) <= 5 * np.array(mode["theta_std"]))
