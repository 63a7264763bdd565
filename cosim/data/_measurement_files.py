"""Reading a measurement file's variables for :func:`~cosim.data.datafile.load_data`: a MATLAB ``.mat`` file
(``scipy.io.loadmat`` through :func:`~cosim.data._trajectory_mat.load_mat`, which gives a cosim file's variables
under their signals' names) or a CSV/Parquet table (through :meth:`~cosim.data.trajectory.Trajectory.read`); and
what a file holds before it is read: :func:`file_variables`, and :func:`time_column`, cosim's one rule for the
time (``t`` when a file has one and no ``time``, else ``time``).

Each reader finds the time variable, checks that the file has every variable the columns use (an
:class:`~cosim.errors.UnknownVariableError` lists the ones it has) and gives them as :class:`_Raw`, with the
units, roles and meta a cosim file stores. :func:`_values` then gives one value a column reads as a vector of one
value per time (or a scalar).

A ``.mat`` variable may be a matrix of channels, read one at a time as ``data[:,k]`` (column ``k``) or
``data[k,:]`` (row ``k``); the time too (``time="data[:,0]"``). Indices are 0-based, as in NumPy; a vector takes
index 0 whichever way it is stored. An index outside the matrix is a one-line
:class:`~cosim.errors.DataError` naming the variable, its shape and the valid range. CSV and Parquet columns are
vectors, so indexing one is refused.

Examples
--------
>>> import tempfile, pathlib
>>> import numpy as np, scipy.io
>>> path = pathlib.Path(tempfile.mkdtemp()) / "rig.mat"
>>> scipy.io.savemat(path, {"data": np.arange(12.0).reshape(4, 3)})
>>> variables = {"data": scipy.io.loadmat(path)["data"]}
>>> _values(path, _Ref("data", 1, 2), variables, None)
array([ 2.,  5.,  8., 11.])
>>> _values(path, _Ref("data", 1, 3), variables, None)
Traceback (most recent call last):
cosim.errors.DataError: data[:,3]: data is 4 x 3, column index must be 0..2 (indices are 0-based, as in NumPy; \
file rig.mat)
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError, FmuNotFoundError, InvalidSettingError, UnknownVariableError
from ._column_expressions import _INDEX_HELP, _Column, _parse_reference, _plain_column, _Ref
from ._trajectory_mat import load_mat, mat_names
from .trajectory import Trajectory

_TABLES = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}


def file_variables(path: str | os.PathLike) -> list[str]:
    """The names of a data file's variables, time included, read without its data: a CSV's header row, a Parquet
    file's schema, a ``.mat`` file's variables (a cosim file's under its signals' names).

    Raises
    ------
    FmuNotFoundError
        No file at `path`.
    InvalidSettingError
        A suffix other than .csv, .parquet, .pq, .mat.
    DataError
        A file that cannot be read as its suffix says.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "rig.csv"
    >>> _ = path.write_text("t,volts,pos\\n0,1,2\\n")
    >>> file_variables(path), time_column(path)
    (['t', 'volts', 'pos'], 't')
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (*_TABLES, ".mat"):
        raise InvalidSettingError(f"cannot tell the format of {path.name!r} from its suffix; use .csv, .parquet, .pq "
                                  "or .mat")
    if not path.is_file():
        what = "is a folder, not a file" if path.is_dir() else "does not exist"
        raise FmuNotFoundError(f"data file {path} {what}; check the path")
    return mat_names(path) if suffix == ".mat" else _table_names(path, _TABLES[suffix])


def time_column(source: str | os.PathLike | Sequence[str]) -> str:
    """The time of a data file by cosim's rule: ``t`` when the file has a ``t`` and no ``time``, else ``time``
    (the column cosim writes, beside which a signal may be named ``t``).

    Parameters
    ----------
    source : path-like or sequence of str
        A CSV, Parquet or ``.mat`` file (its names are read by :func:`file_variables`, not its data), or the
        names themselves.

    Examples
    --------
    >>> time_column(["t", "u"]), time_column(["time", "t"]), time_column(["u"])
    ('t', 'time', 'time')
    """
    names = file_variables(source) if isinstance(source, (str, os.PathLike)) else list(source)
    return "t" if "t" in names and "time" not in names else "time"


