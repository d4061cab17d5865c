"""Live: a Float64 message lost on one topic while every topic keeps streaming (over real DDS, localhost).

Float64 carries no sequence number, so the node pairs r, u, y by arrival order and one lost input message
shifts u against y for the rest of the run. The pipeline's controller-invariant aligner must find the shift,
refill the lost sample from u = C_d(q)(r - y) and say so on /diagnostics; the node's estimates must then equal
the offline pipeline's on the complete data (up to the rounding of the refilled sample).
"""
import subprocess
from pathlib import Path

import numpy as np
from std_msgs.msg import Float64
from test_node_helpers import Client, start_node, stop_node  # noqa: E402

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.sim import scenarios

REPO = Path(__file__).resolve().parents[1]
PAPER = str(REPO / "config" / "paper_example.yaml")


def test_one_lost_input_message_is_realigned_live(ros_env, tmp_path):
    from bag_variants import write_topics

    from additive_rsrivc_ros.io.bagio import DEFAULT_T0_NS
    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("paper_example", duration_s=160.0, seed=5, drift1_start_s=1e4, drift1_end_s=1.1e4,
                         drift2_start_s=1.2e4, drift2_end_s=1.3e4)
    k_lost = 2500                                   # after the initialization, while everything streams
    t_ns = DEFAULT_T0_NS + np.rint(sc.t * 1e9).astype(np.int64)
    bag = write_topics(tmp_path / "lost", {"/reference": (t_ns, sc.r), "/plant_output": (t_ns, sc.y),
                                            "/plant_input": (np.delete(t_ns, k_lost), np.delete(sc.u, k_lost))})
    proc = start_node(ros_env, PAPER, "use_sim_time:=true", "qos_depth:=5000")
    cli = Client(dom, Float64)
    try:
        cli.wait_matched()
        rep = subprocess.run(["rsrivc_replay", str(bag), "--rate", "10", "--clock", "--topics", "/reference",
                              "/plant_input", "/plant_output", "--wait-for-subscribers", "30"], env=ros_env,
                             capture_output=True, text=True, timeout=180)
        assert rep.returncode == 0, rep.stderr
        pipe = MonitorPipeline(MonitorConfig.from_params(load_params_file(PAPER)))
        ref = pipe.push(sc.t, sc.r, sc.u, sc.y)[-20:]      # the complete data, offline

        def matched() -> bool:
            if not cli.modes:
                return False
            got = np.asarray(cli.modes[-1].data)
            return any(np.allclose(got, r.modal.ravel(), rtol=1e-6, atol=0.0) for r in ref)

        cli.wait_for(matched, 60, "~/modes equal to the offline pipeline on the complete data")
        vals = cli.status("estimator")["values"]
        assert vals["alignment"] == "verified" and int(vals["alignment_realignments"]) >= 1, vals
        assert int(vals["alignment_refilled"]) >= 1, vals     # the lost input sample, recomputed from C_d
        reasons = [st.message for arr in cli.diags for st in arr.status if st.name.endswith(": estimator")]
        assert any("re-aligned" in x for x in reasons), "the re-alignment was not reported on /diagnostics"
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0, out
