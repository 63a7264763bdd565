"""A :class:`~cosim.data.trajectory.Trajectory` as a MATLAB ``.mat`` file, for ``scipy.io.loadmat`` and MATLAB's
``load``, read back by cosim with its names, units, roles and meta.

The file (MATLAB 5 format, compressed as ``save -v7`` does) holds

* ``time``: the sample times in s, a column vector;
* one column vector per signal, values exact: float64, or int64 for an integer or Boolean variable of the FMU
  that gave it (``meta["types"]``), as the CSV writes whole numbers. A signal whose name is a MATLAB identifier
  keeps it; another gets one by :func:`matlab_names` (``mass.s`` -> ``mass_s``, ``x[2]`` -> ``x_2``,
  ``der(x)`` -> ``der_x``), made unique;
* ``cosim_trajectory``: a char row holding the JSON of the CSV's sidecar (format, version, the columns, ``names``
  from each MATLAB name back to the signal's, units, roles, sample time, meta), so that the mapping is reversed
  exactly whatever the names. In MATLAB: ``load run.mat; plot(time, mass_s); h = jsondecode(cosim_trajectory)``.

:func:`load_mat` reads a ``.mat`` file's variables under the signals' names (that variable applied when there is
one), for :meth:`Trajectory.read` (:func:`read_mat`) and :func:`~cosim.data.datafile.load_data`. scipy is imported
when a file is written or read. Writes are atomic (:func:`~cosim.files.atomic_output`).

Examples
--------
>>> import tempfile, pathlib, scipy.io
>>> from cosim.data.trajectory import Trajectory
>>> traj = Trajectory.from_arrays([0.0, 0.5], {"mass.s": [0.2, 0.1]}, units={"mass.s": "m"})
>>> path = write_mat(traj, pathlib.Path(tempfile.mkdtemp()) / "run.mat")
>>> sorted(k for k in scipy.io.loadmat(path) if not k.startswith("__"))
['cosim_trajectory', 'mass_s', 'time']
>>> Trajectory.read(path) == traj
True
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError, FmuNotFoundError
from ..files import atomic_output, json_default
from ._trajectory_checks import _TIME, _as_names
from ._trajectory_files import _FORMAT, _column, _header

__all__ = ["HEADER", "load_mat", "mat_names", "matlab_names", "read_mat", "write_mat"]

#: The char variable of a cosim ``.mat`` file holding its header (JSON).
HEADER = "cosim_trajectory"
_MAT_VERSION = 1
_NAME_MAX = 63  # MATLAB's namelengthmax
_KEYWORDS = frozenset(("break", "case", "catch", "classdef", "continue", "else", "elseif", "end", "for", "function",
                       "global", "if", "otherwise", "parfor", "persistent", "return", "spmd", "switch", "try",
                       "while"))
_IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def _matlab_name(name: str) -> str:
    """`name` as a MATLAB identifier: itself when it is one, else its runs of other characters as ``_``, with
    ``x`` before a name that does not start with a letter and after ``x`` a keyword (MATLAB's makeValidName)."""
    if _IDENTIFIER.fullmatch(name) and name not in _KEYWORDS and len(name) <= _NAME_MAX:
        return name
    valid = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_")
    if not valid or not valid[0].isalpha():
        valid = "x" + ("_" if valid else "") + valid
    if valid in _KEYWORDS:
        valid = "x" + valid.capitalize()
    return valid[:_NAME_MAX]


def matlab_names(names: Sequence[str], reserved: Sequence[str] = (_TIME, HEADER)) -> dict[str, str]:
    """Signal name -> a MATLAB variable name for each of `names`: unique, none of `reserved`.

    A name that is a MATLAB identifier (letters, digits and ``_``, from a letter, 63 characters at most, no
    keyword) is kept; another becomes one (:func:`_matlab_name`), with ``_2``, ``_3``... where two would meet.
    The file's header maps them back (:func:`load_mat`).

    Examples
    --------
    >>> matlab_names(["mass.s", "x[2]", "der(x)", "omega_m", "mass_s", "end"])
    {'mass.s': 'mass_s_2', 'x[2]': 'x_2', 'der(x)': 'der_x', 'omega_m': 'omega_m', 'mass_s': 'mass_s', 'end': 'xEnd'}
    """
    taken = set(reserved)
    plain = {name for name in names if _matlab_name(name) == name}  # kept as they are: the others give way
    taken |= plain
    out: dict[str, str] = {}
    for name in names:
        if name in plain:
            out[name] = name
            continue
        base = candidate = _matlab_name(name)
        k = 1
        while candidate in taken:
            k += 1
            candidate = f"{base[:_NAME_MAX - len(str(k)) - 1]}_{k}"
        taken.add(candidate)
        out[name] = candidate
    return out


def write_mat(traj: Any, path: str | os.PathLike) -> Path:
    """Write the Trajectory `traj` as a MATLAB ``.mat`` file (the module docstring's layout), atomically."""
    import scipy.io

    names = matlab_names(traj.names)
    data: dict[str, Any] = {_TIME: np.asarray(traj.time, dtype=float).reshape(-1, 1)}
    for i, name in enumerate(traj.names):
        data[names[name]] = np.ascontiguousarray(_column(traj, i)).reshape(-1, 1)
    dt = float(np.median(np.diff(traj.time))) if len(traj) > 1 and traj.is_uniform() else None
    header = {"format": _FORMAT, "version": _MAT_VERSION, "data": Path(path).name,
              "columns": [_TIME, *names.values()], "names": {m: name for name, m in names.items()},
              "sample_time": dt, **_header(traj)}
    data[HEADER] = json.dumps(header, default=json_default, ensure_ascii=True)  # ASCII: a plain MATLAB char
    with atomic_output(path) as tmp, open(tmp, "wb") as handle:
        scipy.io.savemat(handle, data, do_compression=True, oned_as="column")
    return Path(path)


def _loadmat(path: Path, **options: Any) -> dict[str, Any]:
    import scipy.io

    if not path.is_file():
        what = "is a folder, not a file" if path.is_dir() else "does not exist"
        raise FmuNotFoundError(f"data file {path} {what}; check the path")
    try:
        return scipy.io.loadmat(path, **options)
    except NotImplementedError:
        raise DataError(f"{path.name} is a MATLAB v7.3 (HDF5) file, which cosim does not read; re-save it in "
                        f"MATLAB with save('{path.name}', ..., '-v7') or export it as CSV") from None
    except Exception as exc:  # scipy raises many types (MatReadError, ValueError, IndexError...) on a bad file
        reason = " ".join(str(exc).split())
        raise DataError(f"cannot read {path.name} as a MATLAB file ({reason}); expected a .mat file saved "
                        "with MATLAB's save (version 7 or older)") from None


def _parse_header(path: Path, value: Any) -> dict[str, Any]:
    """The header a ``cosim_trajectory`` char variable holds (``{}`` when `value` is None)."""
    if value is None:
        return {}
    try:
        text = "".join(np.asarray(value).ravel().tolist())
        header = json.loads(text)
    except (TypeError, ValueError):
        header = None
    if not isinstance(header, dict) or header.get("format") != _FORMAT or header.get("version") != _MAT_VERSION:
        raise DataError(f"{path.name} has a {HEADER} variable that is no {_FORMAT} header of version "
                        f"{_MAT_VERSION}; rewrite the file with this cosim, or delete that variable")
    return header


def load_mat(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, Any]]:
    """The variables of a ``.mat`` file by name (a cosim file's under its signals' names) and its cosim header
    (``{}`` for another tool's file). Raises :class:`~cosim.errors.DataError` for a file it cannot read."""
    path = Path(path)
    data = _loadmat(path)
    header = _parse_header(path, data.get(HEADER))
    real = header.get("names", {})
    variables = {str(real.get(key, key)): value for key, value in data.items()
                 if not key.startswith("__") and key != HEADER}
    return variables, header


