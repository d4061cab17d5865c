"""``rsrivc_warmup``: compile every numba kernel once, into the cache (:mod:`.numba_cache`), so that no tool and no
node pays compilation on its first run.

It exercises the code paths the node and the offline tools take, on short simulated records written as real
bags: closed loop (the beam), a rigid-body mode (integrators), open loop, and an automatic start without guesses;
each is simulated (sim.simulate), written (rosbag2/MCAP), read back (bagio, mcap_fast) and diagnosed
(pipeline: alignment, recursion, filters, ZOH, faults). Then every signature those runs met is compiled ahead of
time into one C extension in the same directory (:mod:`.core.compiled`): a process that loads it never imports
numba (about 1 s less per process). ``--check`` then lists kernels that were never compiled and says whether the
extension loads. The setup (``scripts/bootstrap.sh``) runs it; after ``colcon build`` run ``ros2 run additive_rsrivc_ros
rsrivc_warmup`` once (otherwise the first node start compiles, about 20-40 s).
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

from . import numba_cache
from .cli.parser import OneLineParser
from .process_exit import console_entry

#: (scenario, params file, seconds after the init window): every structural code path of the kernels
CASES = (
    ("beam_fault", "beam_fault.yaml", 2.0),            # closed loop, 4096 Hz, input delay
    ("beam_fault", "beam_plant.yaml", 2.0),            # no guesses: the automatic start (FRF, mode finding)
    ("rigid_body", "rigid_body.yaml", 2.0),            # integrators (b0/p^2), PD control
    ("open_loop_multisine", "open_loop_multisine.yaml", 2.0),  # open loop
)
MARKER = ".warm"


def load_kernels() -> float:
    """Load the compiled kernels into this process now; return the seconds it took.

    With the ahead-of-time extension this is a millisecond. Under the JIT a process's first numba call initializes
    numba's target context (about 1-2 s, holding the GIL); each further kernel's first call then loads it from the
    cache in milliseconds. The node does this while configuring, before it subscribes: paid in the middle of a 4 kHz
    stream it stalls the executor and the input pauses. Without a warm cache this compiles (tens of seconds), once.
    The scipy parts the offline start needs (``scipy.special``, ``scipy.linalg``: about 0.3 s) are imported here too,
    so the first estimate after the init window does not wait for them.
    """
    import numpy as np
    import scipy.linalg  # noqa: F401 - the offline start's expm (core/zoh.zoh_matrices)
    import scipy.special  # noqa: F401 - the offline start's F quantile (core/offline/stable.initial_transient_test)

    from .core.estimation import zoh

    t0 = time.monotonic()
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    zoh.second_order_zoh(0.01, 1e-4, 1e-3, phi, gam)    # loads the extension, or starts numba (the rest load in ms)
    return time.monotonic() - t0


# the independent reference simulator the tests and validate_* scripts compare against; no tool runs it
VALIDATION_ONLY = ("additive_rsrivc_ros.sim.independent",)


def kernel_dispatchers() -> dict[str, object]:
    """Every numba dispatcher defined in the package's modules, by ``module.name``."""
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    import additive_rsrivc_ros as pkg

    found: dict[str, object] = {}
    for info in pkgutil.walk_packages(pkg.__path__, "additive_rsrivc_ros."):
        if info.name.endswith((".node", "warmup")) or ".ros" in info.name:
            continue                                   # the ROS shell defines no kernels (and needs rclpy)
        if info.name in VALIDATION_ONLY:
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == info.name:
                found[f"{info.name}.{name}"] = obj
    return found


def _run_case(work: Path, scenario: str, params: str, after_s: float) -> None:
    from .cli import diagnose, simulate
    from .config import load_config
    from .sim.scenarios import config_dir

    cfg_path = config_dir() / params
    cfg = load_config(cfg_path, "additive_rsrivc_monitor")
    bag = work / f"{scenario}-{Path(params).stem}"
    sink = io.StringIO()
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        code = simulate.main(["--scenario", scenario, "--out", str(bag),
                              "--duration", f"{max(cfg.init_duration_s, 2.0) + after_s:g}"])
        if code == 0:
            code = diagnose.main([str(bag), "--params-file", str(cfg_path), "--out", str(work / f"{bag.name}-out"),
                                  "--no-report", "--quiet", "--no-progress"])
    if code != 0:
        raise RuntimeError(f"{scenario} with {params}: {sink.getvalue().strip().splitlines()[-1:]}")


