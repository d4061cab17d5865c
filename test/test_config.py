"""Parameter table, YAML loading and cross-checks (config.py)."""
from pathlib import Path

import numpy as np
import pytest

from additive_rsrivc_ros.config import MonitorConfig, ParamError, load_config, load_params_file, validate_params
from additive_rsrivc_ros.sim.plants import PAPER_PID_DEN, PAPER_PID_NUM

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def test_paper_example_loads_with_truth_modes():
    cfg = load_config(CONFIG_DIR / "paper_example.yaml")
    assert cfg.K == 3 and cfg.closed_loop and cfg.loop_rate_hz == 20.0
    # modal guess -> theta reproduces the paper's a2 = [0.25, 0.04, 0.0025], a1 = [0.25, 0.01, 0.01]
    thetas = np.array([m.theta0() for m in cfg.modes])
    np.testing.assert_allclose(thetas[:, 1], [0.25, 0.04, 0.0025], rtol=1e-6)
    np.testing.assert_allclose(thetas[:, 0], [0.25, 0.01, 0.01], rtol=1e-6)
    # lambda has one home, the estimator's set_memory: the paper's lambda = 0.999 at 20 Hz
    from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC

    np.testing.assert_allclose(RecursiveAdditiveSRIVC.from_config(cfg).forgetting, 0.999)
    assert cfg.controller.numerator == PAPER_PID_NUM and cfg.controller.denominator == PAPER_PID_DEN


def test_typed_views_of_the_alignment_memory_and_fault_parameters():
    """What core reads of the parameters, typed: the values given (not the defaults), the lag in whole samples."""
    from additive_rsrivc_ros.core.diagnosis.faults import FaultSettings

    p = validate_params({"loop_rate_hz": 1000.0, "closed_loop": False, "modes.natural_frequency_hz": [3.0, 30.0],
                         "modes.damping_ratio": [0.1, 0.1], "modes.gain": [1.0, 1.0], "modes.memory_s": [7.0],
                         "alignment.mode": "off", "alignment.max_shift": 5, "alignment.lag_s": 0.0101,
                         "alignment.switch_nats": 55.0, "faults.min_change.damping": 0.33})
    cfg = MonitorConfig.from_params(p)
    al = cfg.alignment
    assert (al.mode, al.max_shift, al.lag_s, al.switch_nats) == ("off", 5, 0.0101, 55.0)
    assert al.aligner_options(cfg.loop_rate_hz) == {"max_shift": 5, "lag": 11, "switch_nats": 55.0}
    assert cfg.mode_memories_s == (7.0,) and [m.memory_s for m in cfg.modes] == [7.0, 7.0]
    assert cfg.fault_settings == FaultSettings.from_params(p) and cfg.fault_settings != FaultSettings.from_params({})


MONITOR_CONFIGS = sorted(p for p in CONFIG_DIR.glob("*.yaml") if not p.name.startswith("diagnostic_aggregator"))


@pytest.mark.parametrize("path", MONITOR_CONFIGS, ids=lambda p: p.name)
def test_every_bundled_monitor_config_is_valid(path):
    load_config(path)


def test_int_for_double_is_accepted_and_bad_values_are_rejected(tmp_path):
    p = validate_params({"loop_rate_hz": 100, "modes.natural_frequency_hz": [3, 30]})
    assert isinstance(p["loop_rate_hz"], float)
    with pytest.raises(ParamError, match="loop_rate_hz"):
        validate_params({"loop_rate_hz": -5.0})
    with pytest.raises(ParamError, match="unknown parameter"):
        validate_params({"loop_rate": 5.0})
    with pytest.raises(ParamError, match="finite"):
        validate_params({"publish_rate_hz": float("nan")})
    base = {"loop_rate_hz": 100.0, "closed_loop": False, "modes.natural_frequency_hz": [3.0, 30.0],
            "modes.damping_ratio": [0.1], "modes.gain": [1.0, 1.0]}
    with pytest.raises(ParamError, match="damping_ratio"):
        MonitorConfig.from_params(validate_params(base))
    base["modes.damping_ratio"] = [0.1, 0.1]
    base["modes.natural_frequency_hz"] = [3.0, 60.0]
    with pytest.raises(ParamError, match="Nyquist"):
        MonitorConfig.from_params(validate_params(base))
    bad = tmp_path / "bad.yaml"
    bad.write_text("other_node:\n  ros__parameters: {loop_rate_hz: 1.0}\n")
    with pytest.raises(ParamError, match="no section"):
        load_params_file(bad)
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ParamError, match="not valid YAML"):
        load_params_file(bad)


def test_template_documents_every_parameter():
    """config/template.yaml (the file users copy) sets every parameter of the table except those whose default
    is an empty list (a ROS 2 params file cannot hold one; the template shows them commented out)."""
    from additive_rsrivc_ros.config import all_params

    flat = load_params_file(CONFIG_DIR / "template.yaml")  # validates every value too
    text = (CONFIG_DIR / "template.yaml").read_text()
    import yaml

    section = yaml.safe_load(text)["/**/additive_rsrivc_monitor"]["ros__parameters"]

    def has(name: str) -> bool:
        node = section
        for part in name.split("."):
            if not isinstance(node, dict) or part not in node:
                return False
            node = node[part]
        return True

    missing = [p.name for p in all_params() if not (isinstance(p.default, list) and not p.default) and not has(p.name)]
    assert not missing, f"template.yaml lacks {missing}"
    empty = [p.name for p in all_params() if isinstance(p.default, list) and not p.default]
    for name in empty:
        assert name.rsplit(".", 1)[-1] in text, f"template.yaml does not mention {name}"
    assert flat["loop_rate_hz"] > 0


def test_template_and_readme_table_are_generated_from_the_table():
    """config/template.yaml and the README's parameter table are what the table renders (issue 15): a changed row
    (default, range, description) without regenerating them fails here."""
    from additive_rsrivc_ros.config import (
        README_PATH,
        REGENERATE_COMMAND,
        TEMPLATE_PATH,
        readme_with_table,
        render_template,
        template_header,
    )

    root = CONFIG_DIR.parent
    template, readme = (root / TEMPLATE_PATH).read_text(), (root / README_PATH).read_text()
    assert template == render_template(template_header(template)), f"{TEMPLATE_PATH} drifted: run {REGENERATE_COMMAND}"
    assert readme == readme_with_table(readme), f"{README_PATH} parameter table drifted: run {REGENERATE_COMMAND}"


def test_template_notes_show_each_rows_range_and_runtime_flag():
    from additive_rsrivc_ros.config import param_note, param_table

    t = param_table()
    assert param_note(t["loop_rate_hz"]) == "[double; range [0.1, 1e+06]; read-only (restart to change)]"
    assert param_note(t["faults.enabled"]) == "[bool; changeable at runtime]"
    assert param_note(t["modes.frequency_range_hz"]) == "[double[]; min 0; read-only (restart to change)]"
    assert "one of information, relative" in param_note(t["estimator.p0_policy"])
