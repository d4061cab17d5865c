"""A console tool's exit without the interpreter's final garbage collection.

At exit CPython collects every container object once more. After numba has loaded its kernels, its type system and
LLVM wrappers are hundreds of thousands of objects, and that last collection took 0.55-0.65 s of a 4-5 s
``rsrivc_diagnose`` run on the bundled bag (``gc.freeze()`` before exit: 0.08 s measured). By then the
work is done and every output is closed, so :func:`console_entry` moves all objects to the permanent generation
(``gc.freeze``) when ``main`` ran as a console script (``argv is None``). atexit handlers, the flushing of the standard
streams and module teardown still run; only objects in reference cycles are left to the operating system. A ``main``
called with arguments (tests, other tools) returns as before.
"""

from __future__ import annotations

import functools
import gc
from typing import Protocol


class Main(Protocol):
    """A tool's ``main``: command-line arguments (None: ``sys.argv``) -> exit status."""

    def __call__(self, argv: list[str] | None = None) -> int: ...


def console_entry(main: Main) -> Main:
    """Decorate a tool's ``main(argv=None) -> int``: run as a console script (``argv is None``), it skips the final
    collection."""

    @functools.wraps(main)
    def run(argv: list[str] | None = None) -> int:
        code = main(argv)
        if argv is None:
            gc.freeze()
        return code

    return run
