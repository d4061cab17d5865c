"""Static types: ``python -m mypy`` on the package with the configuration in setup.cfg reports no error.

As a ROS 2 package's ``test_mypy.py`` does (ament_mypy), but with plain mypy (pinned in
requirements/constraints.txt, installed by scripts/bootstrap.sh). ``PENDING_MYPY`` may list files whose errors
are tolerated for a while; an entry must go once its file is clean, so the list only shrinks (it is empty).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PKG = "additive_rsrivc_ros"
# Files whose type errors are tolerated for now (paths relative to the package). Remove an entry when its file is clean.
PENDING_MYPY: set[str] = set()
ERROR = re.compile(rf"^{PKG}/(?P<file>[^:]+):\d+(?::\d+)?: error: ")


def _mypy_errors() -> tuple[dict[str, list[str]], str]:
    """``{file: [error lines]}`` of mypy on the package, and its whole output."""
    env = dict(os.environ, MYPY_FORCE_COLOR="0", PYTHONDONTWRITEBYTECODE="1")
    proc = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(REPO / "setup.cfg"),
                           "--cache-dir", str(REPO / ".mypy_cache"), "--no-color-output", "--no-error-summary",
                           "--show-error-codes", PKG], cwd=REPO, env=env, capture_output=True, text=True)
    out = proc.stdout + proc.stderr
    assert proc.returncode in (0, 1), f"mypy did not run (exit {proc.returncode}):\n{out}"
    errors: dict[str, list[str]] = defaultdict(list)
    for line in out.splitlines():
        m = ERROR.match(line)
        if m:
            errors[m["file"]].append(line)
    assert proc.returncode == 0 or errors, f"mypy failed without reporting an error:\n{out}"
    return dict(errors), out


@pytest.mark.skipif(importlib.util.find_spec("mypy") is None,
                    reason="mypy is not installed in this environment (scripts/bootstrap.sh installs it; the oldest "
                           "stack of scripts/test_oldest.sh does not)")
def test_mypy_reports_no_error_outside_the_pending_files():
    errors, out = _mypy_errors()
    unexpected = {f: lines for f, lines in errors.items() if f not in PENDING_MYPY}
    assert not unexpected, (f"mypy: {sum(map(len, unexpected.values()))} error(s) in {len(unexpected)} file(s):\n"
                            + "\n".join(line for lines in unexpected.values() for line in lines))
    clean = sorted(f for f in PENDING_MYPY if f not in errors)
    missing = sorted(f for f in PENDING_MYPY if not (REPO / PKG / f).is_file())
    assert not missing, f"PENDING_MYPY lists files that do not exist: {missing}"
    assert not clean, f"mypy reports no error in {clean}: remove them from PENDING_MYPY (test/test_mypy.py)"
