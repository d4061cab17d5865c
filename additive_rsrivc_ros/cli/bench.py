"""``rsrivc_bench [--json]``: speed of the recursive estimator core (docs/INTERFACE.md "Benchmark").

Cases (closed loop, instrument [RA-SRIVC] eq. 33): K = 3 at 20 Hz ([RA-SRIVC] §5 plant, corrected PID,
erratum 1 in docs/DESIGN.md) with (M_l, M_s) = (1, 0); K = 4 at 4096 Hz (the beam truth of ``sim/plants.py``, modes at
about 3, 33, 172, 183 Hz, 4-sample delay) with (1, 0) and (3, 2). Each prints microseconds per sample and the real-time
factor ``(1/rate) / time per sample``. ``start_to_first_estimate_s`` is measured in a fresh Python process
(import, build, one update) with the kernel cache the setup fills (``rsrivc_warmup``); ``cold_start`` adds the
same with an empty cache in the same run (what a user without the cache would wait). ``diagnose_4096hz_k2``: a
fresh ``rsrivc_diagnose`` process on a simulated 60 s beam bag, report included.
``first_estimate_after_init_s``: a fresh process (kernels loaded first, as the node does) from the batch that completes
the init window to the first estimate. ``autostart_4096hz_k4``: the automatic start without guesses on
20 s of the K = 4 beam, from the full window to the first estimate. ``--fleet`` adds the fleet throughput.
The text output prints each issue's target next to its figure. BLAS threads are set to 1 before numpy is imported.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ..core.estimation.compiled import MODE_ENV, extension_loaded  # noqa: E402
from ..core.model import SubmodelStructure  # noqa: E402
from ..process_exit import console_entry  # noqa: E402
from .parser import OneLineParser  # noqa: E402


def _case_data(case: str, seconds: float) -> tuple:
    from ..sim.plants import BEAM_THETAS, PAPER_PID, PAPER_THETAS, beam_controller
    from ..sim.simulate import simulate
    rng = np.random.default_rng(0)
    if case.startswith("k3"):
        rate, thetas, ctrl, delay = 20.0, PAPER_THETAS, PAPER_PID, 0
        t = np.arange(int(seconds * rate)) / rate
        r = 3 * np.sin(0.005 * t) + np.sin(2 * t) + np.sin(5 * t) + np.sin(17.5 * t)
        noise_std = 0.1
    else:
        rate, thetas, ctrl, delay = 4096.0, BEAM_THETAS, beam_controller(4096.0), 4
        t = np.arange(int(seconds * rate)) / rate
        r = 1e-3 * np.sign(np.sin(2 * np.pi * 2.0 * t + 1e-9))
        noise_std = 2e-6
    n = t.size
    sim = simulate(thetas, [SubmodelStructure()] * len(thetas), rate, r=r, controller=ctrl, input_delay=delay,
                   noise=noise_std * rng.standard_normal(n))
    return rate, thetas, ctrl, delay, r, sim.u, sim.y


REPEATS = 7   # runs per case, the fastest counts: on a shared machine other work only ever adds time


def bench_case(case: str, sweeps: int, refinements: int, seconds: float | None = None) -> dict[str, float]:
    """Time the estimator on simulated closed-loop data (the fastest of :data:`REPEATS` runs from the same state);
    returns us_per_sample and realtime_factor."""
    from ..core.estimation.recursive import RecursiveAdditiveSRIVC
    if seconds is None:
        seconds = 1000.0 if case.startswith("k3") else 20.0
    rate, thetas, ctrl, delay, r, u, y = _case_data(case, seconds)
    guess = [th * np.array([1.02, 0.98, 1.01]) for th in thetas]
    memory = 50.0 if rate < 100 else 2.44
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * len(thetas), guess, rate,
                                 forgetting=1.0 - 1.0 / (memory * rate), controller=ctrl, input_delay=delay,
                                 block_sweeps=sweeps, refinements=refinements)
    n0 = min(u.size // 10, int(2 * rate))
    est.prime(r[:n0], u[:n0], y[:n0])
    est.update(r[n0:n0 + 10], u[n0:n0 + 10], y[n0:n0 + 10])  # compile / load cache outside the timing
    best = np.inf
    state = est.get_state()
    for _ in range(REPEATS):
        est.set_state(state)
        t0 = time.perf_counter()
        est.update(r[n0 + 10:], u[n0 + 10:], y[n0 + 10:])
        best = min(best, time.perf_counter() - t0)
    us = 1e6 * best / (u.size - n0 - 10)
    return {"us_per_sample": us, "realtime_factor": (1e6 / rate) / us}


_FIRST = r"""
import os, time
for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(v, "1")
import numpy as np
from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.core.model import SubmodelStructure
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
pid = DiscreteController((0.02329, -0.02058, 0.00454), (1.0, -1.0, 0.0))
th = [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.04, 0.5]), np.array([0.01, 0.0025, 1.0])]
est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 3, th, 20.0, forgetting=0.999, controller=pid)
est.update([1.0], [0.1], [0.2])
m = est.modal()
assert np.all(np.isfinite(m[:, :3]))
print(repr(time.time()))
"""


def _child_figure(code: str, env: dict[str, str] | None = None, silent: str = "child failed") -> float:
    """Run ``code`` in a fresh interpreter and return the number on its last output line (its last error line, or
    ``silent`` without one, raised when it fails or prints nothing)."""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         env=dict(os.environ) if env is None else env)
    lines = res.stdout.strip().splitlines()
    if res.returncode != 0 or not lines:
        raise RuntimeError(res.stderr.strip().splitlines()[-1] if res.stderr.strip() else silent)
    return float(lines[-1])


def start_to_first_estimate(env: dict[str, str] | None = None, runs: int = 2) -> float:
    """Seconds from spawning a fresh interpreter to its first estimate (the last of ``runs``: with the default
    environment the kernel cache is warm by then)."""
    out = float("nan")
    for _ in range(runs):
        t0 = time.time()
        out = _child_figure(_FIRST, env) - t0
    return out


_AFTER_INIT = r"""
import time
import numpy as np
from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.sim.scenarios import build, config_dir
from additive_rsrivc_ros.warmup import load_kernels
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
cfg = load_config(config_dir() / "beam_fault.yaml")
sc = build("beam_fault", duration_s=cfg.init_duration_s + 2.0, seed=1)
load_kernels()                                     # as the node does while configuring, before any data
pipe = MonitorPipeline(cfg)
rate = cfg.loop_rate_hz
n_init, step = int(round(cfg.init_duration_s * rate)), max(1, int(rate / 100))   # 10 ms batches
t_done = None
for j in range(0, sc.t.size, step):
    t0 = time.perf_counter()
    reps = pipe.push(sc.t[j:j + step], sc.r[j:j + step], sc.u[j:j + step], sc.y[j:j + step])
    if t_done is None and j + step >= n_init:
        t_done = t0                                # the batch that completes the init window
    if any(rep.estimating and np.all(np.isfinite(rep.modal[:, :3])) for rep in reps):
        print(repr(time.perf_counter() - t_done))
        break