@dataclass
class _Raw:
    """What a file gave: its variables (name -> ndarray as stored), time (a variable or a column of one), units,
    roles, meta."""

    variables: dict[str, np.ndarray]
    time: _Ref
    units: dict[str, str]
    roles: dict[str, str]
    meta: dict[str, Any]


def _listing(names: Sequence[str]) -> str:
    return ", ".join(names) or "(nothing)"


def _refuse_index(path: Path, ref: _Ref, where: str) -> None:
    """CSV and Parquet columns are vectors: indexing one (``qm[:,0]``) is refused."""
    if ref.axis is not None:
        kind = "Parquet" if path.suffix.lower() in (".parquet", ".pq") else "CSV"
        raise DataError(f"{where}: {ref.key} indexes {ref.variable!r} as a matrix, but {path.name} is a {kind} "
                        f"file, whose columns are vectors (only a .mat variable can be a matrix; indices are "
                        f"0-based, as in NumPy); use the column by name, {ref.variable}")


def _time_name(path: Path, names: Sequence[str], time: str | None, matrices: bool = True) -> _Ref:
    """The time: :func:`time_column`'s by default, else the variable `time` names or the column or row of a ``.mat``
    matrix it indexes (``"data[:,0]"``; `matrices` False, for a CSV or Parquet table, refuses that)."""
    if time is not None and time not in names:
        ref = _parse_reference(time, f"time {time!r}")
        if ref is not None:
            if not matrices:
                _refuse_index(path, ref, f"time {time!r}")
            if ref.variable in names:
                return ref
            raise UnknownVariableError(f"{path.name} has no variable {ref.variable!r} (time {time!r}); it has: "
                                       f"{_listing(names)}; check the spelling")
    name = time_column(names) if time is None else time
    if name in names:
        return _Ref(name)
    wanted = "'t' or 'time'" if time is None else repr(time)
    raise UnknownVariableError(f"{path.name} has no time variable {wanted}; it has: {_listing(names)}; "
                               "pass time=<name of the time variable> (--time on the command line; data[:,0] "
                               "for column 0 of a .mat matrix)")


def _missing(path: Path, names: Sequence[str], columns: Sequence[_Column]) -> None:
    for column in columns:
        for var in column.variables:
            if var not in names:
                base = var.partition("[")[0].strip()
                hint = (f"; to read one column of the matrix {base}, name it: x={var} (indices are 0-based)"
                        if column.plain and ":" in var and base in names else
                        f"; {base} is a matrix: {_INDEX_HELP}" if "[" in var and base in names else
                        "; check the spelling")
                raise UnknownVariableError(f"{path.name} has no variable {var!r} (column {column.describe()!r}); "
                                           f"it has: {_listing(names)}{hint}")


def _read_mat(path: Path, time: str | None, columns: list[_Column] | None) -> tuple[_Raw, list[_Column]]:
    variables, header = load_mat(path)
    names = list(variables)
    time_ref = _time_name(path, names, time)
    n = _values(path, time_ref, variables, None).size
    if columns is None:
        columns = [_plain_column(name) for name in names
                   if name != time_ref.variable and _is_numeric(variables[name]) and np.size(variables[name]) == n
                   and np.ndim(np.squeeze(variables[name])) == 1]
        if not columns:
            matrices = [name for name in names if _is_numeric(variables[name]) and np.ndim(variables[name]) == 2
                        and min(variables[name].shape) > 1]
            hint = (f"; name the columns of a matrix, e.g. columns=['x={matrices[0]}[:,1]'] (indices are 0-based)"
                    if matrices else "")
            raise DataError(f"{path.name} has no vector of {n} samples besides {time_ref.key!r}; it has: "
                            f"{_listing(names)}{hint}")
    _missing(path, names, columns)
    return _Raw(variables, time_ref, dict(header.get("units", {})), dict(header.get("roles", {})),
                dict(header.get("meta", {}))), columns


