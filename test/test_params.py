"""Each parameter is declared once (issue 15): core/params.py rows <-> settings dataclass fields."""

from __future__ import annotations

import types
import typing
from dataclasses import fields

import pytest

from additive_rsrivc_ros.config import all_params, validate_params
from additive_rsrivc_ros.core.diagnosis.faults import FaultSettings
from additive_rsrivc_ros.core.params import (
    ESTIMATOR_PARAMS,
    FAULT_PARAMS,
    EstimatorOptions,
    field_params,
    settings_as_params,
    settings_from_params,
)

SETTINGS = (EstimatorOptions, FaultSettings)
PY_TYPE = {"bool": bool, "int": int, "double": float, "string": str}


def _matches(hint: typing.Any, row_type: str) -> bool:
    """The field type a row of ``row_type`` fills: float for double, tuple[float, ...] for double[] ..."""
    if row_type.endswith("[]"):
        return typing.get_origin(hint) is tuple and typing.get_args(hint) == (PY_TYPE[row_type[:-2]], Ellipsis)
    return hint is PY_TYPE[row_type]


def _field_rows() -> list[tuple[type, str, typing.Any, tuple[str, ...]]]:
    out = []
    for cls in SETTINGS:
        hints = typing.get_type_hints(cls)
        out += [(cls, f.name, hints[f.name], field_params(f)) for f in fields(cls)]
    return out


def test_every_core_row_fills_exactly_one_settings_field():
    filled = [name for *_, names in _field_rows() for name in names]
    rows = [p.name for p in (*ESTIMATOR_PARAMS, *FAULT_PARAMS)]
    assert sorted(filled) == sorted(rows), "rows without a field, or fields filled twice: " + str(
        sorted(set(rows) ^ set(filled)) or [n for n in filled if filled.count(n) > 1])


def test_every_settings_field_names_rows_of_its_type():
    table = {p.name: p for p in all_params()}
    for cls, name, hint, names in _field_rows():
        assert names and all(n in table for n in names), f"{cls.__name__}.{name}: unknown rows {names}"
        if len(names) == 1:
            assert _matches(hint, table[names[0]].type), f"{cls.__name__}.{name}: {hint} vs {table[names[0]].type}"
            continue
        assert typing.get_origin(hint) is tuple, f"{cls.__name__}.{name} fills {len(names)} rows: needs a tuple"
        args = typing.get_args(hint)
        per_row = [args[0]] * len(names) if args[1:] == (Ellipsis,) else list(args)
        assert len(per_row) == len(names), f"{cls.__name__}.{name}: {hint} for {names}"
        for n, h in zip(names, per_row, strict=True):
            assert _matches(h, table[n].type), f"{cls.__name__}.{name} ({n}): {h} vs {table[n].type}"


@pytest.mark.parametrize("cls", SETTINGS, ids=lambda c: c.__name__)
def test_settings_defaults_are_the_table_defaults_and_round_trip(cls):
    defaults = validate_params({})
    built = settings_from_params(cls, defaults)
    assert built == cls()
    flat = settings_as_params(built)
    assert flat == {k: defaults[k] for k in flat}
    assert settings_from_params(cls, flat) == built


def test_a_changed_parameter_reaches_its_field():
    p = validate_params({"faults.min_change.gain": 0.3, "faults.health.stuck_min_samples": 7,
                         "faults.baseline.gain": [1.0, 2.0], "estimator.p0_policy": "relative"})
    s = FaultSettings.from_params(p)
    assert s.min_change == (0.02, 0.2, 0.3) and s.health_stuck_min_samples == 7
    assert s.baseline_value == ((), (), (1.0, 2.0))
    assert EstimatorOptions.from_params(p).p0_policy == "relative"


def test_field_types_are_plain():
    """Field types stay plain Python (no Optional/Union): a row's value always fills them."""
    for cls, name, hint, _ in _field_rows():
        assert typing.get_origin(hint) not in (typing.Union, types.UnionType), f"{cls.__name__}.{name}: {hint}"
