"""Live: a Float64 message lost on one topic while every topic keeps streaming (over real DDS, localhost).

Float64 carries no sequence number, so the node pairs r, u, y by arrival order and one lost input message
shifts u against y for the rest of the run. The pipeline's controller-invariant aligner must find the shift,
refill the lost sample from u = C_d(q)(r - y) and say so on /diagnostics; the node's estimates must then equal
the offline pipeline's on the complete data (up to the rounding of the refilled sample).
"""
import sys
import time
from pathlib import Path

import numpy as np
from std_msgs.msg import Float64

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core import scenarios
from additive_rsrivc_ros.core.pipeline import MonitorPipeline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_node_helpers import Client, start_node, stop_node  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PAPER = str(REPO / "config" / "paper_example.yaml")


def test_one_lost_input_message_is_realigned_live(ros_env):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("paper_example", duration_s=160.0, seed=5, drift1_start_s=1e4, drift1_end_s=1.1e4,
                         drift2_start_s=1.2e4, drift2_end_s=1.3e4)
    n = sc.t.size
    k_lost = 2500                                   # after the initialization, while everything streams
    rate_pub = 400.0                                # 20x the loop rate: the sample grid is the arrival order
    proc = start_node(ros_env, PAPER, "qos_depth:=20000", "stale_timeout_s:=5.0")
    cli = Client(dom, Float64)
    try:
        cli.wait_matched()
        t0 = time.monotonic()
        for k in range(n):
            for s, x in (("reference", sc.r), ("input", sc.u), ("output", sc.y)):
                if not (s == "input" and k == k_lost):
                    cli.pubs[s].publish(Float64(data=float(x[k])))
            lag = t0 + (k + 1) / rate_pub - time.monotonic()
            if lag > 0:
                time.sleep(lag)
        pipe = MonitorPipeline(MonitorConfig.from_params(load_params_file(PAPER)))
        h = 1.0 / 20.0
        ref = pipe.push(np.arange(n) * h, sc.r, sc.u, sc.y)
        # the node holds back the aligner's lag and one sample for the lost message: compare at its last report
        last_ref = {round(r.time_s, 6): r for r in ref}

        def matched() -> bool:
            if not cli.modes:
                return False
            got = np.asarray(cli.modes[-1].data)
            return any(np.allclose(got, r.modal.ravel(), rtol=1e-6, atol=0.0) for r in list(last_ref.values())[-20:])

        cli.wait_for(matched, 60, "~/modes equal to the offline pipeline on the complete data")
        reasons = [st.message + " " + " ".join(kv.value for kv in st.values)
                   for arr in cli.diags for st in arr.status if st.name.endswith(": estimator")]
        assert any("re-aligned" in x for x in reasons), "the re-alignment was not reported on /diagnostics"
        vals = cli.status("estimator")["values"]
        assert vals["alignment"] == "verified" and int(vals["alignment_realignments"]) >= 1
        assert int(vals["alignment_refilled"]) >= 1        # the lost input sample, recomputed from C_d
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0, out
