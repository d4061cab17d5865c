"""Where the compiled numba kernels are cached, and why there.

Numba's ``cache=True`` keys a cached kernel on its *own* source file's timestamp only: when an ``@njit``
callee in another module changes, the caller's stale machine code is still loaded (this hid a change of
``core/zoh.py`` once). The package therefore caches in a directory keyed on a hash of every numba module's
source, so a changed kernel anywhere means a fresh directory, never a stale load, and on the install that runs
them: the package's location, the Python environment (``sys.prefix``, interpreter version) and the installed
numpy, numba and llvmlite. Two installs of one version (a second venv, a ``colcon build`` next to a ``pip
install``, another numpy) never load or overwrite each other's kernels:

    ``$RSRIVC_CACHE_DIR`` (default ``$XDG_CACHE_HOME/additive_rsrivc_ros``, i.e. ``~/.cache/...``)
    ``/numba-<package version>-<source hash>-<install hash>/``

It is user-writable, so read-only installs (``colcon build``, ``pip install``) cache too; when no candidate is
writable the system temporary directory is used. The same directory holds the kernels compiled ahead of time
(``core/compiled.py``), checked against the sources again when loaded. A ``NUMBA_CACHE_DIR`` set by the user is
respected as is (then invalidation of the JIT cache is the user's). :func:`configure` runs once, from the
package's ``__init__``, before any kernel module is imported; ``rsrivc_warmup`` (``python -m
additive_rsrivc_ros.warmup``) fills the cache.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path

#: set in the environment by :func:`configure` so that child processes can tell an inherited automatic
#: ``NUMBA_CACHE_DIR`` (recomputed for their own sources) from one the user set.
AUTO_MARKER = "RSRIVC_NUMBA_CACHE_AUTO"
_PACKAGE = Path(__file__).resolve().parent
#: the modules that define or call numba kernels (their source decides the cache directory; ``core/compiled.py``
#: checks the same files against its manifest).
KERNEL_SOURCES = ("core/*.py", "mcap_fast.py")


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
    from . import __version__

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
        numba_config.CACHE_DIR = path
    return path
