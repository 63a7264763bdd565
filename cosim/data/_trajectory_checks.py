"""What makes a :class:`~cosim.data.trajectory.Trajectory` valid: its fields checked and normalised.

:func:`checked_fields` turns what a trajectory is built from into read-only float arrays, tuples of names, units
and roles, and a ``meta`` copied through JSON, or raises an error that names the column, time or row at fault and
says what to do (:class:`~cosim.errors.DataError`, :class:`~cosim.errors.InvalidSettingError` for a role).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from ..errors import DataError, InvalidSettingError
from ..files import json_default

__all__ = ["ROLES", "checked_fields"]

_TIME = "time"  # the time column's name, reserved

#: The roles a signal can have.
ROLES = ("state", "input", "output", "reference")


def _normalise_meta(meta: Mapping[str, Any] | None) -> dict[str, Any]:
    if meta is None:
        return {}
    if not isinstance(meta, Mapping):
        raise DataError(f"meta must be a dict, got {type(meta).__name__}; pass a JSON-serialisable dict")
    try:
        return json.loads(json.dumps(dict(meta), default=json_default))
    except (TypeError, ValueError) as exc:
        raise DataError(f"meta is not JSON-serialisable ({exc}); keep it to str, numbers, lists and dicts"
                        ) from None


def _as_names(names: str | Iterable[str]) -> tuple[str, ...]:
    return (names,) if isinstance(names, str) else tuple(names)


def _fmt_time(t: float) -> str:
    return f"{t:.9g}"


def checked_fields(
    time: Any, values: Any, names: str | Iterable[str], units: str | Iterable[str] | None,
    roles: str | Iterable[str] | None, meta: Mapping[str, Any] | None,
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], tuple[str, ...], tuple[str, ...], dict[str, Any]]:
    """The fields of a trajectory, checked: read-only ``time`` and ``values``, names, units, roles, meta."""
    names = _as_names(names)
    bad = [name for name in names if not isinstance(name, str) or not name or name == _TIME]
    if bad:
        raise DataError(f"signal names must be non-empty strings other than {_TIME!r}, got {bad[0]!r}; "
                        "rename that signal")
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise DataError(f"signal names must be unique, repeated: {', '.join(repeated)}; rename them")
    m = len(names)
    try:
        time = np.array(time, dtype=float)
        values = np.array(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"time and values must be numeric arrays ({exc}); convert the data to floats"
                        ) from None
    if time.ndim != 1 or time.size == 0:
        raise DataError(f"time must be a non-empty 1-D array, got shape {time.shape}; "
                        "pass one time per sample")
    n = time.size
    if values.shape != (n, m):
        raise DataError(f"values has shape {values.shape}, expected (n_samples, n_signals) = ({n}, {m}); "
                        "pass one row per time and one column per name")
    finite = np.isfinite(time)
    if not finite.all():
        i = int(np.argmin(finite))
        raise DataError(f"time is {time[i]} at index {i}; expected finite times in s; drop that row")
    steps = np.diff(time)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        raise DataError(f"time is not strictly increasing at index {i} (t={_fmt_time(time[i])} s after "
                        f"{_fmt_time(time[i - 1])} s); sort the rows and drop repeated times")
    finite = np.isfinite(values)
    if not finite.all():
        row = int(np.argmin(finite.all(axis=1)))
        col = int(np.argmin(finite[row]))
        raise DataError(f"signal {names[col]!r} is {values[row, col]} at t={_fmt_time(time[row])} s "
                        f"(row {row}); expected finite values; drop or fill the bad samples")
    units = ("",) * m if units is None else tuple(_as_names(units))
    roles = ("output",) * m if roles is None else tuple(_as_names(roles))
    if len(units) != m or not all(isinstance(u, str) for u in units):
        raise DataError(f"units must be {m} strings, one per signal, got {units!r}; use '' when unknown")
    if len(roles) != m:
        raise DataError(f"roles must be {m} strings, one per signal, got {roles!r}")
    unknown = [role for role in roles if role not in ROLES]
    if unknown:
        raise InvalidSettingError(f"unknown role {unknown[0]!r}; expected one of {', '.join(ROLES)}")
    time.setflags(write=False)
    values.setflags(write=False)
    return time, values, names, units, roles, _normalise_meta(meta)
