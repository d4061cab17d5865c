"""All-or-nothing outputs and clean interrupts for the offline tools (stdlib only, imported before numpy).

* :func:`interrupts`: SIGINT and SIGTERM both raise :class:`Interrupted` (a ``KeyboardInterrupt``) in the main
  thread; after the first one both signals are ignored, so the clean-up that follows cannot be interrupted
  again. The exit status convention is ``128 + signal number`` (130 SIGINT, 143 SIGTERM).
* :class:`AtomicDir`: the files are written into a temporary sibling folder ``.<name>.partial-<pid>``,
  which replaces the target folder only when complete: with ``renameat2(RENAME_EXCHANGE)`` (Linux; one atomic
  step, the old folder then removed) or, where that is unavailable, two renames with SIGINT/SIGTERM blocked.
  An older output folder is replaced whole, never mixed; a folder holding files other than the tool's own
  outputs is refused (it is not ours to delete). On failure or interrupt the temporary folder is removed.
* :func:`atomic_write_text`: a file written to a temporary sibling, flushed and ``os.replace``-d into place.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType

HANDLED = (signal.SIGINT, signal.SIGTERM)
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


class Interrupted(KeyboardInterrupt):
    """Raised by SIGINT or SIGTERM inside :func:`interrupts`; ``signum`` tells which."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + int(self.signum)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


def exit_code(exc: BaseException) -> int:
    """128 + signal number for :class:`Interrupted`; 130 for a plain ``KeyboardInterrupt``."""
    return exc.exit_code if isinstance(exc, Interrupted) else 128 + int(signal.SIGINT)


_swallowed: list[int] = []   # signals whose Interrupted was raised inside a C callback and swallowed there
_received: list[int] = []    # every handled signal (a library may turn the Interrupted into another exception)


def _raise(signum: int, frame: FrameType | None) -> None:
    for s in HANDLED:   # one interrupt only: the clean-up that follows must run to its end
        signal.signal(s, signal.SIG_IGN)
    _received.append(signum)
    raise Interrupted(signum)


def received() -> int | None:
    """The signal that interrupted the run (inside :func:`interrupts`), if any: an error seen after it is a
    consequence of the interrupt, not of the input."""
    return _received[0] if _received else None


def _unraisable(hook: Callable) -> Callable:
    """A ``sys.unraisablehook`` that keeps an :class:`Interrupted` swallowed by a C callback (e.g. numba's llvmlite
    object-cache callback during compilation) for :func:`raise_if_interrupted` instead of printing a traceback."""
    def handle(info: object) -> None:
        exc = getattr(info, "exc_value", None)
        if isinstance(exc, Interrupted):
            _swallowed.append(exc.signum)
            return
        hook(info)
    return handle


def raise_if_interrupted() -> None:
    """Raise the :class:`Interrupted` a C callback swallowed (call at safe points: between blocks, before a commit)."""
    if _swallowed:
        raise Interrupted(_swallowed[0])


@contextmanager
def interrupts(final: bool = False) -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` inside the block (main thread only); old handlers restored.

    Where the signal lands inside a C callback, the exception cannot propagate; it is kept (no traceback) and
    raised by the next :func:`raise_if_interrupted`. ``final`` (a console script's whole run): afterwards the
    signals are ignored instead -- the run is over and its exit status is the result; a signal during the
    interpreter's shutdown must not turn a complete run into a death by signal."""
    old: dict[int, Callable | int | None] = {}
    hook = sys.unraisablehook
    _swallowed.clear()
    _received.clear()
    try:
        for s in HANDLED:
            old[s] = signal.signal(s, _raise)
    except ValueError:          # not the main thread: leave the handlers alone
        old = {}
    sys.unraisablehook = _unraisable(hook)
    try:
        yield
    finally:
        sys.unraisablehook = hook
        for signum, h in old.items():
            signal.signal(signum, signal.SIG_IGN if final else h if h is not None else signal.SIG_DFL)


@contextmanager
def signals_blocked() -> Iterator[None]:
    """Defer SIGINT/SIGTERM for the duration of the block (delivered when it ends)."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, HANDLED)
    except (AttributeError, ValueError, OSError):   # pragma: no cover - platforms without sigmask
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    import ctypes

    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2   # the running process's libc (glibc >= 2.28)
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    rc = fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    return rc == 0


class OutputDirError(OSError):
    """The output folder cannot be replaced (not a folder, or it holds files that are not ours)."""


class AtomicDir:
    """A temporary sibling folder that replaces ``target`` on :meth:`commit` (see the module docstring).

    ``owned``: file names the tool writes; an existing ``target`` holding anything else is refused.
    """

    def __init__(self, target: str | Path, owned: Collection[str]) -> None:
        self.target = Path(target)
        self.owned = frozenset(owned)
        self.tmp = self.target.parent / f".{self.target.name}.partial-{os.getpid()}"
        self.committed = False

    def open(self) -> Path:
        """Create the temporary folder (register the object for :meth:`discard` before calling this)."""
        import shutil

        check_replaceable(self.target, self.owned)
        self.target.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(self.tmp, ignore_errors=True)
        self.tmp.mkdir()
        return self.tmp

    def commit(self) -> Path:
        """Move the finished temporary folder into place (an older ``target`` is replaced whole)."""
        import shutil

        with signals_blocked():
            raise_if_interrupted()
            check_replaceable(self.target, self.owned)
            old = self.target.parent / f".{self.target.name}.old-{os.getpid()}"
            if self.target.exists():
                if _exchange(self.tmp, self.target):
                    old = self.tmp                              # the old output now sits at tmp
                else:
                    os.rename(self.target, old)
                    os.rename(self.tmp, self.target)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.rename(self.tmp, self.target)
            self.committed = True
        return self.target

    def discard(self) -> None:
        """Remove the temporary folder (after a failure or an interrupt); the target is untouched."""
        import shutil

        if not self.committed:
            with signals_blocked():
                shutil.rmtree(self.tmp, ignore_errors=True)


def check_replaceable(target: Path, owned: Collection[str]) -> None:
    """Raise :class:`OutputDirError` unless ``target`` is absent, or a folder holding only ``owned`` names."""
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputDirError(f"output path {target} exists and is not a directory")
    foreign = sorted(p.name for p in target.iterdir() if p.name not in owned)
    if foreign:
        raise OutputDirError(f"output directory {target} holds files that are not rsrivc outputs ("
                             f"{', '.join(foreign[:3])}{' ...' if len(foreign) > 3 else ''}); refusing to replace it, "
                             "choose another --out")


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` all-or-nothing (temporary sibling, fsync, ``os.replace``)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        with signals_blocked():
            raise_if_interrupted()
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            with signals_blocked():
                tmp.unlink(missing_ok=True)
    return path
