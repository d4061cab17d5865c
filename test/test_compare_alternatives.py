"""scripts/compare_alternatives.py: its scoring against the truth and its one-line answer without the alternatives."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "compare_alternatives.py"


def _script():
    spec = importlib.util.spec_from_file_location("compare_alternatives", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod          # its dataclass looks its module up
    spec.loader.exec_module(mod)
    return mod


def test_found_modes_are_matched_one_to_one_within_the_tolerance():
    ca = _script()
    truth = np.array([[62.0, 0.01], [71.0, 0.015], [240.0, 0.02]])
    # one mode between the pair (matches the nearer, 62 Hz, only), one 4 % off (matched), one 30 % off (spurious)
    found = np.array([[64.0, 0.02], [240.0 * 1.04, 0.02], [300.0, 0.1]])
    s = ca.score(found, truth)
    assert (s["found"], s["matched"], s["spurious"]) == (3, 2, 1)
    assert math.isclose(s["df"], 4.0) and math.isclose(s["dz"], 100.0)     # worst: 240 Hz / 62 Hz
    assert ca.score(np.zeros((0, 2)), truth)["matched"] == 0


def test_without_the_alternatives_it_says_how_to_install_them_in_one_line(capsys, monkeypatch):
    ca = _script()
    monkeypatch.setattr(ca, "missing_packages", lambda: ["pyOMA-2"])
    assert ca.main(["--quick"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install -r scripts/requirements-compare.txt" in err[0] and "pyOMA-2" in err[0]
