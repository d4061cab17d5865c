"""Where the compiled numba kernels are cached, and why there.

Numba's ``cache=True`` keys a kernel on its own source file only, so a changed ``@njit`` callee in another module leaves
the caller's stale machine code loaded. The package therefore caches in a directory keyed on a hash of every kernel
module's source and on the install that runs them (package location, ``sys.prefix``, interpreter, installed numpy,
numba and llvmlite): ``$RSRIVC_CACHE_DIR/numba-<version>-<source hash>-<install hash>/`` (default root
``$XDG_CACHE_HOME/additive_rsrivc_ros`` or ``~/.cache/additive_rsrivc_ros``; the system temporary directory when none is
writable). Two installs never load or overwrite each other's kernels. The directory also holds the kernels compiled
ahead of time (``core/estimation/compiled.py``). A ``NUMBA_CACHE_DIR`` set by the user is respected as is.
:func:`configure` runs
once, from the package's ``__init__``, before any kernel module is imported; ``rsrivc_warmup`` fills the cache.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path

from ._version import __version__

#: set in the environment by :func:`configure` so that child processes can tell an inherited automatic
#: ``NUMBA_CACHE_DIR`` (recomputed for their own sources) from one the user set.
AUTO_MARKER = "RSRIVC_NUMBA_CACHE_AUTO"
_PACKAGE = Path(__file__).resolve().parent
#: the modules that define or call numba kernels (their source decides the cache directory;
# ``core/estimation/compiled.py``
#: checks the same files against its manifest).
KERNEL_SOURCES = ("core/**/*.py", "io/mcap_fast.py")


def source_hash() -> str:
    """SHA-256 (12 hex digits) of the kernel modules' source, in a fixed order (about a millisecond)."""
    h = hashlib.sha256()
    for pattern in KERNEL_SOURCES:
        for path in sorted(_PACKAGE.glob(pattern)):
            h.update(path.name.encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:12]


#: the compiled dependencies whose installed release decides what a cached kernel was built against
COMPILED_DEPENDENCIES = ("numpy", "numba", "llvmlite")


def _installed(module: str) -> str:
    """Where ``module`` is installed and when that was (its ``__init__``'s path and mtime): found without importing
    it, in microseconds; a reinstall or another release changes it."""
    import importlib.util

    try:
        spec = importlib.util.find_spec(module)
        origin = spec.origin if spec is not None else None
        return f"{origin}:{os.stat(origin).st_mtime_ns}" if origin else "-"
    except (ImportError, ValueError, OSError):
        return "-"


def install_hash() -> str:
    """SHA-256 (8 hex digits) of this install: the package's directory, the Python environment and interpreter,
    the machine type and the installed :data:`COMPILED_DEPENDENCIES`."""
    parts = [str(_PACKAGE), sys.prefix, sys.version, os.uname().machine,
             *(_installed(m) for m in COMPILED_DEPENDENCIES)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:8]


def _writable(directory: Path) -> bool:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".probe-"):
            pass
        return True
    except OSError:
        return False


def default_root() -> Path:
    """``$RSRIVC_CACHE_DIR``, else ``$XDG_CACHE_HOME/additive_rsrivc_ros``, else ``~/.cache/additive_rsrivc_ros``."""
    explicit = os.environ.get("RSRIVC_CACHE_DIR")
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path("~/.cache").expanduser())
    return Path(xdg) / "additive_rsrivc_ros"


def cache_dir() -> Path:
    """The writable, source-keyed kernel cache directory (created if needed)."""
    name = f"numba-{__version__}-{source_hash()}-{install_hash()}"
    for root in (default_root(), Path(tempfile.gettempdir()) / f"additive_rsrivc_ros-{os.getuid()}"):
        if _writable(root / name):
            return root / name
    return Path(tempfile.mkdtemp(prefix=f"{name}-"))


def user_set() -> bool:
    """True when ``NUMBA_CACHE_DIR`` was set by the user (not inherited from :func:`configure`)."""
    value = os.environ.get("NUMBA_CACHE_DIR")
    return bool(value) and value != os.environ.get(AUTO_MARKER)


def configure() -> str | None:
    """Point numba's cache at :func:`cache_dir` unless the user chose one; return the directory in use.

    Sets the environment (inherited by worker processes and the node) before numba is imported, or numba's
    config when it already is; kernels decorated afterwards cache there.
    """
    if user_set():
        return os.environ["NUMBA_CACHE_DIR"]
    try:
        path = str(cache_dir())
    except OSError:       # nothing writable at all: numba's own fallback (next to the source, else no cache)
        return None
    os.environ["NUMBA_CACHE_DIR"] = path
    os.environ[AUTO_MARKER] = path
    numba_config = sys.modules.get("numba.core.config")
    if numba_config is not None:
        vars(numba_config)["CACHE_DIR"] = path   # the module numba reads its setting from
    return path
