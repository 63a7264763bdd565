"""The files of a :class:`~cosim.data.trajectory.Trajectory`: CSV and Parquet, written and read (``.mat`` files:
:mod:`._trajectory_mat`).

The formats are described in :mod:`cosim.data.trajectory`. Writers take a trajectory and write atomically
(:func:`~cosim.files.atomic_output`); :func:`read_file` gives the time column, the signals and the cosim header
(units, roles, meta) of a cosim file or of another tool's table, for :meth:`Trajectory.read` to build from.
A CSV is plain (a header row, then numbers: what ``pandas.read_csv`` and MATLAB ``readtable`` read as is); its
header lives in the sidecar ``NAME.meta.json``. CSVs of cosim < 0.2 carried it in a first comment line
``# cosim-trajectory v1 {...}``; they still read. pandas and pyarrow are imported when a file is written or
read, not with cosim.
"""

from __future__ import annotations

import functools
import json
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError, FmuNotFoundError, InvalidSettingError
from ..files import atomic_output, json_default, write_text_atomic
from ._trajectory_checks import _TIME, _as_names

if TYPE_CHECKING:
    import pandas as pd

    from .trajectory import Trajectory

__all__ = ["read_file", "sidecar_path", "write_csv", "write_parquet"]

_FORMAT = "cosim-trajectory"
_VERSION = 1
_SIDECAR_VERSION = 2
_CSV_PREFIX = f"# {_FORMAT} v"
_PARQUET_KEY = _FORMAT.encode()
_SUFFIXES = MappingProxyType({".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".mat": "mat"})


@functools.cache
def _csv_read_options() -> dict[str, Any]:
    """Options of ``pandas.read_csv`` that read floats back exactly, for the installed pandas."""
    import pandas as pd

    # pandas < 3 parses floats with a fast, not always exact parser unless asked; pandas 3 is exact by default
    return {"float_precision": "round_trip"} if int(pd.__version__.split(".")[0]) < 3 else {}


def _header(traj: Trajectory) -> dict[str, Any]:
    return {"units": dict(zip(traj.names, traj.units, strict=True)),
            "roles": dict(zip(traj.names, traj.roles, strict=True)), "meta": traj.meta}


def _column(traj: Trajectory, i: int) -> np.ndarray:
    """Column `i` as written: whole numbers for an integer or Boolean variable of the FMU that gave it
    (``meta["types"]``, e.g. Int32, UInt8, Boolean as 0/1), floats otherwise."""
    values = traj.values[:, i]
    fmi_type = (traj.meta.get("types") or {}).get(traj.names[i])
    if fmi_type and fmi_type not in ("Float32", "Float64", "Real") and np.all(values == np.round(values)) \
            and np.all(np.abs(values) < 2.0**63):
        return values.astype(np.int64)
    return values


def sidecar_path(path: str | os.PathLike) -> Path:
    """The metadata file beside a CSV: ``run.csv`` -> ``run.meta.json``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.meta.json")


def write_csv(traj: Trajectory, path: str | os.PathLike) -> Path:
    """Write `traj` as a plain CSV file and its header as the sidecar ``NAME.meta.json``, both atomically.

    The sidecar names the CSV's columns, so that a reader can tell a sidecar left from another file apart.
    """
    import pandas as pd

    frame = pd.DataFrame({name: _column(traj, i) for i, name in enumerate(traj.names)}, columns=list(traj.names))
    frame.insert(0, _TIME, traj.time)
    dt = float(np.median(np.diff(traj.time))) if len(traj) > 1 and traj.is_uniform() else None
    sidecar = {"format": _FORMAT, "version": _SIDECAR_VERSION, "data": Path(path).name,
               "columns": [_TIME, *traj.names], "sample_time": dt, **_header(traj)}
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        frame.to_csv(handle, index=False, lineterminator="\n")
        handle.close()
        write_text_atomic(sidecar_path(path), json.dumps(sidecar, indent=1, default=json_default) + "\n")
    return Path(path)


def write_parquet(traj: Trajectory, path: str | os.PathLike) -> Path:
    """Write `traj` to a Parquet file atomically and return its path."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    columns = [pa.array(traj.time)] + [pa.array(_column(traj, i)) for i in range(len(traj.names))]
    table = pa.Table.from_arrays(columns, names=[_TIME, *traj.names])
    header = json.dumps({"version": _VERSION, **_header(traj)}).encode()
    table = table.replace_schema_metadata({_PARQUET_KEY: header})
    with atomic_output(path) as tmp:
        pq.write_table(table, tmp)
    return Path(path)


def read_file(path: Path, time: str, columns: str | Sequence[str] | None
              ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """Time, signals (all, or `columns` in that order) and cosim header (``{}`` for a plain file) of `path`."""
    kind = _file_kind(path)
    if not path.is_file():
        what = "is a folder, not a file" if path.is_dir() else "does not exist"
        raise FmuNotFoundError(f"data file {path} {what}; expected a .csv or .parquet file; "
                               "check the path")
    wanted = None if columns is None else [c for c in _as_names(columns) if c != time]
    reader = _read_csv if kind == "csv" else _read_parquet
    return reader(path, time, wanted)


def _file_kind(path: Path) -> str:
    kind = _SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InvalidSettingError(f"cannot tell the format of {path.name!r} from its suffix; "
                                  "use .csv, .parquet, .pq or .mat")
    return kind


def _check_columns(path: Path, present: Sequence[str], time: str, wanted: Sequence[str] | None) -> list[str]:
    listing = ", ".join(present) or "(none)"
    if time not in present:
        raise DataError(f"{path.name} has no time column {time!r}; columns present: {listing}; "
                        "pass time=<name of the time column>")
    if wanted is None:
        return [c for c in present if c != time]
    missing = [c for c in wanted if c not in present]
    if missing:
        raise DataError(f"{path.name} lacks column(s) {', '.join(missing)}; columns present: {listing}; "
                        "check the names")
    return list(wanted)


def _numeric(path: Path, name: str, column: pd.Series) -> np.ndarray:
    import pandas as pd

    if column.dtype.kind in "fiub":
        return column.to_numpy(dtype=float, na_value=np.nan)
    converted = pd.to_numeric(column, errors="coerce")
    bad = converted.isna() & column.notna()
    if bad.any():
        row = int(np.argmax(bad.to_numpy()))
        raise DataError(f"column {name!r} of {path.name} holds {column.iloc[row]!r} at data row {row}; "
                        "expected numbers; fix or drop that column")
    return converted.to_numpy(dtype=float, na_value=np.nan)


def _read_csv(path: Path, time: str, wanted: Sequence[str] | None
              ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    import pandas as pd

    header: dict[str, Any] = _read_sidecar(path)
    skip = 0
    with open(path, encoding="utf-8-sig") as handle:
        for line in handle:
            if not line.startswith("#"):
                break
            if skip == 0 and line.startswith(_CSV_PREFIX) and not header:
                version, _, body = line[len(_CSV_PREFIX):].partition(" ")
                header = _parse_header(path, version, body)
            skip += 1
    try:
        present = list(pd.read_csv(path, skiprows=skip, nrows=0, encoding="utf-8-sig").columns)
        names = _check_columns(path, present, time, wanted)
        frame = pd.read_csv(path, skiprows=skip, usecols=[time, *names], encoding="utf-8-sig",
                            **_csv_read_options())
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        if isinstance(exc, DataError):
            raise
        reason = " ".join(str(exc).split())
        raise DataError(f"cannot read {path.name} as CSV ({reason}); expected a header row then numbers"
                        ) from None
    data = {name: _numeric(path, name, frame[name]) for name in names}
    if header.get("columns") not in (None, present):
        warnings.warn(f"{sidecar_path(path).name} describes columns {header['columns']}, not those of "
                      f"{path.name}; its units, roles and meta are ignored (rewrite or delete it)", stacklevel=4)
        header = {}
    return _numeric(path, time, frame[time]), data, header


def _read_sidecar(path: Path) -> dict[str, Any]:
    """The header in ``NAME.meta.json`` beside `path` (``{}`` when there is none)."""
    side = sidecar_path(path)
    if not side.is_file():
        return {}
    try:
        header = json.loads(side.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError):
        header = None
    if not isinstance(header, dict) or header.get("format") != _FORMAT:
        raise DataError(f"{side.name} beside {path.name} is not a {_FORMAT} sidecar (expected JSON with "
                        f'"format": "{_FORMAT}"); delete or rename it')
    if header.get("version") != _SIDECAR_VERSION:
        raise DataError(f"{side.name} has {_FORMAT} version {header.get('version')!r}; this cosim reads "
                        f"version {_SIDECAR_VERSION}; rewrite the file with this cosim")
    return header


def _parse_header(path: Path, version: Any, body: str | bytes) -> dict[str, Any]:
    """The JSON of units, roles and meta, for a file of format version `version`."""
    try:
        header = json.loads(body) if str(version).strip() == str(_VERSION) else None
    except (json.JSONDecodeError, UnicodeDecodeError):
        header = None
    if not isinstance(header, dict):
        raise DataError(f"{path.name} has an unreadable {_FORMAT} header (version {str(version).strip()!r}); "
                        f"expected version {_VERSION} with JSON; rewrite the file with this cosim")
    return header


def _read_parquet(path: Path, time: str, wanted: Sequence[str] | None
                  ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        schema = pq.read_schema(path)
        names = _check_columns(path, schema.names, time, wanted)
        table = pq.read_table(path, columns=[time, *names])
    except (pa.ArrowException, OSError) as exc:
        reason = " ".join(str(exc).split())
        raise DataError(f"cannot read {path.name} as Parquet ({reason}); expected a Parquet table") from None
    raw = (schema.metadata or {}).get(_PARQUET_KEY)
    header: dict[str, Any] = {}
    if raw is not None:
        try:
            version = json.loads(raw).get("version", "?")
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            version = "?"
        header = _parse_header(path, version, raw)

    def column(name: str) -> np.ndarray:
        chunked = table.column(name)
        if not (pa.types.is_floating(chunked.type) or pa.types.is_integer(chunked.type)
                or pa.types.is_boolean(chunked.type) or pa.types.is_decimal(chunked.type)):
            raise DataError(f"column {name!r} of {path.name} has type {chunked.type}; expected numbers "
                            "(time in s as a number); convert or drop that column")
        return np.asarray(chunked.to_numpy(zero_copy_only=False), dtype=float)

    return column(time), {name: column(name) for name in names}, header