def mat_names(path: str | os.PathLike) -> list[str]:
    """The variable names of a ``.mat`` file (a cosim file's as its signals' names), without reading its data."""
    import scipy.io

    path = Path(path)
    header = _parse_header(path, _loadmat(path, variable_names=[HEADER]).get(HEADER))  # a bad file is refused
    real = header.get("names", {})
    return [str(real.get(name, name)) for name, _, _ in scipy.io.whosmat(path) if name != HEADER]


def read_mat(path: Path, time: str, columns: str | Sequence[str] | None
             ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """Time, signals (every vector of one value per time, or `columns` in that order) and cosim header of a
    ``.mat`` file, for :meth:`Trajectory.read`."""
    wanted = None if columns is None else [c for c in _as_names(columns) if c != time]
    variables, header = load_mat(path)
    listing = ", ".join(variables) or "(none)"
    if time not in variables:
        raise DataError(f"{path.name} has no time variable {time!r}; variables present: {listing}; "
                        "pass time=<name of the time variable>")
    t = np.asarray(variables[time], dtype=float).reshape(-1) if _is_vector(variables[time]) else None
    if t is None:
        raise DataError(f"time {time!r} of {path.name} is not a vector; pass time=<name of the time vector>")
    vectors = [name for name, value in variables.items()
               if name != time and _is_vector(value) and np.size(value) == t.size]
    if wanted is None:
        names = vectors
    else:
        missing = [name for name in wanted if name not in vectors]
        if missing:
            raise DataError(f"{path.name} lacks vector(s) {', '.join(missing)} of {t.size} samples like {time!r}; "
                            f"variables present: {listing}; check the names (a matrix's columns are read by "
                            "load_data, e.g. columns=['x=data[:,1]'])")
        names = list(wanted)
    return t, {name: np.asarray(variables[name], dtype=float).reshape(-1) for name in names}, header


def _is_vector(value: Any) -> bool:
    return (isinstance(value, np.ndarray) and value.dtype.kind in "fiub" and value.ndim <= 2
            and (value.ndim < 2 or min(value.shape) == 1))
