"""The package's numba kernels, served ahead of time when possible, by numba's JIT otherwise.

Every kernel is declared with :func:`kernel`. ``rsrivc_warmup`` runs the tools' code paths under the JIT, then compiles
every signature they met into one C extension (``numba.pycc``, :func:`build`) in the source-keyed cache directory
(:mod:`..numba_cache`), with a manifest of the exports, the kernel modules' SHA-256 and the CPU. A process whose sources
and CPU match loads it in a millisecond and never imports numba (about 1 s per process). Each call is checked against
the exported signature (compiled code trusts its arguments); anything else (another signature, keywords, no extension,
changed sources, ``RSRIVC_KERNELS=jit``, ``NUMBA_DISABLE_JIT=1``) goes to numba's JIT: same code, same cache, same
results.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import sys
import sysconfig
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

EXTENSION = "rsrivc_kernels"
MANIFEST = EXTENSION + ".json"
#: ``RSRIVC_KERNELS=jit`` makes this process use numba's JIT even when the extension is there
MODE_ENV = "RSRIVC_KERNELS"
_PACKAGE_DIR = Path(__file__).resolve().parents[2]   # core/estimation/compiled.py -> the package
_PACKAGE = __name__.split(".")[0]
_LOCK = threading.RLock()
_REGISTRY: list[Kernel] = []
_state: dict[str, Any] = {"extension": None, "loaded": False, "jit": False}


class ArgSpec(NamedTuple):
    """One argument of an exported signature: ``kind`` is ``array``, ``float``, ``int`` or ``bool``."""

    kind: str
    dtype: str = ""
    ndim: int = 0
    layout: str = ""
    readonly: bool = False


def jit_forced() -> bool:
    """This process runs the kernels under numba's JIT (``RSRIVC_KERNELS=jit`` or ``NUMBA_DISABLE_JIT``)."""
    return (os.environ.get(MODE_ENV, "").strip().lower() == "jit"
            or os.environ.get("NUMBA_DISABLE_JIT", "0").strip() not in ("", "0"))


def _source_digests() -> dict[str, str]:
    """SHA-256 of every module that defines or calls a kernel, by path relative to the package (the files of
    ``numba_cache.KERNEL_SOURCES``, which core must not import)."""
    out = {}
    for pattern in ("core/**/*.py", "io/mcap_fast.py"):
        for path in sorted(_PACKAGE_DIR.glob(pattern)):
            out[path.relative_to(_PACKAGE_DIR).as_posix()] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


_CPU_KEYS = ("vendor_id", "cpu family", "model", "flags", "CPU implementer", "CPU architecture", "CPU part",
             "Features")


def _cpu_fingerprint() -> str | None:
    """The first processor's model and instruction-set flags (Linux ``/proc/cpuinfo``), or None when unknown.

    An extension built for this CPU (``target_cpu='host'``: the K = 4 kernel 0.64 us per sample here, 1.12 with the
    generic model) must not run on another, e.g. from a home directory a heterogeneous cluster shares (illegal
    instruction)."""
    fields = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if not line.strip():
                    break                              # the first processor's block is enough
                key, _, value = line.partition(":")
                if key.strip() in _CPU_KEYS:
                    fields[key.strip()] = value.strip()
    except OSError:
        return None
    if not fields:
        return None
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def _directory() -> Path | None:
    value = os.environ.get("NUMBA_CACHE_DIR")
    return Path(value) if value else None


def _load_extension() -> tuple[Any, dict[str, list[tuple[str, tuple[ArgSpec, ...]]]]] | None:
    """The extension and its exports by ``module.function``, if built for exactly these sources."""
    directory = _directory()
    if directory is None:
        return None
    try:
        manifest = json.loads((directory / MANIFEST).read_text(encoding="utf-8"))
        if manifest.get("ext_suffix") != sysconfig.get_config_var("EXT_SUFFIX"):
            return None
        if manifest.get("sources") != _source_digests():
            return None
        if manifest.get("cpu") != "generic" and manifest.get("cpu") != _cpu_fingerprint():
            return None
        spec = importlib.util.spec_from_file_location(EXTENSION, directory / manifest["file"])
        if spec is None or spec.loader is None:
            return None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        exports = {name: [(export, tuple(ArgSpec(*a) for a in args)) for export, args in variants]
                   for name, variants in manifest["exports"].items()}
    except (OSError, ImportError, ValueError, KeyError, TypeError):
        return None
    return module, exports