def warm(verbose: bool = True) -> float:
    """Run :data:`CASES` under numba's JIT, build the ahead-of-time extension from the signatures they met
    (:mod:`.core.compiled`), mark the cache directory warm; return the seconds it took."""
    from .core.estimation import compiled

    t0 = time.monotonic()
    compiled.ensure_jit()                              # the JIT cache and the signatures to export
    with tempfile.TemporaryDirectory(prefix="rsrivc-warmup-") as tmp:
        for scenario, params, after_s in CASES:
            t = time.monotonic()
            _run_case(Path(tmp), scenario, params, after_s)
            if verbose:
                print(f"rsrivc_warmup: {scenario} / {params}: {time.monotonic() - t:.1f} s", file=sys.stderr)
    directory = numba_cache.configure()
    if directory:
        _build_extension(Path(directory), verbose)
        (Path(directory) / MARKER).write_text(f"{time.time():.0f}\n", encoding="utf-8")
    return time.monotonic() - t0


def _build_extension(directory: Path, verbose: bool) -> None:
    """Compile the kernels ahead of time; on failure (no C compiler, say) the JIT cache serves, one line says why."""
    from .core.estimation import compiled

    try:
        count, seconds = compiled.build(directory, kernel_dispatchers())
    except Exception as exc:                           # noqa: BLE001 - any toolchain failure leaves the JIT serving
        print(f"rsrivc_warmup: no ahead-of-time kernels ({type(exc).__name__}: {str(exc)[:200]}); "
              "the JIT cache serves; with a C compiler, run rsrivc_warmup again", file=sys.stderr)
        return
    if verbose:
        print(f"rsrivc_warmup: {count} kernel signatures compiled ahead of time ({seconds:.0f} s)", file=sys.stderr)


def _compiled(dispatcher: object) -> bool:
    """Compiled in this process, or cached on disk (a kernel called only from other kernels has no signatures of
    its own when its callers were loaded from the cache)."""
    if getattr(dispatcher, "signatures", None):
        return True
    cache = getattr(dispatcher, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    try:
        return bool(cache_file is not None and cache_file._load_index())
    except (OSError, ValueError, EOFError):
        return False


def is_warm() -> bool:
    """The current source's cache directory was filled by :func:`warm`."""
    import os

    directory = os.environ.get("NUMBA_CACHE_DIR")
    if not directory:
        return False
    return (Path(directory) / MARKER).is_file()


@console_entry
def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="rsrivc_warmup", description=__doc__.split("\n\n")[0])
    ap.add_argument("--if-needed", action="store_true", help="do nothing when this source's cache is warm")
    ap.add_argument("--check", action="store_true",
                    help="afterwards, list kernels never compiled and say if the ahead-of-time extension is missing")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    import os

    where = os.environ.get("NUMBA_CACHE_DIR", "numba's default (next to the sources)")
    warm_already = args.if_needed and is_warm()
    if warm_already and not args.check:
        return 0                                       # silent: the setup calls this on every run
    if not warm_already:
        if not args.quiet:
            print(f"rsrivc_warmup: compiling the numba kernels once into {where} (about two minutes)",
                  file=sys.stderr)
        try:
            seconds = warm(verbose=not args.quiet)
        except (RuntimeError, OSError, ValueError) as exc:
            print(f"rsrivc_warmup: error: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print("rsrivc_warmup: interrupted (the kernels compiled so far stay cached)", file=sys.stderr)
            return 130
        if not args.quiet:
            print(f"rsrivc_warmup: kernels compiled and cached in {where} ({seconds:.1f} s)", file=sys.stderr)
    return _check() if args.check else 0


def _check() -> int:
    """Print every kernel never compiled into the JIT cache and whether the ahead-of-time extension loads for
    these sources; 1 if anything is missing."""
    from .core.estimation import compiled

    missing = compiled._load_extension() is None
    if missing:
        print("rsrivc_warmup: no ahead-of-time extension for these sources and this CPU", file=sys.stderr)
    compiled.ensure_jit()
    cold = [name for name, d in kernel_dispatchers().items()
            if not _compiled(d) and getattr(d, "targetoptions", {}).get("inline") != "always"]   # inlined: in callers
    for name in cold:
        print(f"rsrivc_warmup: never compiled: {name}", file=sys.stderr)
    return 1 if cold or missing else 0


if __name__ == "__main__":
    sys.exit(main())