"""


def first_estimate_after_init() -> float:
    """Seconds of computation in a fresh interpreter (the setup's kernel cache, kernels loaded first as the node
    loads them while configuring) from the batch that completes the init window to the first report with an
    estimate: the offline initialization, the check of the start and the first recursive updates (4096 Hz beam, K
    = 2, config/beam_fault.yaml, 10 ms batches). The live node publishes that estimate at the first report instant
    after it, i.e. up to one publish period later."""
    return _child_figure(_AFTER_INIT, silent="no estimate after init")


def _env_with_cache_root(root: str) -> dict[str, str]:
    from ..numba_cache import AUTO_MARKER

    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", AUTO_MARKER)}
    env["RSRIVC_CACHE_DIR"] = root
    return env


def cold_start() -> dict[str, float]:
    """Start to first estimate with the setup's kernel cache (what users see after ``rsrivc_warmup``) and with an
    empty cache (what they would see without it: numba compiles first), measured in the same run."""
    import tempfile

    warm = start_to_first_estimate()
    with tempfile.TemporaryDirectory(prefix="rsrivc-bench-cache-") as root:
        empty = start_to_first_estimate(_env_with_cache_root(root), runs=1)
    return {"warm_cache_s": warm, "empty_cache_s": empty}


DIAGNOSE_RUNS = 3
"""Fresh ``rsrivc_diagnose`` processes per figure: the machine's noise moves one process by 15 % (the fastest is the
figure, as for the kernel cases; the median is printed next to it)."""


def diagnose_figure(seconds: float = 60.0, runs: int = DIAGNOSE_RUNS) -> dict[str, float]:
    """Fresh ``rsrivc_diagnose`` processes on a simulated beam bag (4096 Hz, K = 2, report included): wall time of
    the fastest of ``runs`` processes and its own stages (read, estimate+diagnose, report; ``process_median_s``
    the median of the runs); ``process_jit_s`` one process under numba's JIT (``RSRIVC_KERNELS=jit``), right after
    them, for the ratio to the ahead-of-time kernels."""
    import tempfile
    from pathlib import Path

    from ..sim.scenarios import build, config_dir

    with tempfile.TemporaryDirectory(prefix="rsrivc-bench-diag-") as tmp:
        bag = Path(tmp) / "beam"
        build("beam_fault", duration_s=seconds, seed=1).write_bag(bag)
        runs_out: list[tuple[float, dict[str, float]]] = []
        jit_s = math.nan
        for j, mode in enumerate([""] * max(runs, 1) + ["jit"]):   # this process's kernels, then numba's JIT
            out = Path(tmp) / f"out{j}"
            t0 = time.monotonic()
            res = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.cli.diagnose", str(bag),
                                  "--params-file", str(config_dir() / "beam_fault.yaml"), "--out", str(out),
                                  "--quiet", "--no-progress"], capture_output=True, text=True, timeout=600,
                                 env={**os.environ, **({MODE_ENV: mode} if mode else {})})
            wall = time.monotonic() - t0
            if res.returncode != 0:
                raise RuntimeError(f"rsrivc_diagnose: {res.stderr.strip().splitlines()[-1:]}")
            if mode:
                jit_s = wall
            else:
                runs_out.append((wall, json.loads((out / "summary.json").read_text())["timings_s"]))
    wall, stages = min(runs_out, key=lambda ws: ws[0])
    median = float(np.median([w for w, _ in runs_out]))
    return {"seconds_of_data": seconds, "process_s": wall, "process_median_s": median, "runs": len(runs_out),
            "process_jit_s": jit_s, **stages}


def autostart_figure(seconds: float = 20.0) -> dict[str, float]:
    """The automatic start (no guesses, ``modes.count: 0``) as the node and ``rsrivc_diagnose`` run it
    (``MonitorPipeline``, ``init_duration_s`` = ``seconds``) on the K = 4 beam of the kernel cases at 4096 Hz
    (closed loop, 2 Hz square-wave setpoint): ``start_s``, the seconds from the full window to the first estimate
    (the search for the modes, the check of the start and the estimator's offline initialization; its second run in
    this process, kernels loaded as the node loads them while configuring), ``search_s`` the search alone, the modes
    found and their largest relative frequency error against the truth (matched in order of frequency; NaN when the
    count differs)."""
    from ..config import MonitorConfig, validate_params
    from ..core.model import modal_from_theta
    from ..core.monitor.pipeline import MonitorPipeline

    rate, thetas, ctrl, delay, r, u, y = _case_data("k4", seconds)
    cfg = MonitorConfig.from_params(validate_params({
        "loop_rate_hz": rate, "closed_loop": True, "controller.numerator": list(ctrl.numerator),
        "controller.denominator": list(ctrl.denominator), "input_delay_samples": delay, "init_duration_s": seconds,
        "alignment.mode": "off"}))
    t = np.arange(u.size) / rate
    start_s, search_s, pipe = float("nan"), float("nan"), None
    for _ in range(2):
        pipe = MonitorPipeline(cfg)
        t0 = time.perf_counter()
        pipe.push(t, r, u, y)       # init_duration_s = the record: search, check, initialization, no recursion
        start_s = time.perf_counter() - t0 if pipe.initialized else float("nan")
        found = pipe.search.found if pipe.search is not None else None
        search_s = float(found.seconds) if found is not None else float("nan")
    truth = np.sort([modal_from_theta(th, SubmodelStructure())[0] for th in thetas])
    found_f = np.sort(pipe.modal()[:, 0]) if pipe is not None and pipe.initialized else np.zeros(0)
    err = float(np.max(np.abs(found_f / truth - 1.0))) if found_f.size == truth.size else float("nan")
    return {"seconds_of_data": seconds, "start_s": start_s, "search_s": search_s, "modes_true": int(truth.size),
            "modes_found": int(found_f.size), "max_frequency_error": err, "target_s": 2.0}


def fleet_figure() -> dict[str, float]:
    """Bags per minute of ``rsrivc_fleet`` with one worker and with all (see :mod:`.fleet`)."""
    from .fleet import throughput

    return throughput()


CASES = {"k3_20hz_closed_1_0": ("k3", 1, 0), "k4_4096hz_closed_1_0": ("k4", 1, 0),
         "k4_4096hz_closed_3_2": ("k4", 3, 2)}


@console_entry
def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="rsrivc_bench", description="Speed figures of the recursive estimator.")
    ap.add_argument("--json", action="store_true", help="print one JSON object (docs/INTERFACE.md)")
    ap.add_argument("--seconds", type=float, default=None, help="simulated seconds per case (default 1000/20)")
    ap.add_argument("--diagnose-seconds", type=float, default=60.0,
                    help="seconds of the simulated bag for the rsrivc_diagnose figure (default 60)")
    ap.add_argument("--autostart-seconds", type=float, default=20.0,
                    help="seconds of data for the automatic-start figure (default 20)")
    ap.add_argument("--fleet", action="store_true",
                    help="also the fleet throughput: bags per minute with 1 worker and with all (needs dask)")
    args = ap.parse_args(argv)
    try:
        out: dict = {}
        for key, (case, ml, ms) in CASES.items():
            out[key] = bench_case(case, ml, ms, args.seconds)
        out["kernels"] = "ahead_of_time" if extension_loaded() else "jit"
        out["cold_start"] = cold_start()
        out["start_to_first_estimate_s"] = out["cold_start"]["warm_cache_s"]
        out["first_estimate_after_init_s"] = first_estimate_after_init()
        out["diagnose_4096hz_k2"] = diagnose_figure(args.diagnose_seconds)
        out["autostart_4096hz_k4"] = autostart_figure(args.autostart_seconds)
        if args.fleet:
            out["fleet"] = fleet_figure()
    except Exception as exc:  # noqa: BLE001 - one-line error, non-zero exit
        print(f"rsrivc_bench: error: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{'case':<24} {'us/sample':>10} {'x real time':>12}")
        for key in CASES:
            target = "  (target <= 0.5 us/sample)" if key == "k4_4096hz_closed_1_0" else ""
            print(f"{key:<24} {out[key]['us_per_sample']:10.3f} {out[key]['realtime_factor']:12.1f}{target}")
        cs, dg, st = out["cold_start"], out["diagnose_4096hz_k2"], out["autostart_4096hz_k4"]
        print("kernels: " + ("served ahead of time (rsrivc_warmup's extension)" if out["kernels"] == "ahead_of_time"
                             else "numba's JIT (no extension for these sources and this CPU: run rsrivc_warmup)"))
        print(f"start to first estimate: {cs['warm_cache_s']:.3f} s with the setup's kernel cache, "
              f"{cs['empty_cache_s']:.1f} s with an empty one (numba compiles)")
        print(f"first estimate after the init window: {out['first_estimate_after_init_s']:.3f} s of computation in a "
              "fresh process with the setup's kernel cache (4096 Hz beam, K = 2); target <= 1.5 s")
        print(f"rsrivc_diagnose of {dg['seconds_of_data']:g} s of 4096 Hz data (K = 2, report): process "
              f"{dg['process_s']:.2f} s (fastest of {dg['runs']}, median {dg['process_median_s']:.2f}; "
              f"{dg['process_jit_s']:.2f} s under numba's JIT); read {dg['read_s']:.2f}, "
              f"estimate {dg['estimate_s']:.2f}, report "
              f"{dg['report_s']:.2f}, total {dg['total_s']:.2f} s; target < 1.5 s for 60 s")
        print(f"automatic start (no guesses) on {st['seconds_of_data']:g} s of the 4096 Hz beam: "
              f"{st['start_s']:.2f} s from the full window to the first estimate (search {st['search_s']:.2f} s), "
              f"{st['modes_found']} of {st['modes_true']} modes found (largest frequency error "
              f"{100 * st['max_frequency_error']:.3g} %); target < {st['target_s']:g} s")
        if "fleet" in out:
            fl = out["fleet"]
            print(f"fleet: {fl['bags_per_min_1_worker']:.1f} bags/min with 1 worker, "
                  f"{fl['bags_per_min_all_workers']:.1f} with {fl['workers']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
