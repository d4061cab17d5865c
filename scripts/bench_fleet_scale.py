#!/usr/bin/env python3
"""How ``rsrivc_fleet`` scales: samples per second and recordings per minute against the number of workers, on a
LocalCluster and on an external ``dask scheduler`` with ``dask worker`` processes (127.0.0.1 only), compared with
one in-process ``rsrivc_diagnose`` on the same kind of recordings.

    python scripts/bench_fleet_scale.py [--machines 50] [--recordings 10] [--duration 60] [--rate 4000]
                                        [--workers 1 2] [--clusters local external] [--reference N] [--report]
                                        [--bags DIR] [--json]

The fleet: ``--machines`` simulated machines (additive_rsrivc_ros.sim.fleetsim: open loop, two modes at 5 and 20 Hz,
forgetting memory 2 s, the fault logic's default start-up) with ``--recordings`` recordings each of ``--duration`` s
at ``--rate`` Hz, one folder per machine (``--group-by folder``); every fifth machine's mode 2 falls 0.5 % per
recording. The bags are written in parallel into ``--bags DIR`` (kept and reused when it holds the same fleet) or a
temporary folder.

Per configuration (cluster kind x workers) the cluster is started and each worker diagnoses one warm-up bag first
(imports, compiled kernels: once per worker process, not per bag); the time is from submitting the tasks to the last
result. The reference is ``diagnose_bag`` (what ``rsrivc_diagnose`` runs) in this process, warm, on the first
``--reference`` recordings (default: 10), measured right before each configuration (the load of a shared machine
drifts). Printed: samples per second, recordings per minute, per-worker samples per second and its ratio to the
reference; samples per CPU second of the workers against the reference's (the overhead, free of contention); the
time to compute the incremental run's cache keys; the drift findings against the drifting machines.
Run with ``scripts/env.sh`` sourced (one BLAS thread per process, the shared numba cache); the default fleet
(50 x 10 x 60 s at 4 kHz = 1.2e8 samples) takes a while on two cores: ``--machines 4 --recordings 3`` is a quick run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from additive_rsrivc_ros.cli import fleet
from additive_rsrivc_ros.cli.dask_loopback import LoopbackCluster
from additive_rsrivc_ros.cli.diagnose import diagnose_bag
from additive_rsrivc_ros.core.diagnosis.trend import DEFAULT_ALPHA
from additive_rsrivc_ros.sim import fleetsim

DRIFT = 0.005
DRIFT_EVERY = 5            # machines 0, 5, 10, ... drift


def machine(rate_hz: float) -> fleetsim.Machine:
    return fleetsim.Machine(rate_hz=rate_hz, memory_s=2.0, init_duration_s=2.0, settle_memory_lengths=None,
                            baseline_duration_s=None)


def _write_one(job: tuple[str, int, int, float, float]) -> str:
    folder, m, i, duration, rate = job
    drift = DRIFT if m % DRIFT_EVERY == 0 else 0.0
    return str(fleetsim.write_recording(Path(folder) / f"rec_{i:02d}", i, drift_per_recording=drift,
                                        duration_s=duration, seed=1000 + m, machine=machine(rate)))


def write_fleet(root: Path, a: argparse.Namespace) -> tuple[list[Path], Path]:
    """The fleet's bags (written in parallel where missing) and the params file of every machine."""
    manifest = {"machines": a.machines, "recordings": a.recordings, "duration": a.duration, "rate": a.rate,
                "drift": DRIFT, "every": DRIFT_EVERY}
    stamp = root / "fleet_manifest.json"
    if stamp.is_file() and json.loads(stamp.read_text()) != manifest:
        raise SystemExit(f"{root} holds another fleet (see {stamp}); give another --bags folder")
    root.mkdir(parents=True, exist_ok=True)
    params = fleetsim.machine_params(root / "machine.yaml", machine=machine(a.rate))
    jobs = [(str(root / f"m{m:02d}"), m, i, a.duration, a.rate) for m in range(a.machines) for i in range(a.recordings)]
    todo = [j for j in jobs if not (Path(j[0]) / f"rec_{j[2]:02d}" / "metadata.yaml").is_file()]
    for j in todo:
        shutil.rmtree(Path(j[0]) / f"rec_{j[2]:02d}", ignore_errors=True)
        Path(j[0]).mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with ProcessPoolExecutor(max_workers=max(a.workers)) as pool:
        list(pool.map(_write_one, todo))
    if todo:
        print(f"wrote {len(todo)} bag(s) in {time.monotonic() - t0:.1f} s", file=sys.stderr)
    stamp.write_text(json.dumps(manifest))
    return [Path(j[0]) / f"rec_{j[2]:02d}" for j in jobs], params


