"""diagnostic_aggregator analyzers per axis (diagnostics_config, multi_axis.launch.py aggregator:=true) against the
shipped config/diagnostic_aggregator.yaml and the monitor's status names."""
from pathlib import Path

import yaml

from additive_rsrivc_ros import diagnostics_config as dc

REPO = Path(__file__).resolve().parents[1]


def test_generated_analyzers_are_the_shipped_ones_for_two_axes():
    shipped = yaml.safe_load((REPO / "config" / "diagnostic_aggregator.yaml").read_text())
    params = shipped[dc.AGGREGATOR_NODE]["ros__parameters"]
    got = dc.aggregator_params(["axis1", "axis2"], modes=2)
    assert got["path"] == params["path"]
    group, shipped_group = got[dc.GROUP_KEY], params[dc.GROUP_KEY]
    assert {k: group[k] for k in ("type", "path")} == {k: shipped_group[k] for k in ("type", "path")}
    for axis in ("axis1", "axis2"):
        assert group["analyzers"][axis] == shipped_group["analyzers"][axis], axis


def test_one_branch_per_axis_and_only_its_own_statuses():
    """Each axis's analyzer takes exactly the statuses of the monitor in that namespace (names as the node makes
    them: full name without the leading '/'; test_node_names sees them live), none of another axis."""
    axes = ["axis1", "axis2", "axis10", "/left/arm/"]
    analyzers = dc.aggregator_params(axes, modes=3)[dc.GROUP_KEY]["analyzers"]
    assert list(analyzers) == ["axis1", "axis2", "axis10", "left_arm"]
    for axis, (key, a) in zip(axes, analyzers.items(), strict=True):
        ns = axis.strip("/")
        assert a["path"] == ns and a["expected"] == [f"{ns}/additive_rsrivc_monitor: {s}" for s in
                                                     ("estimator", "mode 1", "mode 2", "mode 3")], key
        for other in axes:
            name = f"{other.strip('/')}/additive_rsrivc_monitor: mode 1"
            taken = any(name.startswith(p) for p in a["startswith"])
            assert taken == (other == axis), (key, name)         # axis1 does not take axis10's statuses
    assert dc.status_prefix("") == "additive_rsrivc_monitor" == dc.status_prefix("/")
    assert "expected" not in dc.aggregator_params(["axis1"])[dc.GROUP_KEY]["analyzers"]["axis1"]