def _is_numeric(value: Any) -> bool:
    return isinstance(value, np.ndarray) and value.dtype.kind in "fiub"


def _shape(value: np.ndarray) -> str:
    return " x ".join(str(size) for size in value.shape) if value.ndim else "a scalar"


def _pick(path: Path, ref: _Ref, value: Any, n: int | None, time_name: str) -> np.ndarray:
    """Column or row ``ref.index`` of the matrix `value` (a vector, stored either way, takes index 0 only)."""
    if not _is_numeric(value):
        _vector(path, ref.variable, value, None)  # raises: not numbers
    where = f"{ref.key}: {ref.variable} is {_shape(value)}"
    zero_based = f"(indices are 0-based, as in NumPy; file {path.name})"
    if value.ndim > 2:
        raise DataError(f"{where}; only a vector or a 2-D matrix can be indexed, as {ref.variable}[:,k] or "
                        f"{ref.variable}[k,:] {zero_based}")
    if value.ndim < 2 or min(value.shape) == 1:  # a vector: [:,0] and [0,:] both give all of it
        if ref.index != 0:
            raise DataError(f"{where}, a vector: {ref.what} index must be 0 {zero_based}")
        return value.reshape(-1)
    count = value.shape[ref.axis]  # type: ignore[index]  # axis is 0 or 1 here
    if not 0 <= ref.index < count:
        valid = f", {ref.what} index must be 0..{count - 1}" if count else f": it has no {ref.what}s"
        raise DataError(f"{where}{valid} {zero_based}")
    picked = np.take(value, ref.index, axis=ref.axis)
    if n is not None and picked.size != n and count == n:  # the channels run the other way
        other = _Ref(ref.variable, 1 - ref.axis, ref.index)  # type: ignore[operator]
        pattern = f"{ref.variable}[:,k]" if other.axis == 1 else f"{ref.variable}[k,:]"
        fix = other.key if ref.index < picked.size else f"{pattern} with k in 0..{picked.size - 1}"
        raise DataError(f"{where}: its {other.what}s are the channels ({n} samples, like {time_name!r}), so "
                        f"{ref.key} has {picked.size} values; write {fix} {zero_based}")
    return picked


def _values(path: Path, ref: _Ref, variables: dict[str, np.ndarray], n: int | None,
            time_name: str = "") -> np.ndarray:
    """What `ref` reads from the file's `variables`, as :func:`_vector` gives it."""
    value = variables[ref.variable]
    if ref.axis is not None:
        value = _pick(path, ref, value, n, time_name)
    return _vector(path, ref.key, value, n, time_name)


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
        hint = f"; {_INDEX_HELP} ({name}[:,0] is its first column)" if squeezed.ndim == 2 else ""
        raise DataError(f"variable {name!r} of {path.name} has shape {shape}; expected {expected}{hint}")
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
    time_ref = _time_name(path, names, time, matrices=False)
    time_name = time_ref.variable
    if columns is None:
        columns = [_plain_column(name) for name in names if name != time_name]
    for column in columns:
        for ref in column.references:
            _refuse_index(path, ref, f"column {column.describe()!r}")
    _missing(path, names, columns)
    needed = list(dict.fromkeys(v for c in columns for v in c.variables if v != time_name))
    traj = Trajectory.read(path, time=time_name, columns=needed)
    variables = {name: traj[name] for name in traj.names}
    variables[time_name] = traj.time
    units = dict(zip(traj.names, traj.units, strict=True))
    roles = dict(zip(traj.names, traj.roles, strict=True))
    return _Raw(variables, time_ref, units, roles, dict(traj.meta)), columns