def extension_loaded() -> bool:
    """True when this process serves kernels from the ahead-of-time extension."""
    return _extension() is not None


def _extension() -> tuple[Any, dict] | None:
    if not _state["loaded"]:
        with _LOCK:
            if not _state["loaded"]:
                _state["extension"] = None if jit_forced() else _load_extension()
                _state["loaded"] = True
    return _state["extension"]


_DTYPES = {name: np.dtype(name) for name in ("float64", "int64", "uint8", "bool")}
# numpy's array flag bits (ndarray.flags.num; numpy/ndarraytypes.h)
_C_CONTIGUOUS, _F_CONTIGUOUS, _ALIGNED, _WRITEABLE = 0x0001, 0x0002, 0x0100, 0x0400
_LAYOUT_BITS = {"C": _C_CONTIGUOUS, "F": _F_CONTIGUOUS, "A": 0}


@functools.cache
def matcher(specs: tuple[ArgSpec, ...]) -> Callable[..., bool]:
    """A function of the call's arguments: True when they are exactly of the exported types, i.e. what numba's
    dispatcher would type them as (dtype, dimensions, layout, aligned, writable unless exported read-only).

    Generated once per signature (one boolean expression, as ``collections.namedtuple`` generates its class):
    about 0.1 us per argument, against several for a loop over the specs.
    """
    env: dict[str, Any] = {"ndarray": np.ndarray, "INTS": (int, np.integer), "BOOLS": (bool, np.bool_)}
    terms = []
    for i, s in enumerate(specs):
        a = f"a{i}"
        if s.kind == "array":
            env[f"dtype{i}"] = _DTYPES[s.dtype]
            mask = _ALIGNED | _LAYOUT_BITS[s.layout] | (0 if s.readonly else _WRITEABLE)
            terms.append(f"type({a}) is ndarray and {a}.dtype is dtype{i} and {a}.ndim == {s.ndim} "
                         f"and ({a}.flags.num & {mask}) == {mask}")
        elif s.kind == "float":
            terms.append(f"isinstance({a}, float)")
        elif s.kind == "int":
            terms.append(f"isinstance({a}, INTS) and not isinstance({a}, bool)")
        elif s.kind == "bool":
            terms.append(f"isinstance({a}, BOOLS)")
        else:
            raise ValueError(f"unknown argument kind {s.kind!r}")
    names = "".join(f"a{i}, " for i in range(len(specs)))
    source = (f"def matches(*args):\n    if len(args) != {len(specs)}:\n        return False\n"
              f"    ({names}) = args\n    return {' and '.join(terms) or 'True'}\n")
    exec(source, env)                                  # noqa: S102 - built from the manifest's fixed vocabulary
    return env["matches"]


class Kernel:
    """A kernel served by the extension for its exported signatures, by numba's JIT for anything else."""

    def __init__(self, py_func: Callable, variants: list[tuple[Callable, tuple[ArgSpec, ...]]],
                 inline: bool = False) -> None:
        functools.update_wrapper(self, py_func)
        self.py_func = py_func
        self.inline = inline
        self.variants = [(fn, matcher(specs)) for fn, specs in variants]
        self.dispatcher: Any = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if not kwargs:
            for compiled_fn, matches in self.variants:
                if matches(*args):
                    return compiled_fn(*args)
        return self.jit()(*args, **kwargs)

    def jit(self) -> Any:
        """numba's dispatcher of this kernel (switches every kernel of the process to the JIT, once)."""
        if self.dispatcher is None:
            ensure_jit()
        return self.dispatcher


def ensure_jit() -> None:
    """Switch this process to numba's JIT: give every kernel its numba dispatcher and put the dispatchers where
    kernels call each other (compiled numba code resolves a callee through its module's globals). Called on the
    first call the extension does not serve, and by numba code outside the package that calls its kernels
    (``sim.independent``, a validation-only simulator)."""
    with _LOCK:
        if _state["jit"]:
            return
        for k in _REGISTRY:
            k.dispatcher = _njit(k.py_func, k.inline)
        for name, module in list(sys.modules.items()):
            if module is None or not (name == _PACKAGE or name.startswith(_PACKAGE + ".")):
                continue
            for attr, value in list(vars(module).items()):
                if isinstance(value, Kernel) and value.dispatcher is not None:
                    setattr(module, attr, value.dispatcher)
        _state["jit"] = True


