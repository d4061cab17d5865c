"""The public names of docs/INTERFACE.md, written once, and the small helpers every writer and reader shares.

Mode fields (``/diagnostics`` mode status keys, ``~/modes`` field order, CSV columns), quantity names (events,
fault flags, trends), status level names, the headers of ``estimates.csv``, ``events.csv`` and ``fleet.csv``
and the ``events.csv`` row are defined here and nowhere else; the node, the offline tools, the report and the
fault logic import them. Pure Python: numpy is imported only inside :func:`json_clean` and :func:`plain` (a
command's ``--help`` stays fast).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

# ------------------------------------------------------------------------------------------------- mode fields
MODE_FIELDS: tuple[str, ...] = ("natural_frequency_hz", "damping_ratio", "gain", "natural_frequency_hz_std",
                                "damping_ratio_std", "gain_std")
"""Columns of ``modal()`` (``f_hz, zeta, gain`` and their std), the ``~/modes`` field order and the CSV columns."""
BASELINE_KEYS: tuple[str, ...] = MODE_FIELDS[:3]
"""The modal values a baseline holds (``faults.baseline.<key>`` parameters)."""
BASELINE_FIELDS: tuple[str, ...] = tuple(f"baseline_{k}" for k in BASELINE_KEYS)

# ------------------------------------------------------------------------------------------------- quantities
QUANTITIES: tuple[str, ...] = ("natural_frequency", "damping", "gain")
"""Quantity names of events, flags and trends; index q matches columns q and q + 3 of ``modal()``."""
FLAG_FIELDS: tuple[str, ...] = tuple(f"fault_{q}" for q in QUANTITIES)
MODE_KEYS: tuple[str, ...] = (*MODE_FIELDS, *BASELINE_FIELDS, *FLAG_FIELDS)
"""Exactly the interface's keys of a ``<node name>: mode <i>`` diagnostic status, in order."""
SIM_QUANTITIES: tuple[str, ...] = ("frequency", "damping", "gain")
"""The simulator's spelling of :data:`QUANTITIES` (``ModalChange.quantity``): recorded bags carry it in their
``/truth/fault`` records, so it stays; :func:`quantity_of` and :func:`sim_quantity_of` translate."""
DIRECTIONS: tuple[str, ...] = ("up", "down")


def quantity_of(sim_quantity: str) -> str:
    """The public quantity name (:data:`QUANTITIES`) of a simulator quantity (:data:`SIM_QUANTITIES`)."""
    return QUANTITIES[SIM_QUANTITIES.index(sim_quantity)]


def sim_quantity_of(quantity: str) -> str:
    """The simulator's name of a public quantity name (inverse of :func:`quantity_of`)."""
    return SIM_QUANTITIES[QUANTITIES.index(quantity)]


# ------------------------------------------------------------------------------------------------- levels
LEVEL_NAMES: tuple[str, ...] = ("OK", "WARN", "ERROR", "STALE")
"""``diagnostic_msgs/DiagnosticStatus`` level names by value (``core.faults.Level``)."""
VERDICTS: tuple[str, ...] = ("OK", "FAULT", "DEGRADED", "NO ESTIMATE")
"""``summary.json`` ``verdict`` values, best to worst."""
ALIGN_APPROXIMATE_RELATIVE = 1e-6
"""Above this relative residual the controller invariant ``u = C_d(q)(r - y)`` is approximate (float32 control gives
~1e-7): reported on health, and the verdict flags the model (the configured controller is not the loop's)."""
MODEL_ORDER_FLAGGED: tuple[str, ...] = ("too_low", "misfit")
"""``health['model_order']['state']`` values that flag the model (health WARN; the offline verdict DEGRADED)."""

# ------------------------------------------------------------------------------------------------- files
ESTIMATES_HEADER: tuple[str, ...] = ("time_s", "mode", *MODE_FIELDS, *FLAG_FIELDS)
EVENTS_HEADER: tuple[str, ...] = ("onset_time_s", "clear_time_s", "mode", "quantity", "direction", "baseline",
                                  "value")
FLEET_HEADER: tuple[str, ...] = ("bag", "start_time_s", "mode", *BASELINE_KEYS, *BASELINE_FIELDS, "events",
                                 "verdict")
FINDING_KEYS: tuple[str, ...] = ("machine", "mode", "quantity", "direction", "first_bag", "change_percent")
"""Keys of one fleet-level drift finding in ``fleet.json``."""


# ------------------------------------------------------------------------------------------------- helpers
def num(v: Any) -> str:
    """Lossless decimal string of a number (shortest round-trip repr): ``nan``, ``inf``, ``-inf`` when not finite.

    The CSV cells and the ``/diagnostics`` values."""
    x = float(v)
    return repr(x) if math.isfinite(x) else ("nan" if math.isnan(x) else ("inf" if x > 0 else "-inf"))


def events_csv_cells(row: Mapping[str, Any]) -> list[Any]:
    """One ``events.csv`` line from an event's columns (``FaultEvent.csv_row``): lossless decimals, an empty clear
    time while the event is open."""
    clear = row["clear_time_s"]
    return [num(row["onset_time_s"]), "" if clear is None or clear == "" else num(clear), row["mode"],
            row["quantity"], row["direction"], num(row["baseline"]), num(row["value"])]


def one_line(exc: BaseException, limit: int | None = None) -> str:
    """The first line of an exception's message (its type name when empty), cut to ``limit`` characters."""
    text = str(exc).strip().splitlines()
    line = text[0] if text else type(exc).__name__
    return line if limit is None else line[:limit]


def plain(v: Any) -> Any:
    """A numpy array or scalar as plain Python (lists, int, float); anything else unchanged (NaN kept)."""
    import numpy as np

    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def json_clean(v: Any) -> Any:
    """Plain, strict-JSON data, recursively: numpy to Python, tuples to lists, paths to strings, non-finite floats
    to None (no NaN tokens)."""
    import numpy as np

    if isinstance(v, dict):
        return {str(k): json_clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [json_clean(x) for x in v]
    if isinstance(v, np.ndarray | np.generic):
        return json_clean(plain(v))
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, Path):
        return str(v)
    return v