def _cpu_seconds() -> float:
    """User + system CPU seconds of the calling process (all its threads)."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def reference(bags: list[Path], params: Path, work: Path, report: bool) -> tuple[float, float]:
    """Samples per second and per CPU second of ``diagnose_bag`` in this process (warm: a warm-up bag first)."""
    diagnose_bag(bags[0], params, work / "ref_warm", report=report)
    t0, c0 = time.monotonic(), _cpu_seconds()
    samples = 0
    for b in bags:
        s = diagnose_bag(b, params, work / "ref" / b.parent.name / b.name, report=report)
        samples += int(s["samples"])
    wall, cpu = time.monotonic() - t0, _cpu_seconds() - c0
    shutil.rmtree(work / "ref", ignore_errors=True)
    return samples / wall, samples / cpu


def run_config(kind: str, n: int, tasks: list[fleet.BagTask], warm: Path, params: Path, work: Path,
               report: bool) -> tuple[float, float, list[dict[str, Any]]]:
    """Elapsed seconds of the fleet's tasks on a warm cluster of ``n`` workers, the CPU seconds its workers spent
    on them, and the results."""
    ext = LoopbackCluster(n).start() if kind == "external" else None
    try:
        client, cluster = fleet.start_client(ext.address if ext else None, n)
        try:
            client.run(fleet._warm_worker, str(warm), str(params), str(work / "warm"), report)
            cpu0 = client.run(_cpu_seconds)
            t0 = time.monotonic()
            results = fleet.run_tasks(client, tasks, sys.stderr, False)
            elapsed = time.monotonic() - t0
            cpu1 = client.run(_cpu_seconds)
        finally:
            fleet.close_client(client, cluster)
    finally:
        if ext is not None:
            ext.stop()
    return elapsed, sum(cpu1[w] - cpu0.get(w, 0.0) for w in cpu1), results


def cache_keys(bags: list[Path], params: Path, work: Path) -> tuple[float, float, float]:
    """Seconds to compute the incremental run's cache keys of every bag the first time (every file read and hashed)
    and again (file digests remembered by path, size and modification time), and the megabytes hashed."""
    from additive_rsrivc_ros.cli.fleet_cache import ResultCache

    out = work / "cache_probe"
    t0 = time.monotonic()
    cache = ResultCache(out)
    for b in bags:
        cache.key(str(b), str(params), None, False)
    cold = time.monotonic() - t0
    cache.save()
    t0 = time.monotonic()
    again = ResultCache(out)
    for b in bags:
        again.key(str(b), str(params), None, False)
    return cold, time.monotonic() - t0, cache.hashed_bytes / 1e6


def drift_check(results: list[dict[str, Any]], n_machines: int) -> str:
    summary = fleet.fleet_summary(results, DEFAULT_ALPHA)
    flagged = {Path(f["machine"]).name for f in summary["findings"]}
    drifting = {f"m{m:02d}" for m in range(n_machines) if m % DRIFT_EVERY == 0}
    return (f"drift flagged on {len(flagged & drifting)} of {len(drifting)} drifting machine(s), on "
            f"{len(flagged - drifting)} of {n_machines - len(drifting)} healthy one(s)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--machines", type=int, default=50)
    p.add_argument("--recordings", type=int, default=10)
    p.add_argument("--duration", type=float, default=60.0, help="seconds per recording")
    p.add_argument("--rate", type=float, default=4000.0, help="sample rate [Hz]")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--clusters", nargs="+", choices=("local", "external"), default=["local", "external"])
    p.add_argument("--reference", type=int, default=None, help="recordings for the in-process reference")
    p.add_argument("--report", action="store_true", help="per-bag report.html too (default: CSV/JSON only)")
    p.add_argument("--bags", default=None, help="folder for the fleet's bags (kept; reused when it holds this fleet)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    a = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="rsrivc_fleet_scale_"))
    try:
        bags, params = write_fleet(Path(a.bags) if a.bags else work / "bags", a)
        n_ref = a.reference or min(len(bags), 10)
        samples = int(round(a.duration * a.rate)) * len(bags)
        keys_cold, keys_warm, mbytes = cache_keys(bags, params, work)
        rows = []
        for kind in a.clusters:
            for n in a.workers:
                # the reference right before each configuration: on a shared machine the load drifts
                ref, ref_cpu = reference(bags[:n_ref], params, work, a.report)
                out = work / f"out_{kind}_{n}"
                names = fleet.bag_names(bags)
                tasks = [fleet.BagTask(nm, str(b), str(params), str(out / nm), None, a.report, str(b.parent))
                         for nm, b in zip(names, bags, strict=True)]
                elapsed, cpu, results = run_config(kind, n, tasks, bags[0], params, work, a.report)
                failed = [r["error"] for r in results if not r["ok"]]
                rate = samples / elapsed
                rows.append({"cluster": kind, "workers": n, "elapsed_s": elapsed, "samples_per_s": rate,
                             "recordings_per_min": 60.0 * len(bags) / elapsed, "per_worker_samples_per_s": rate / n,
                             "in_process_samples_per_s": ref, "per_worker_vs_in_process": rate / n / ref,
                             "samples_per_cpu_s": samples / cpu, "in_process_samples_per_cpu_s": ref_cpu,
                             "per_cpu_s_vs_in_process": samples / cpu / ref_cpu, "failed": len(failed),
                             "drift": drift_check(results, a.machines)})
                shutil.rmtree(out, ignore_errors=True)
        load = os.getloadavg()
        fig = {"machines": a.machines, "recordings": len(bags), "duration_s": a.duration, "rate_hz": a.rate,
               "samples": samples, "reference_recordings": n_ref, "runs": rows, "load_average": load,
               "cache_keys_first_s": keys_cold, "cache_keys_again_s": keys_warm, "hashed_mb": mbytes}
        if a.json:
            print(json.dumps(fig))
            return
        print(f"rsrivc_fleet scale: {a.machines} machines x {a.recordings} recordings of {a.duration:g} s at "
              f"{a.rate:g} Hz = {len(bags)} recordings, {samples:.3g} samples"
              f"{', report included' if a.report else ', no report'}; load average {load[0]:.1f} {load[1]:.1f} "
              f"{load[2]:.1f} on {os.cpu_count()} CPUs")
        print(f"incremental run's cache keys of all {len(bags)} bags: {keys_cold:.2f} s the first time "
              f"({mbytes:.0f} MB hashed), {keys_warm:.2f} s again (file digests remembered)")
        print(f"in-process: diagnose_bag on {n_ref} recordings right before each configuration; per CPU s: samples "
              "per CPU second of the worker processes (contention-free overhead measure)")
        print(f"{'cluster':9} {'workers':>7} {'elapsed s':>9} {'samples/s':>10} {'rec/min':>7} {'per worker':>10} "
              f"{'in-proc':>8} {'ratio':>6} {'per CPU s':>9} {'in-proc':>8} {'ratio':>6}  drift")
        for r in rows:
            print(f"{r['cluster']:9} {r['workers']:7d} {r['elapsed_s']:9.1f} {r['samples_per_s']:10,.0f} "
                  f"{r['recordings_per_min']:7.1f} {r['per_worker_samples_per_s']:10,.0f} "
                  f"{r['in_process_samples_per_s']:8,.0f} {100 * r['per_worker_vs_in_process']:5.0f}% "
                  f"{r['samples_per_cpu_s']:9,.0f} {r['in_process_samples_per_cpu_s']:8,.0f} "
                  f"{100 * r['per_cpu_s_vs_in_process']:5.0f}%  {r['drift']}"
                  + (f"; {r['failed']} FAILED" if r["failed"] else ""))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
