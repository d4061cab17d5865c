"""``rsrivc_fleet BAG_OR_DIR... --params-file YAML --out DIR [--scheduler ADDR] [--workers N]``: many bags at once.

Each bag is an independent task on ``dask.distributed`` (a ``LocalCluster`` of ``--workers`` single-threaded worker
processes, default the CPUs this process may use, or the scheduler at ``--scheduler ADDR``): ``rsrivc_diagnose`` on
that bag (:func:`.diagnose.diagnose_bag`, the same files in ``DIR/<bag name>/``). A bag that fails is reported on
stderr and in ``DIR/fleet_failures.json`` and skipped; a worker that dies mid-task gives its task to another.
``BAG_OR_DIR`` is a rosbag2 directory or a directory searched for them (the output folder excluded);
``--params-file`` is one params file or a mapping from bag glob to params file (first match wins). Unchanged bags are
not diagnosed again (:mod:`.fleet_cache`; ``--recompute``). Then each machine's recordings are compared
(:mod:`..core.trend`): ``fleet.csv``, ``fleet.json`` (drift findings), ``fleet.html``, ``fleet_trend.json``.
docs/fleet_drift.md says which bags are one machine, how a level and its drift are tested, and how to run an
external cluster; the files and exit status (0, 1 every bag failed, 2 bad arguments, 130/143) are in
docs/INTERFACE.md.
"""

from __future__ import annotations

import argparse
import csv
import fnmatch
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from ..core.vocabulary import BASELINE_KEYS, FINDING_KEYS, FLEET_HEADER, QUANTITIES, json_clean, num, one_line
from ..process_exit import console_entry
from .fleet_cache import CACHE_DIRNAME, ResultCache
from .parser import OneLineParser
from .progress import ProgressBar
from .timerange import add_range_arguments, range_of

PROG = "rsrivc_fleet"
DASK_HINT = ("dask.distributed is not installed; rsrivc_fleet needs the optional extra: "
             "pip install 'additive_rsrivc_ros[fleet]' (or: pip install 'dask[distributed]')")


class ArgError(ValueError):
    """Bad command-line arguments (exit status 2)."""


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog=PROG, description="Diagnose many bags as independent tasks on dask.distributed and look for "
                "drift across recordings.")
    p.add_argument("bags", nargs="+", metavar="BAG_OR_DIR", help="rosbag2 directories, or directories holding bags")
    p.add_argument("--params-file", required=True, help="the node's params YAML, or a mapping file bag glob -> params")
    p.add_argument("--out", required=True, help="output directory: DIR/<bag name>/ per bag, DIR/fleet.* summary")
    p.add_argument("--scheduler", default=None, help="address of a running dask scheduler (default: a LocalCluster)")
    p.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes (default: the CPUs "
                   "available to this process)")
    p.add_argument("--node-name", default=None, help="node name whose section of the params file is used")
    p.add_argument("--no-report", action="store_true", help="per bag: skip report.html and modes.svg")
    p.add_argument("--group-by", choices=("params", "folder"), default="params", help="what makes a machine: its "
                   "params file or mapping glob (default), or the folder holding its recordings")
    p.add_argument("--recompute", action="store_true", help="diagnose every bag again (default: reuse the results "
                   "of bags whose content, params file and package are unchanged, DIR/.fleet_cache)")
    p.add_argument("--alpha", type=float, default=None, help="family-wise false-alarm probability of the drift "
                   "tests per machine (default 0.01)")
    prog = p.add_mutually_exclusive_group()
    prog.add_argument("--progress", dest="progress", action="store_true", default=None,
                      help="show a progress bar on stderr (default: only when stderr is a terminal)")
    prog.add_argument("--no-progress", dest="progress", action="store_false", help="never show a progress bar")
    add_range_arguments(p)
    return p


# ------------------------------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class BagTask:
    """One bag to diagnose: its unique name (the output sub-folder), paths and params file."""

    name: str
    bag: str
    params_file: str
    out_dir: str
    node_name: str | None = None
    report: bool = True
    machine: str = ""            # the mapping file's glob that matched, or the params file: recordings of one machine
    start: str | None = None     # --start / --end of every bag (cli/timerange.py)
    end: str | None = None


