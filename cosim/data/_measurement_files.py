"""Reading a measurement file's variables for :func:`~cosim.data.datafile.load_data`: a MATLAB ``.mat`` file
(``scipy.io.loadmat``, imported when one is read) or a CSV/Parquet table (through
:meth:`~cosim.data.trajectory.Trajectory.read`).

Each reader finds the time variable, checks that the file has every variable the columns use (an
:class:`~cosim.errors.UnknownVariableError` lists the ones it has) and gives them as :class:`_Raw`, with the
units, roles and meta a cosim file stores.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError, UnknownVariableError
from ._column_expressions import _Column, _plain_column
from .trajectory import Trajectory

_TIME_NAMES = ("t", "time")


@dataclass
class _Raw:
    """What a file gave: its variables (name -> ndarray as stored), time name, units, roles, meta."""

    variables: dict[str, np.ndarray]
    time: str
    units: dict[str, str]
    roles: dict[str, str]
    meta: dict[str, Any]


def _listing(names: Sequence[str]) -> str:
    return ", ".join(names) or "(nothing)"


def _time_name(path: Path, names: Sequence[str], time: str | None) -> str:
    candidates = _TIME_NAMES if time is None else (time,)
    for name in candidates:
        if name in names:
            return name
    wanted = " or ".join(repr(c) for c in candidates)
    raise UnknownVariableError(f"{path.name} has no time variable {wanted}; it has: {_listing(names)}; "
                               "pass time=<name of the time variable> (--time on the command line)")


def _missing(path: Path, names: Sequence[str], columns: Sequence[_Column]) -> None:
    for column in columns:
        for var in column.variables:
            if var not in names:
                raise UnknownVariableError(f"{path.name} has no variable {var!r} (column {column.describe()!r}); "
                                           f"it has: {_listing(names)}; check the spelling")


def _read_mat(path: Path, time: str | None, columns: list[_Column] | None) -> tuple[_Raw, list[_Column]]:
    import scipy.io

    try:
        data = scipy.io.loadmat(path)
    except NotImplementedError:
        raise DataError(f"{path.name} is a MATLAB v7.3 (HDF5) file, which cosim does not read; re-save it in "
                        f"MATLAB with save('{path.name}', ..., '-v7') or export it as CSV") from None
    except Exception as exc:  # scipy raises many types (MatReadError, ValueError, IndexError...) on a bad file
        reason = " ".join(str(exc).split())
        raise DataError(f"cannot read {path.name} as a MATLAB file ({reason}); expected a .mat file saved "
                        "with MATLAB's save (version 7 or older)") from None
    variables = {k: v for k, v in data.items() if not k.startswith("__")}
    names = list(variables)
    time_name = _time_name(path, names, time)
    n = _vector(path, time_name, variables[time_name], None).size
    if columns is None:
        columns = [_plain_column(name) for name in names
                   if name != time_name and _is_numeric(variables[name]) and np.size(variables[name]) == n
                   and np.ndim(np.squeeze(variables[name])) == 1]
        if not columns:
            raise DataError(f"{path.name} has no vector of {n} samples besides {time_name!r}; it has: "
                            f"{_listing(names)}")
    _missing(path, names, columns)
    return _Raw(variables, time_name, {}, {}, {}), columns


def _is_numeric(value: Any) -> bool:
    return isinstance(value, np.ndarray) and value.dtype.kind in "fiub"


def _vector(path: Path, name: str, value: Any, n: int | None, time_name: str = "") -> np.ndarray:
    """`value` as a float vector of `n` samples (any length when `n` is None), or a float for a scalar."""
    shape = getattr(value, "shape", ())
    if not _is_numeric(value):
        kind = type(value).__name__ if not isinstance(value, np.ndarray) else f"{value.dtype} array"
        raise DataError(f"variable {name!r} of {path.name} is a {kind}, not numbers; use a numeric vector")
    squeezed = np.squeeze(np.asarray(value, dtype=float))
    if n is not None and squeezed.ndim == 0:
        return squeezed  # a scalar, broadcast over time
    if squeezed.ndim != 1:
        expected = f"a vector of {n} samples like {time_name!r} or a scalar" if n else "a vector"
        raise DataError(f"variable {name!r} of {path.name} has shape {shape}; expected {expected}")
    if n is not None and squeezed.size != n:
        raise DataError(f"variable {name!r} of {path.name} has {squeezed.size} samples, expected {n} like "
                        f"{time_name!r}; use variables recorded on the same time base")
    return squeezed


def _table_names(path: Path, kind: str) -> list[str]:
    if kind == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            return list(pq.read_schema(path).names)
        except (pa.ArrowException, OSError) as exc:
            reason = " ".join(str(exc).split())
            raise DataError(f"cannot read {path.name} as Parquet ({reason}); expected a Parquet table") from None
    try:
        with open(path, encoding="utf-8-sig", newline="") as handle:
            for line in handle:
                if not line.startswith("#"):
                    return [name.strip() for name in next(csv.reader([line]))]
    except UnicodeDecodeError:
        raise DataError(f"cannot read {path.name} as CSV (not UTF-8 text); expected a header row then numbers"
                        ) from None
    raise DataError(f"{path.name} has no header row; expected a header row (time and signal names) then numbers")


def _read_table(path: Path, kind: str, time: str | None, columns: list[_Column] | None
                ) -> tuple[_Raw, list[_Column]]:
    names = _table_names(path, kind)
    time_name = _time_name(path, names, time)
    if columns is None:
        columns = [_plain_column(name) for name in names if name != time_name]
    _missing(path, names, columns)
    needed = list(dict.fromkeys(v for c in columns for v in c.variables if v != time_name))
    traj = Trajectory.read(path, time=time_name, columns=needed)
    variables = {name: traj[name] for name in traj.names}
    variables[time_name] = traj.time
    units = dict(zip(traj.names, traj.units, strict=True))
    roles = dict(zip(traj.names, traj.roles, strict=True))
    return _Raw(variables, time_name, units, roles, dict(traj.meta)), columns
