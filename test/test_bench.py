"""rsrivc_bench --json (CONTRACT "Benchmark"): keys present, figures positive (no timing assertion)."""
import json
import subprocess
import sys


def test_bench_json_keys():
    res = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.cli.bench", "--json", "--seconds", "2",
                          "--diagnose-seconds", "6", "--autostart-seconds", "10"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    for key in ("k3_20hz_closed_1_0", "k4_4096hz_closed_1_0", "k4_4096hz_closed_3_2"):
        assert out[key]["us_per_sample"] > 0 and out[key]["realtime_factor"] > 0
    assert out["start_to_first_estimate_s"] > 0 and out["first_estimate_after_init_s"] > 0
    assert out["cold_start"]["warm_cache_s"] > 0 and out["cold_start"]["empty_cache_s"] > 0
    dg = out["diagnose_4096hz_k2"]
    assert dg["process_s"] >= dg["total_s"] > 0 and dg["seconds_of_data"] == 6 and dg["process_jit_s"] > 0
    assert dg["runs"] == 3 and dg["process_median_s"] >= dg["process_s"]
    assert out["kernels"] in ("ahead_of_time", "jit")
    st = out["autostart_4096hz_k4"]
    assert st["seconds_of_data"] == 10 and st["start_s"] > 0 and st["modes_true"] == 4
    assert 1 <= st["modes_found"] <= 6   # a start was made (10 s need not show all four modes)


def test_bench_bad_argument_exits_nonzero():
    res = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.cli.bench", "--seconds", "abc"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode != 0 and "Traceback" not in res.stderr