def _is_bag(p: Path) -> bool:
    return p.is_dir() and (p / "metadata.yaml").is_file()


def find_bags(items: Sequence[str], out_dir: Path) -> list[Path]:
    """The bags named or found below the arguments (in argument order, each directory's bags sorted)."""
    out_res = out_dir.resolve()
    found: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_file() and (p.name == "metadata.yaml" or (p.parent / "metadata.yaml").is_file()):
            p = p.parent
        if not p.exists():
            raise ArgError(f"not found: {item}")
        if _is_bag(p):
            found.append(p)
            continue
        if not p.is_dir():
            raise ArgError(f"{item}: not a rosbag2 bag (no metadata.yaml) nor a directory of bags")
        below = []
        for root, dirs, files in os.walk(p):
            r = Path(root)
            if r.resolve() == out_res or out_res in r.resolve().parents:
                dirs[:] = []
                continue
            if "metadata.yaml" in files:
                below.append(r)
                dirs[:] = []       # a bag's sub-folders are not bags
            dirs.sort()
        if not below:
            raise ArgError(f"{item}: no rosbag2 bag (a folder with metadata.yaml) found")
        found += sorted(below)
    unique: dict[Path, Path] = {}
    for b in found:
        unique.setdefault(b.resolve(), b)
    return list(unique.values())


def bag_names(bags: Sequence[Path]) -> list[str]:
    """Output folder names: the bag's name, prefixed by its parent's where names repeat, then numbered."""
    names = [b.resolve().name or "bag" for b in bags]
    counts = {n: names.count(n) for n in names}
    names = [f"{b.resolve().parent.name}_{n}" if counts[n] > 1 else n for b, n in zip(bags, names, strict=True)]
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}_{seen[n]}")
    return out


def params_resolver(path: str) -> Callable[[Path, str], tuple[str, str] | None]:
    """``(bag, as_given) -> (params file, machine)`` from a params file (every bag, one machine) or a mapping file
    (module docstring; the machine is the glob that matched), None when no glob matches."""
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ArgError(f"--params-file {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ArgError(f"--params-file {path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    is_map = isinstance(data, dict) and data and all(isinstance(v, str) for v in data.values())
    if not is_map:
        return lambda bag, given: (str(p), str(p))
    rules = [(str(g), str(v if Path(v).is_absolute() else p.parent / v)) for g, v in data.items()]

    def resolve(bag: Path, given: str) -> tuple[str, str] | None:
        keys = (given, str(bag.resolve()), bag.resolve().name)
        return next(((v, g) for g, v in rules if any(fnmatch.fnmatch(k, g) for k in keys)), None)
    return resolve


def _check_params(files: set[str], node_name: str | None) -> None:
    from ..config import DEFAULT_NODE_NAME, ParamError, load_config

    for f in sorted(files):
        try:
            load_config(f, node_name or DEFAULT_NODE_NAME)
        except (ParamError, OSError, ValueError) as exc:
            raise ArgError(f"params file {f}: {one_line(exc)}") from None


def make_tasks(args: argparse.Namespace) -> tuple[list[BagTask], list[dict[str, str]]]:
    """Tasks for the bags, and the bags without a params file (as failures)."""
    out = Path(args.out)
    bags = find_bags(args.bags, out)
    given = {b.resolve(): str(b) for b in bags}
    resolve = params_resolver(args.params_file)
    tasks, unmatched = [], []
    for b, name in zip(bags, bag_names(bags), strict=True):
        hit = resolve(b, given[b.resolve()])
        if hit is None:
            unmatched.append({"bag": name, "path": str(b), "error": f"no glob of {args.params_file} matches it"})
            continue
        machine = str(b.resolve().parent) if getattr(args, "group_by", "params") == "folder" else hit[1]
        tasks.append(BagTask(name, str(b.resolve()), str(Path(hit[0]).resolve()), str((out / name).resolve()),
                             args.node_name, not args.no_report, machine, getattr(args, "start", None),
                             getattr(args, "end", None)))
    _check_params({t.params_file for t in tasks}, args.node_name)
    return tasks, unmatched


# ------------------------------------------------------------------------------------------------- worker task
def run_bag(task: BagTask) -> dict[str, Any]:
    """The per-bag task (runs on a worker): diagnose, then the bag's level per mode for the trend.

    Never raises: a failure comes back as ``{"ok": False, "error": one line}``."""
    import io

    t_start = time.monotonic()
    res: dict[str, Any] = {"name": task.name, "bag": task.bag, "params_file": task.params_file,
                           "machine": task.machine or task.params_file, "ok": False}
    err = io.StringIO()
    try:
        from .diagnose import diagnose_bag

        summary = diagnose_bag(task.bag, task.params_file, task.out_dir, node_name=task.node_name,
                               report=task.report, stderr=err, start=task.start, end=task.end)
        res.update(_bag_result(summary, Path(task.out_dir)), ok=True)
    except Exception as exc:  # noqa: BLE001 - a failed bag is reported and skipped, never the whole run
        res["error"] = f"{type(exc).__name__}: {one_line(exc)}" if not isinstance(exc, ValueError | OSError) \
            else one_line(exc)
    res["warnings"] = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    res["elapsed_s"] = time.monotonic() - t_start
    return res


def _read_estimates(path: Path, k: int) -> tuple[Any, Any]:
    """(times (N,), modal (N, K, 6)) from estimates.csv."""
    import numpy as np

    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))[1:]
    n = len(rows) // k if k else 0
    a = np.array([[float(v) for v in r[2:8]] for r in rows[: n * k]], float).reshape(n, k, 6) if n else \
        np.zeros((0, k, 6))
    t = np.array([float(r[0]) for r in rows[: n * k: k]], float) if n else np.zeros(0)
    return t, a