def kernel(py_func: Callable | None = None, *, inline: bool = False) -> Any:
    """Declare a numba kernel (``njit(cache=True)``): the extension's code when built, else numba's JIT.

    ``@kernel(inline=True)``: numba inlines the function into the kernels that call it (``inline="always"``, at the
    level of numba's IR: the same operations in the same order, so the same results), for small scalar helpers of
    a per-sample loop, whose call and returned tuple cost more than their arithmetic."""
    if py_func is None:
        return functools.partial(kernel, inline=inline)
    loaded = None if _state["jit"] else _extension()
    if loaded is None:
        return _njit(py_func, inline)
    module, exports = loaded
    variants = [(getattr(module, export), specs)
                for export, specs in exports.get(f"{py_func.__module__}.{py_func.__name__}", [])
                if hasattr(module, export)]
    k = Kernel(py_func, variants, inline)
    _REGISTRY.append(k)
    return k


def _njit(py_func: Callable, inline: bool) -> Any:
    from numba import njit

    return njit(cache=True, inline="always" if inline else "never")(py_func)


def _arg_spec(t: Any) -> ArgSpec:
    from numba.core import types

    if isinstance(t, types.Array):
        if not t.aligned or t.layout not in ("C", "F", "A") or str(t.dtype) not in _DTYPES:
            raise TypeError(f"no ahead-of-time export for {t}")
        return ArgSpec("array", str(t.dtype), t.ndim, t.layout, not t.mutable)
    if t == types.float64:
        return ArgSpec("float")
    if t == types.int64:
        return ArgSpec("int")
    if t == types.boolean:
        return ArgSpec("bool")
    raise TypeError(f"no ahead-of-time export for {t}")


def build(directory: Path, dispatchers: dict[str, Any]) -> tuple[int, float]:
    """Compile every signature the ``dispatchers`` (``module.name`` -> dispatcher) have met into the extension.

    Written to a temporary name and renamed, the manifest last, so a concurrent process sees either the old
    pair or the new one. Returns (exports, seconds).
    """
    import warnings

    t0 = time.monotonic()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                # numba.pycc's pending deprecation
        from numba.pycc import CC
    exports: dict[str, list] = {}
    cpu = _cpu_fingerprint()
    cc = CC(EXTENSION)
    cc.target_cpu = "host" if cpu else ""              # this machine's instruction set, else the generic model
    for name, disp in sorted(dispatchers.items()):
        for i, sig in enumerate(disp.signatures):
            try:
                specs = [_arg_spec(t) for t in sig]
            except TypeError:
                continue                               # left to the JIT
            export = f"{name.replace('.', '__')}__{i}"
            cc.export(export, sig)(disp.py_func)
            exports.setdefault(name, []).append([export, [list(s) for s in specs]])
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory, prefix=".build-") as tmp:
        cc.output_dir = tmp
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cc.compile()
        built = Path(tmp) / cc.output_file
        target = f"{EXTENSION}-{os.getpid()}-{time.time_ns()}{sysconfig.get_config_var('EXT_SUFFIX')}"
        os.replace(built, directory / target)          # a new name: a loaded old extension is never overwritten
    manifest = {"file": target, "ext_suffix": sysconfig.get_config_var("EXT_SUFFIX"), "sources": _source_digests(),
                "cpu": cpu or "generic", "exports": exports}
    tmp_manifest = directory / f".{MANIFEST}.{os.getpid()}"
    tmp_manifest.write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    os.replace(tmp_manifest, directory / MANIFEST)
    try:                                               # a concurrent build may have written the manifest since
        keep = {target, json.loads((directory / MANIFEST).read_text(encoding="utf-8")).get("file")}
    except (OSError, ValueError):
        keep = {target}
    for old in directory.glob(f"{EXTENSION}-*"):
        try:
            if old.name not in keep and time.time() - old.stat().st_mtime > 600.0:   # not a concurrent build's
                old.unlink()                           # a process that loaded it keeps its mapping
        except OSError:
            pass
    return sum(len(v) for v in exports.values()), time.monotonic() - t0
