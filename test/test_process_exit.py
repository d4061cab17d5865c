"""console_entry: a console script's exit skips the final collection, keeps its exit status and atexit handlers; a
main called with arguments changes nothing."""

from __future__ import annotations

import gc
import subprocess
import sys
import textwrap

from additive_rsrivc_ros.process_exit import console_entry

_CHILD = textwrap.dedent("""
    import atexit, gc, sys
    from additive_rsrivc_ros.process_exit import console_entry

    @console_entry
    def main(argv=None):
        return 7 if argv is None else 0

    atexit.register(lambda: print("atexit ran", gc.get_freeze_count() > 0, flush=True))
    sys.exit(main())
""")


def test_a_console_run_freezes_before_exit_and_keeps_status_and_atexit():
    res = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, timeout=120)
    assert res.returncode == 7, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "atexit ran True"


def test_a_main_called_with_arguments_does_not_freeze():
    @console_entry
    def main(argv: list[str] | None = None) -> int:
        return len(argv or [])

    before = gc.get_freeze_count()
    assert main(["a", "b"]) == 2
    assert gc.get_freeze_count() == before
    assert main.__name__ == "main"