#: blind-interval kinds (:mod:`..verdict`) outside a recording's settled part: the estimator's start-up and
#: settling (also after a disruption restarted it), health holds, gaps and times without an estimate. Learning the
#: baseline, an untrusted baseline and monitoring are settled.
UNSETTLED_KINDS = frozenset({"initializing", "settling", "hold", "no_data", "no_estimate"})
#: a recording feeds the drift test when its settled part is at least this many (longest) memory lengths: with the
#: default settling of 3 memory lengths after the initialization, recordings from about 4 memory lengths count (the
#: level's std covers a short settled part: core.trend.bag_level)
MIN_SETTLED_MEMORY_LENGTHS = 0.5


def settled_mask(t: Any, blind: Sequence[dict[str, Any]]) -> Any:
    """True at the output instants ``t`` of the recording's settled part (outside :data:`UNSETTLED_KINDS`)."""
    import numpy as np

    mask = np.ones(t.shape, bool)
    for b in blind:
        if str(b.get("kind", "")) in UNSETTLED_KINDS:
            mask &= ~((t >= float(b["start_s"]) - 1e-9) & (t < float(b["end_s"]) - 1e-9))
    return mask


def _bag_result(summary: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """What the fleet needs of one diagnosed bag: verdict, events, first sample time, levels per mode."""
    from ..core.diagnosis.faults import FaultSettings
    from ..core.diagnosis.trend import bag_level
    from ..core.params import settings_from_params

    k = int(summary["K"])
    params = summary.get("parameters", {})
    settings = settings_from_params(FaultSettings, params)  # the run's thresholds (a name it lacks: the default)
    memory = params.get("modes.memory_s") or [1.0] * k
    t, modal = _read_estimates(out_dir / "estimates.csv", k)
    period = 1.0 / float(params.get("publish_rate_hz", 10.0) or 10.0)
    if t.size > 1:
        period = float(sorted(t[1:] - t[:-1])[(t.size - 1) // 2])
    mask = settled_mask(t, summary.get("blind_intervals", []))
    level = bag_level(modal, mask, memory, period) if t.size else None
    exclusion = _exclusion(summary, level, memory)
    modes = []
    for m in summary["modes"]:
        i = int(m["mode"]) - 1
        final = m.get("final") or {}
        value = ([float(level.value[i, q]) for q in range(3)] if level is not None else
                 [_num(final.get(c)) for c in BASELINE_KEYS])
        modes.append({"mode": i + 1, "value": value,
                      "std": [float(level.std[i, q]) for q in range(3)] if level is not None else [math.nan] * 3,
                      "baseline": [_num((m.get("baseline") or {}).get(c)) for c in BASELINE_KEYS]})
    return {"start_time_ns": int(summary["start_time_ns"]), "verdict": summary["verdict"],
            "verdict_text": summary.get("verdict_text", ""), "events": len(summary.get("events", [])),
            "K": k, "monitored_s": float(summary.get("monitored_s") or 0.0), "duration_s": summary.get("duration_s"),
            "level_s": level.monitored_s if level is not None else 0.0, "modes": modes, "exclusion": exclusion,
            "min_change": dict(zip(QUANTITIES, settings.min_change, strict=True)),
            "spread_factor": settings.relevance_spread_factor}


def _exclusion(summary: dict[str, Any], level: Any, memory: Sequence[float]) -> str | None:
    """Why the bag cannot feed the trend (None: it can)."""
    if summary["verdict"] == "NO ESTIMATE":
        return "no estimate: the estimator never had an accepted model"
    if level is None:
        return "no settled estimate (the estimator was still settling at the end, or health held it throughout)"
    if level.monitored_s < MIN_SETTLED_MEMORY_LENGTHS * max(memory):
        return (f"settled for only {level.monitored_s:.3g} s (< {MIN_SETTLED_MEMORY_LENGTHS:g} x the memory, "
                f"{max(memory):g} s)")
    return None


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


# ------------------------------------------------------------------------------------------------- cluster
def default_workers() -> int:
    """Worker processes of the LocalCluster: the CPUs this process may use (affinity and cgroup quota)."""
    try:
        from dask.system import CPU_COUNT

        return max(1, int(CPU_COUNT))
    except ImportError:                                           # pragma: no cover - dask is checked first
        return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


#: dask settings of the LocalCluster's workers (``dask.config`` keys). dask's nanny starts workers with
#: ``MALLOC_TRIM_THRESHOLD_=65536``, which also switches off glibc's adaptive mmap threshold: every array above
#: 128 kB of a diagnosis was then mapped and zeroed afresh (10x the page faults, 0.7 s of 3.8 s of CPU on four 60 s
#: recordings at 4 kHz). Without it the task thread's CPU time equals an in-process diagnosis'. The statistical
#: profiler only feeds the dashboard, which this cluster does not have.
WORKER_CONFIG: dict[str, Any] = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,     # None: not set (dask's nanny)
    "distributed.worker.profile.enabled": False,
}


def start_client(scheduler: str | None, workers: int | None) -> tuple[Any, Any]:
    """``(client, cluster)``: a Client of the scheduler at ``scheduler``, or of a new LocalCluster of ``workers``
    single-threaded worker processes (cluster None with a scheduler address)."""
    import logging

    import dask
    from dask.distributed import Client, LocalCluster

    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # inherited by the workers
        os.environ.setdefault(var, "1")
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise ArgError(f"--scheduler {scheduler}: cannot connect ({one_line(exc)})") from None
    n = workers or default_workers()
    # the workers inherit this process's environment, where an earlier dask nanny in this process may have left it
    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    # no dashboard; the scheduler's HTTP endpoint on a free port (8787 may belong to another cluster)
    with dask.config.set(WORKER_CONFIG):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               scheduler_kwargs={"dashboard_address": ":0"}, silence_logs=logging.ERROR)
    return Client(cluster), cluster


def close_client(client: Any, cluster: Any) -> None:
    """Close the client and a LocalCluster we started (never a remote scheduler). Connections that close while
    the cluster goes down are expected: dask's shutdown messages (a ``CommClosedError`` traceback) are silenced."""
    import logging

    for name in ("distributed", "distributed.comm", "distributed.worker", "distributed.nanny", "tornado",
                 "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    for obj in (client, cluster):
        if obj is None:
            continue
        try:
            obj.close(timeout=10) if obj is client else obj.close()
        except Exception:  # noqa: BLE001 - shutting down: nothing left to save
            pass


def remove_partials(out: Path, names: Sequence[str]) -> None:
    """Remove the temporary folders of bags whose worker died or was stopped before its folder was complete
    (:class:`.atomic.AtomicDir` names them ``.<name>.partial-<pid>``); finished folders are never touched."""
    import glob
    import shutil

    for name in names:
        for tmp in out.glob(f".{glob.escape(name)}.partial-*"):
            shutil.rmtree(tmp, ignore_errors=True)


def run_tasks(client: Any, tasks: Sequence[BagTask], stderr: TextIO, show: bool,
              on_done: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Submit one task per bag and collect the results as they finish (a lost worker fails only its bag)."""
    from dask.distributed import as_completed

    futures = {client.submit(run_bag, t, key=f"rsrivc_fleet-{i}-{t.name}", pure=False, retries=0): t
               for i, t in enumerate(tasks)}
    results: list[dict[str, Any]] = []
    failed = [0]

    def describe(done: float, total: float, elapsed: float) -> str:
        return f"{int(done)}/{len(tasks)} bags{f' ({failed[0]} failed)' if failed[0] else ''}  {elapsed:6.1f} s"
    bar = ProgressBar(PROG, len(tasks), stderr, show, describe)
    bar.update(0)
    try:
        for fut in as_completed(list(futures)):
            t = futures[fut]
            try:
                res = fut.result()
            except Exception as exc:  # noqa: BLE001 - the worker died (killed, out of memory): this bag failed
                res = {"name": t.name, "bag": t.bag, "params_file": t.params_file, "ok": False, "warnings": [],
                       "error": f"task lost ({type(exc).__name__}: {one_line(exc)})"}
            failed[0] += not res["ok"]
            bar.clear()
            if on_done is not None:
                on_done(res)
            results.append(res)
            bar.update(len(results))
    finally:
        bar.close()
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)
    order = {t.name: i for i, t in enumerate(tasks)}
    return sorted(results, key=lambda r: order[r["name"]])


# ------------------------------------------------------------------------------------------------- summary
def _group_k(bags: Sequence[dict[str, Any]]) -> int:
    ks = [b["K"] for b in bags if b["exclusion"] is None] or [b["K"] for b in bags]
    return max(set(ks), key=lambda k: (ks.count(k), -k))


def machine_trend(bags: Sequence[dict[str, Any]], alpha: float) -> dict[str, Any]:
    """The drift tests of one machine's diagnosed bags (in recording order) and the bags' use in them."""
    import numpy as np

    from ..core.diagnosis.trend import BagLevel, fleet_drift

    k = _group_k(bags)
    levels: list[BagLevel | None] = []
    rows = []
    for b in bags:
        why = b["exclusion"] or (f"{b['K']} modes, the machine's other recordings have {k}" if b["K"] != k else None)
        lv = None
        if why is None:
            lv = BagLevel(np.array([m["value"] for m in b["modes"]], float), np.array([m["std"] for m in b["modes"]],
                          float), float(b["level_s"]), np.ones(k))
        levels.append(lv)
        note = (f"levels from its {b['level_s']:.3g} s settled part (verdict {b['verdict']})"
                if why is None and b["verdict"] != "OK" else None)
        rows.append({"bag": b["name"], "start_time_s": b["start_time_ns"] / 1e9, "verdict": b["verdict"],
                     "events": b["events"], "used": why is None, "exclusion": why, "note": note,
                     "level_s": b["level_s"],
                     "monitored_s": b["monitored_s"], "value": [m["value"] for m in b["modes"]],
                     "std": [m["std"] for m in b["modes"]], "baseline": [m["baseline"] for m in b["modes"]]})
    ref = next((b for b in bags if b["exclusion"] is None), bags[0])
    tests = fleet_drift(levels, ref["min_change"], spread_factor=ref["spread_factor"], alpha=alpha)
    findings = [dict(zip(FINDING_KEYS, (bags[0]["machine"], t.mode, t.quantity, t.direction,
                                        bags[t.first_index]["name"], round(t.change_percent, 6)), strict=True))
                for t in tests if t.flagged and t.first_index is not None]
    return {"machine": bags[0]["machine"], "params_file": bags[0]["params_file"], "K": k,
            "alpha": alpha, "min_change": ref["min_change"],
            "spread_factor": ref["spread_factor"], "bags": rows, "tests": [t.to_dict() for t in tests],
            "findings": findings}


def fleet_summary(results: Sequence[dict[str, Any]], alpha: float) -> dict[str, Any]:
    """Per machine (params file, or mapping glob) the recordings in order of their first sample's time and their
    drift tests."""
    ok = sorted((r for r in results if r["ok"]), key=lambda r: (r["start_time_ns"], r["name"]))
    machines: dict[str, list[dict[str, Any]]] = {}
    for r in ok:
        machines.setdefault(r["machine"], []).append(r)
    groups = [machine_trend(bags, alpha) for bags in machines.values()]
    return {"machines": groups, "findings": [f for g in groups for f in g["findings"]],
            "failures": [{"bag": r["name"], "path": r["bag"], "error": r["error"]} for r in results if not r["ok"]]}


def write_fleet_csv(path: Path, results: Sequence[dict[str, Any]]) -> int:
    """fleet.csv (docs/INTERFACE.md): one row per bag and mode, bags in order of their first sample's time."""
    ok = sorted((r for r in results if r["ok"]), key=lambda r: (r["start_time_ns"], r["name"]))
    rows = 0
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(FLEET_HEADER)
        for r in ok:
            for m in r["modes"]:
                w.writerow([r["name"], num(r["start_time_ns"] / 1e9), m["mode"], *(num(v) for v in m["value"]),
                            *(num(v) for v in m["baseline"]), r["events"], r["verdict"]])
                rows += 1
    return rows


def _json_text(obj: Any) -> str:
    return json.dumps(json_clean(obj), indent=2, allow_nan=False) + "\n"


def write_outputs(out: Path, results: Sequence[dict[str, Any]], summary: dict[str, Any]) -> None:
    """fleet.csv, fleet.json, fleet_trend.json, fleet_failures.json and fleet.html (each written atomically)."""
    from ..outputs.fleet_report import render_fleet_html
    from .atomic import atomic_write_text

    out.mkdir(parents=True, exist_ok=True)
    tmp = out / f".fleet.csv.partial-{os.getpid()}"
    try:
        write_fleet_csv(tmp, results)
        os.replace(tmp, out / "fleet.csv")
    finally:
        tmp.unlink(missing_ok=True)
    atomic_write_text(out / "fleet.json", _json_text([{k: f[k] for k in FINDING_KEYS} for f in summary["findings"]]))
    atomic_write_text(out / "fleet_trend.json", _json_text(summary))
    atomic_write_text(out / "fleet_failures.json", _json_text(summary["failures"]))
    atomic_write_text(out / "fleet.html", render_fleet_html(summary))


def print_findings(summary: dict[str, Any], stdout: TextIO) -> None:
    """The drift findings (or that there are none) and the excluded bags, on stdout."""
    for g in summary["machines"]:
        used = sum(b["used"] for b in g["bags"])
        print(f"machine {g['machine']}: {len(g['bags'])} recording(s), {used} in the drift test", file=stdout)
        for b in g["bags"]:
            if not b["used"]:
                print(f"  not in the drift test: {b['bag']}: {b['exclusion']}", file=stdout)
            elif b["note"]:
                print(f"  in the drift test: {b['bag']}: {b['note']}", file=stdout)
        for f in g["findings"]:
            print(f"  DRIFT: mode {f['mode']} {f['quantity'].replace('_', ' ')} {f['direction']} "
                  f"{f['change_percent']:+.2f} % across the recordings (threshold reached at {f['first_bag']})",
                  file=stdout)
        if not g["findings"]:
            print("  no drift across the recordings", file=stdout)


# ------------------------------------------------------------------------------------------------- main
def split_cached(tasks: Sequence[BagTask], cache: ResultCache
                 ) -> tuple[list[dict[str, Any]], list[BagTask], dict[str, str]]:
    """``(reused results, tasks to run, cache key per task name)`` (:mod:`.fleet_cache`; a bag whose files cannot
    be read gets no key and is run: its task reports the error)."""
    reused, todo, keys = [], [], {}
    for t in tasks:
        try:
            keys[t.name] = cache.key(t.bag, t.params_file, t.node_name, t.report, t.out_dir, (t.start, t.end))
        except OSError:
            todo.append(t)
            continue
        fields = {"name": t.name, "bag": t.bag, "params_file": t.params_file, "machine": t.machine or t.params_file}
        hit = cache.lookup(keys[t.name], t.out_dir, fields)
        if hit is None:
            todo.append(t)
        else:
            reused.append(hit)
    return reused, todo, keys


def _compute(args: argparse.Namespace, todo: Sequence[BagTask], keys: dict[str, str], cache: ResultCache,
             stderr: TextIO, state: dict[str, Any]) -> list[dict[str, Any]]:
    """Diagnose the bags of ``todo`` on the cluster; store each bag's result in the cache as it arrives."""
    out = Path(args.out)
    state["partials"] = (out, [t.name for t in todo])
    client, cluster = start_client(args.scheduler, args.workers)
    state["client"] = (client, cluster)
    n_workers = len(client.scheduler_info().get("workers", {}))
    print(f"{PROG}: {len(todo)} bag(s) on {n_workers} worker(s)"
          f"{f' at {args.scheduler}' if args.scheduler else ' (LocalCluster)'}", file=stderr)
    out_dirs = {t.name: t.out_dir for t in todo}

    def report(res: dict[str, Any]) -> None:
        state["done"].append(res["name"])
        for w in res.get("warnings", []):
            print(f"{PROG}: {res['name']}: {w}", file=stderr)
        if not res["ok"]:
            print(f"{PROG}: {res['name']}: failed, skipped: {res['error']}", file=stderr)
        elif res["name"] in keys:
            cache.store(keys[res["name"]], out_dirs[res["name"]], res)

    show = args.progress if args.progress is not None else stderr.isatty()
    results = run_tasks(client, todo, stderr, bool(show), report)
    close_client(client, cluster)
    state.pop("client", None)
    remove_partials(*state.pop("partials"))
    return results


def fleet(args: argparse.Namespace, stdout: TextIO, stderr: TextIO, state: dict[str, Any]) -> int:
    """The work behind :func:`main`; raises :class:`ArgError` for bad arguments."""
    from ..core.diagnosis.trend import DEFAULT_ALPHA

    alpha = DEFAULT_ALPHA if args.alpha is None else float(args.alpha)
    if not 0.0 < alpha < 1.0:
        raise ArgError(f"--alpha must be in (0, 1), got {args.alpha}")
    if args.workers is not None and args.workers < 1:
        raise ArgError(f"--workers must be >= 1, got {args.workers}")
    try:
        range_of(args.start, args.end)
    except ValueError as exc:
        raise ArgError(str(exc)) from None
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        raise ArgError(DASK_HINT) from None
    tasks, unmatched = make_tasks(args)
    for u in unmatched:
        print(f"{PROG}: {u['bag']}: skipped: {u['error']}", file=stderr)
    if not tasks:
        raise ArgError("no bag has a params file")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    cache = ResultCache(out, enabled=not args.recompute)
    reused, todo, keys = split_cached(tasks, cache)
    if reused:
        print(f"{PROG}: {len(reused)} bag(s) unchanged since an earlier run: their results reused "
              f"({out / CACHE_DIRNAME})", file=stderr)
    state["done"] = [r["name"] for r in reused]
    results = list(reused)
    if todo:
        results += _compute(args, todo, keys, cache, stderr, state)
    cache.save()
    results += [{"name": u["bag"], "bag": u["path"], "params_file": "", "ok": False, "error": u["error"]}
                for u in unmatched]
    summary = fleet_summary(results, alpha)
    write_outputs(out, results, summary)
    n_ok = sum(r["ok"] for r in results)
    for r in sorted((r for r in results if r["ok"]), key=lambda r: r["start_time_ns"]):
        print(f"{r['name']}: {r['verdict']}: {r['verdict_text']}", file=stdout)
    print_findings(summary, stdout)
    n_new = sum(r["ok"] and not r.get("cached") for r in results)
    print(f"{n_ok} of {len(results)} bag(s) diagnosed ({n_new} computed, {n_ok - n_new} reused) in "
          f"{time.monotonic() - t0:.1f} s; wrote {out}/: fleet.csv, "
          f"fleet.json ({len(summary['findings'])} drift finding(s)), fleet.html, fleet_trend.json, "
          f"fleet_failures.json ({len(summary['failures'])} failed)", file=stdout)
    return 0 if n_ok else 1


@console_entry
def main(argv: list[str] | None = None) -> int:
    """Console entry point (exit status: see the module docstring)."""
    from .atomic import exit_code, interrupts

    state: dict[str, Any] = {}
    with interrupts(final=argv is None):   # a console script's run: no death by signal after it
        try:
            args = _parser().parse_args(argv)
            return fleet(args, sys.stdout, sys.stderr, state)
        except KeyboardInterrupt as exc:
            n = len(state.get("done", []))
            _say(f"{PROG}: interrupted ({getattr(exc, 'name', 'SIGINT')}) after {n} bag(s); their folders are "
                 "complete, no fleet summary written")
            return exit_code(exc)
        except ArgError as exc:
            _say(f"{PROG}: error: {one_line(exc)}")
            return 2
        except Exception as exc:  # noqa: BLE001 - never a traceback for users; RSRIVC_DEBUG=1 shows it
            if os.environ.get("RSRIVC_DEBUG"):
                raise
            _say(f"{PROG}: internal error: {type(exc).__name__}: {one_line(exc)} (set RSRIVC_DEBUG=1 for a traceback)")
            return 1
        finally:
            if state.get("client") is not None:
                close_client(*state.pop("client"))
            if state.get("partials") is not None:
                remove_partials(*state.pop("partials"))


def _say(line: str) -> None:
    try:
        print(line, file=sys.stderr)
    except (OSError, ValueError):   # stderr gone (closed pipe): the exit status still tells
        pass


if __name__ == "__main__":
    sys.exit(main())


# ------------------------------------------------------------------------------------------------- benchmark
def throughput(n_bags: int = 8, duration_s: float = 10.0, workers: int | None = None,
                     report: bool = True) -> dict[str, float | int]:
    """Fleet throughput: bags per minute with 1 worker and with ``workers`` (default: all CPUs available) on the
    same ``n_bags`` simulated recordings (:mod:`..sim.fleetsim`, ``duration_s`` each, per-bag report included unless
    ``report`` is False). Timed from submitting the tasks to the last result, on a started cluster whose workers
    have each diagnosed one warm-up bag first (imports, numba cache, fonts: paid once per worker, not per bag).

    Returns ``{"bags_per_min_1_worker": x, "bags_per_min_all_workers": y, "workers": n}`` (``rsrivc_bench --json``
    key ``fleet``)."""
    import tempfile

    from ..sim import fleetsim

    n_all = workers or default_workers()
    rates = {}
    with tempfile.TemporaryDirectory(prefix="rsrivc_fleet_bench_") as tmp:
        bags, params = fleetsim.write_machine_recordings(Path(tmp) / "bags", n_bags + 1, duration_s=duration_s)
        warm, bags = bags[0], bags[1:]
        for n in sorted({1, n_all}):
            client, cluster = start_client(None, n)
            try:
                client.run(_warm_worker, str(warm), str(params), str(Path(tmp) / "warm"), report)
                tasks = [BagTask(b.name, str(b), str(params), str(Path(tmp) / f"out{n}" / b.name), None, report)
                         for b in bags]
                t0 = time.monotonic()
                results = run_tasks(client, tasks, sys.stderr, False)
                elapsed = time.monotonic() - t0
            finally:
                close_client(client, cluster)
            failed = [r["error"] for r in results if not r["ok"]]
            if failed:
                raise RuntimeError(f"benchmark bag failed: {failed[0]}")
            rates[n] = 60.0 * n_bags / elapsed
    return {"bags_per_min_1_worker": rates[1], "bags_per_min_all_workers": rates[n_all], "workers": n_all}


def _warm_worker(bag: str, params: str, out: str, report: bool) -> None:
    """Diagnose a warm-up bag on this worker (its first task would otherwise pay for imports and caches)."""
    from .diagnose import diagnose_bag

    diagnose_bag(bag, params, Path(out) / str(os.getpid()), report=report)
