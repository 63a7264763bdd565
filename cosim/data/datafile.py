"""Load measured data into a :class:`~cosim.data.trajectory.Trajectory`: :func:`load_data`, :func:`differentiate`,
:func:`check_excitation`.

One call reads a measurement file, picks or computes the columns, checks the record and adds the derivatives
that were not measured::

    traj = load_data("DATA_EMPS.mat", columns=["qm", "force=gtau*vir"], derive=["qm"],
                     derive_method="butterworth", roles={"qm": "state", "qm_dot": "state", "force": "input"})

Formats, by suffix
------------------
``.csv``, ``.parquet``, ``.pq``
    Read with :meth:`Trajectory.read` (a cosim file keeps its units, roles and meta; another tool's file needs a
    header row with a time column).
``.mat``
    MATLAB files up to version 7 (``scipy.io.loadmat``), each variable a column or row vector of one value per
    time, a scalar (a gain, say) that an expression broadcasts over time, or a matrix of channels read one
    column or row at a time (below); a cosim ``.mat`` file (``Trajectory.write("run.mat")``) keeps its signals'
    names, units, roles and meta. MATLAB v7.3 files are HDF5 files that cosim does not read: re-save them
    with ``save(file, '-v7')`` (or export a CSV).

Columns
-------
A column is a variable of the file (``"qm"``) or a named expression of the file's variables (``"force=gtau*vir"``,
``"force=35.15*vir + pulses_N"``): numbers and variables combined with ``+ - * /``, unary minus and
parentheses, parsed with :mod:`ast` (nothing is passed to ``eval``). Scalars broadcast over time. Give them as a
sequence of such strings or as a mapping ``{name: expression}``.

Matrix variables (``.mat`` only)
--------------------------------
A rig often saves every channel as a column of one array. Name each column you want: ``"pos=data[:,2]"`` is
column 2 of the variable ``data``, ``"pos=data[2,:]"`` row 2 of a matrix stored with one channel per row.
**Indices are 0-based, as in Python and NumPy**: ``data[:,0]`` is MATLAB's ``data(:,1)``. Spaces are free
(``data[:, 2]``), an indexed variable may stand in an expression (``"force=35.15*data[:,3]"``), and the time may
be one too (``time="data[:,0]"``). A vector takes index 0 whichever way it is stored. An index outside the
matrix is a :class:`~cosim.errors.DataError` naming the variable, its shape and the valid range
(``data[:,7]: data is 5000 x 4, column index must be 0..3 ...``). CSV and Parquet columns are vectors: indexing
one is refused.

Checks (each a one-line error naming what, where and what to do)
----------------------------------------------------------------
A missing file (:class:`~cosim.errors.FmuNotFoundError`); an unknown suffix
(:class:`~cosim.errors.InvalidSettingError`); a variable the file lacks
(:class:`~cosim.errors.UnknownVariableError`, listing the ones it has); a variable that is not a vector of one
value per time, fewer samples than :data:`MIN_SAMPLES` (or than the differentiator needs), a NaN or inf value
(naming the column, time and row), time that is not strictly increasing or not uniform (steps within
:data:`UNIFORM_RTOL` of the median step; ``resample=True`` interpolates onto a uniform grid instead), and an
input that is constant (:func:`check_excitation`): all :class:`~cosim.errors.DataError`.

Derivatives
-----------
``derive=["qm"]`` adds ``qm_dot`` (and ``qm_ddot`` with ``derive_order=2``), computed from the sampled ``qm``
by one of :data:`DERIVATIVE_METHODS` (see :func:`differentiate`; both live in :mod:`cosim.data.derivatives` and
import from here too). Inputs are zero-order held between samples everywhere in cosim; a resampled input is
linearly interpolated at the new sample times, then held.

The columns' expressions are parsed in :mod:`~cosim.data._column_expressions` and the files read in
:mod:`~cosim.data._measurement_files`; this module checks the record and puts it together.

Examples
--------
>>> import tempfile, pathlib
>>> import numpy as np, scipy.io
>>> path = pathlib.Path(tempfile.mkdtemp()) / "axis.mat"
>>> t = np.arange(200) * 1e-3
>>> scipy.io.savemat(path, {"t": t[:, None], "x": (0.5 * t**2)[:, None], "v": np.sin(t)[:, None], "g": 2.0})
>>> traj = load_data(path, columns=["x", "u=g*v"], derive=["x"], roles={"u": "input", "x": "state"})
>>> traj.names, traj.roles
(('x', 'x_dot', 'u'), ('state', 'output', 'input'))
>>> bool(np.allclose(traj["x_dot"], t))
True

A matrix with time in column 0 and the channels in the next columns:

>>> rig = path.with_name("rig.mat")
>>> scipy.io.savemat(rig, {"data": np.column_stack([t, 0.5 * t**2, np.sin(t)])})
>>> traj = load_data(rig, time="data[:,0]", columns=["x=data[:,1]", "u=2*data[:, 2]"])
>>> traj.names, traj.meta["data_file"]["time"], traj.meta["data_file"]["columns"]
(('x', 'u'), 'data[:,0]', {'x': 'data[:,1]', 'u': '2*data[:, 2]'})
>>> bool(np.array_equal(traj["x"], 0.5 * t**2))
True
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from ..errors import DataError, FmuNotFoundError, InvalidSettingError, UnknownVariableError
from ._column_expressions import _evaluate, _parse_columns
from ._measurement_files import _listing, _read_mat, _read_table, _values, file_variables, time_column
from .derivatives import DERIVATIVE_METHODS, _method, _savgol_windows, differentiate
from .trajectory import Trajectory

# differentiate and DERIVATIVE_METHODS live in cosim.data.derivatives; they import from here too
__all__ = ["load_data", "differentiate", "check_excitation", "file_variables", "time_column", "DERIVATIVE_METHODS",
           "MIN_SAMPLES", "UNIFORM_RTOL", "derived_velocities"]

#: Fewest samples a record may have: two give a time step, three a central difference.
MIN_SAMPLES = 3
#: Time counts as uniform when every step is within this fraction of the median step.
UNIFORM_RTOL = 1e-3

_SUFFIXES = MappingProxyType({".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".mat": "mat"})


def derived_velocities(record: Trajectory) -> dict[str, str]:
    """The velocities :func:`load_data` derived from a measured position (``derive=``), velocity -> position:
    ``POS_dot`` for each position, or the names a caller gave them (``meta["data_file"]["derivatives"]
    ["velocities"]``, as ``cosim``'s ``--derive VEL=POS`` records them). Empty for a record that derived none.

    A derived velocity is the output of a smoothing differentiator, not a measurement: the diagnosis's search
    leaves it out of its cost (:func:`cosim.diagnose._free_run.measured_states`).

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.data.trajectory import Trajectory
    >>> t = np.arange(5) * 0.1
    >>> traj = Trajectory.from_arrays(t, {"x": t, "x_dot": np.ones(5)},
    ...                               meta={"data_file": {"derivatives": {"of": ["x"]}}})
    >>> derived_velocities(traj)
    {'x_dot': 'x'}
    """
    meta = record.meta if isinstance(record.meta, Mapping) else {}
    info = meta.get("data_file") if isinstance(meta.get("data_file"), Mapping) else {}
    derivatives = info.get("derivatives") if isinstance(info.get("derivatives"), Mapping) else {}
    named = derivatives.get("velocities")
    if isinstance(named, Mapping):
        return {str(v): str(p) for v, p in named.items()}
    return {f"{p}_dot": str(p) for p in derivatives.get("of") or ()}


# ------------------------------------------------------------------------------------------------ excitation
def check_excitation(traj: Trajectory, inputs: str | Sequence[str] | None = None) -> Trajectory:
    """Refuse a record in which an input never changes: identification has nothing to work from.

    An input is constant when its peak-to-peak range is at most ``1e-12`` times its largest magnitude (exactly
    constant, up to rounding).

    Parameters
    ----------
    traj : Trajectory
        The record.
    inputs : str or sequence of str, optional
        The signals to check; default the trajectory's inputs (role ``"input"``).

    Returns
    -------
    Trajectory
        `traj` itself, so that the check chains.

    Raises
    ------
    DataError
        ``input 'force' is constant: nothing to identify from``, with its value.
    UnknownVariableError
        A name that is not a signal of `traj`.

    Examples
    --------
    >>> from cosim.data.trajectory import Trajectory
    >>> traj = Trajectory.from_arrays([0.0, 1.0, 2.0], {"force": [2.0, 2.0, 2.0]}, roles={"force": "input"})
    >>> check_excitation(traj)
    Traceback (most recent call last):
    cosim.errors.DataError: input 'force' is constant: nothing to identify from (it is 2 over the whole record); \
excite the system (steps, a multisine) or drop that input
    """
    names = traj.inputs if inputs is None else ((inputs,) if isinstance(inputs, str) else tuple(inputs))
    for name in names:
        column = traj[name]
        scale = float(np.max(np.abs(column))) if column.size else 0.0
        if column.size and float(np.ptp(column)) <= 1e-12 * scale:
            raise DataError(f"input {name!r} is constant: nothing to identify from (it is {column[0]:g} over the "
                            "whole record); excite the system (steps, a multisine) or drop that input")
    return traj


# ------------------------------------------------------------------------------------------------ time
def _fmt(t: float) -> str:
    return f"{t:.9g}"


def _check_time(path: Path, name: str, t: np.ndarray) -> None:
    finite = np.isfinite(t)
    if not finite.all():
        row = int(np.argmin(finite))
        raise DataError(f"time {name!r} of {path.name} is {t[row]} at row {row}; expected finite times in s; "
                        "drop that row")
    steps = np.diff(t)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        raise DataError(f"time {name!r} of {path.name} is not strictly increasing at row {row} "
                        f"(t={_fmt(t[row])} s after {_fmt(t[row - 1])} s); sort the rows and drop repeated times")


def _uniform_step(path: Path, name: str, t: np.ndarray, resample: bool) -> tuple[float, bool]:
    """The step, and whether the record must be resampled (it is not uniform and resample is on).

    A uniform record's step is its span over its steps (robust to jitter in the stored times); a non-uniform
    record's is the median step, the grid it is resampled onto.
    """
    steps = np.diff(t)
    dt = float(np.median(steps))
    off = np.abs(steps - dt) > UNIFORM_RTOL * dt
    if not off.any():
        return float((t[-1] - t[0]) / (t.size - 1)), False
    if resample:
        return dt, True
    row = int(np.argmax(off)) + 1
    raise DataError(f"time {name!r} of {path.name} is not uniform: the step before row {row} (t={_fmt(t[row])} s) "
                    f"is {_fmt(steps[row - 1])} s against a median step of {_fmt(dt)} s (tolerance "
                    f"{UNIFORM_RTOL:.1%}); pass resample=True (cosim diagnose --resample) to interpolate onto a "
                    "uniform grid, or fix the time")


# ------------------------------------------------------------------------------------------------ entry point
def load_data(
    path: str | os.PathLike,
    *,
    time: str | None = None,
    columns: Mapping[str, str] | Sequence[str] | None = None,
    roles: Mapping[str, str] | None = None,
    units: Mapping[str, str] | None = None,
    derive: str | Sequence[str] = (),
    derive_order: int = 1,
    derive_method: str = "savitzky_golay",
    derive_options: Mapping[str, Any] | None = None,
    derive_window: int | None = None,
    resample: bool = False,
    excitation: bool = True,
) -> Trajectory:
    """Read measured data from a ``.csv``, ``.parquet`` or ``.mat`` file into a checked :class:`Trajectory`.

    Parameters
    ----------
    path : path-like
        The file; its suffix says the format (``.csv``, ``.parquet``/``.pq``, ``.mat``).
    time : str, optional
        Name of the time variable in s; default :func:`time_column`'s: ``"t"`` when the file has one and no
        ``"time"``, else ``"time"``. In a ``.mat`` file, also a column or
        row of a matrix: ``"data[:,0]"``, ``"data[0,:]"`` (0-based).
    columns : sequence of str or mapping, optional
        The signals, in order: a variable of the file (``"qm"``) or a named expression of its variables
        (``"force=gtau*vir"``; mapping form ``{"force": "gtau*vir"}``) built from numbers, variables (vectors
        or scalars, which broadcast), ``+ - * /``, unary minus and parentheses. A ``.mat`` matrix variable is read
        by 0-based column, ``"pos=data[:,2]"``, or row, ``"pos=data[2,:]"``, also inside an expression
        (``"force=35.15*data[:, 3]"``). Default: every variable that is a vector of one value per time.
    roles : mapping, optional
        Signal name -> ``"state"``, ``"input"``, ``"output"`` or ``"reference"``, derived signals included
        (``{"qm": "state", "qm_dot": "state", "force": "input"}``); default ``"output"`` (or the role a cosim
        file stores for a plain column).
    units : mapping, optional
        Signal name -> unit; a derived signal gets its source's unit per s (``"m/s"``, ``"m/s^2"``) unless
        given here.
    derive : str or sequence of str
        Signals to differentiate: each adds ``<name>_dot`` (and ``<name>_ddot`` with ``derive_order=2``) right
        after its source.
    derive_order : {1, 2}
        Velocity only, or velocity and acceleration.
    derive_method : str
        ``"savitzky_golay"`` (default: a cubic over a window chosen from the data, see
        :func:`~cosim.data.derivatives.savgol_window`), ``"butterworth"`` (zero-phase low-pass at a tenth
        of the sampling rate, order 4, then central differences) or ``"finite_difference"``; see
        :func:`differentiate`.
    derive_options : mapping, optional
        The method's options, e.g. ``{"window": 31}`` or ``{"cutoff": 100.0}``.
    derive_window : int, optional
        The Savitzky-Golay window in samples (odd), instead of the one chosen from the data for each signal and
        derivative (the least estimated mean-square error); the same as ``derive_options={"window": N}``.
    resample : bool
        Put a record whose time steps are not uniform (beyond :data:`UNIFORM_RTOL` of the median step) onto the
        uniform grid ``t0 + k * dt`` (dt the median step) by linear interpolation of every column, instead of
        refusing it. Time must still be strictly increasing.
    excitation : bool
        Refuse an input that is constant (:func:`check_excitation`: nothing to identify from); false for a record
        that only drives a simulation.

    Returns
    -------
    Trajectory
        The signals with their roles and units, at times ``t0 + k*dt`` (a uniform record's stored times, whose
        jitter is below :data:`UNIFORM_RTOL` of a step, are replaced by that grid with ``dt`` = span / steps;
        the largest shift is ``meta["data_file"]["time_jitter"]`` in s). ``meta["data_file"]`` records the file,
        its format, the time variable, each column's expression, the scalars used, the derivative method with its
        options (``windows``: the Savitzky-Golay window of each derived signal, ``window_from``: ``"data"`` or
        ``"given"``) and any resampling; ``meta["dt"]`` is the time step. A cosim file's own meta is kept.

    Raises
    ------
    FmuNotFoundError
        No file at `path`.
    InvalidSettingError
        An unknown suffix, a malformed column (brackets other than ``[:,k]`` or ``[k,:]`` included), an unknown
        derivative method or option.
    UnknownVariableError
        A variable (time, column, derived or role name) that is not there; the message lists what there is.
    DataError
        Unreadable file (a MATLAB v7.3 file included), a variable that is not a vector of one value per time, a
        matrix index out of range (naming the variable, its shape and the valid range) or an index on a CSV or
        Parquet column, too few samples (the message gives the minimum), NaN or inf (naming column, time and
        row), time not strictly increasing or not uniform (naming the row), a constant input
        (:func:`check_excitation`).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> import numpy as np, pandas as pd
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "bench.csv"
    >>> t = np.arange(50) * 0.01
    >>> pd.DataFrame({"time": t, "volts": np.sign(np.sin(9 * t)), "pos": t**2}).to_csv(path, index=False)
    >>> traj = load_data(path, columns=["pos", "force=35.15*volts"], derive="pos", derive_order=2,
    ...                  roles={"pos": "state", "pos_dot": "state", "force": "input"}, units={"pos": "m"})
    >>> traj
    Trajectory(50 samples, t=0..0.49 s, dt=0.01 s; pos [m] state, pos_dot [m/s] state, pos_ddot [m/s^2] output, \
force [] input)
    >>> float(traj["pos_ddot"][25].round(6)), traj.meta["data_file"]["columns"]["force"]
    (2.0, '35.15*volts')
    """
    path = Path(path)
    kind = _SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InvalidSettingError(f"cannot tell the format of {path.name!r} from its suffix; use .csv, .parquet, "
                                  ".pq or .mat")
    if not path.is_file():
        what = "is a folder, not a file" if path.is_dir() else "does not exist"
        raise FmuNotFoundError(f"data file {path} {what}; check the path")
    if time is not None and not isinstance(time, str):
        raise InvalidSettingError(f"time must be the name of the time variable (or data[:,0], column 0 of a .mat "
                                  f"matrix), got {time!r}")
    parsed = None if columns is None else _parse_columns(columns)
    derive = (derive,) if isinstance(derive, str) else tuple(dict.fromkeys(derive))
    if derive_window is not None:
        if derive_method != "savitzky_golay":
            raise InvalidSettingError(f"derive_window sets the Savitzky-Golay window; derive_method is "
                                      f"{derive_method!r}: drop derive_window or use savitzky_golay")
        derive_options = {**dict(derive_options or {}), "window": derive_window}
    method, options, min_derive = _method(derive_method, derive_options, derive_order) if derive else (None, {}, 0)

    raw, parsed = _read_mat(path, time, parsed) if kind == "mat" else _read_table(path, kind, time, parsed)
    time_name = raw.time.key  # "t", or "data[:,0]" for a column of a matrix
    t = _values(path, raw.time, raw.variables, None)
    n = t.size
    env: dict[str, float | np.ndarray] = {}
    scalars: dict[str, float] = {}
    for ref in dict.fromkeys(r for c in parsed for r in c.references):
        env[ref.key] = _values(path, ref, raw.variables, n, time_name)
        if np.ndim(env[ref.key]) == 0:
            scalars[ref.key] = float(env[ref.key])
    signals: dict[str, np.ndarray] = {}
    for column in parsed:
        signals[column.name] = np.broadcast_to(np.asarray(_evaluate(column.tree, env), dtype=float), (n,)).copy()

    minimum = max(MIN_SAMPLES, min_derive)
    if n < minimum:
        why = f" ({derive_method} with {options})" if min_derive > MIN_SAMPLES else ""
        raise DataError(f"{path.name} has {n} samples; at least {minimum} are needed{why}; use a longer record")
    _check_time(path, time_name, t)
    for name, values in signals.items():
        finite = np.isfinite(values)
        if not finite.all():
            row = int(np.argmin(finite))
            raise DataError(f"column {name!r} of {path.name} is {values[row]} at t={_fmt(t[row])} s (row {row}); "
                            "expected finite values; drop or fill the bad samples")
    dt, must_resample = _uniform_step(path, time_name, t, resample)
    meta_resampled: dict[str, Any] | None = None
    grid = t[0] + dt * np.arange(n)
    time_shift = float(np.max(np.abs(grid - t)))
    if not must_resample:
        t = grid  # time is t0 + k*dt; the stored times' jitter (below UNIFORM_RTOL of a step) is recorded
    else:
        count = int(math.floor((t[-1] - t[0]) / dt * (1 + 1e-12))) + 1
        grid = t[0] + dt * np.arange(count)
        signals = {name: np.interp(grid, t, values) for name, values in signals.items()}
        meta_resampled = {"from_samples": n, "samples": count, "dt": dt, "method": "linear interpolation"}
        t = grid
        if count < minimum:
            raise DataError(f"{path.name} has {count} samples after resampling; at least {minimum} are needed")

    ordered: dict[str, np.ndarray] = {}
    plain = {c.name: c.text for c in parsed if c.plain}  # signal -> the file's variable it copies
    file_units = {name: raw.units.get(var, "") for name, var in plain.items()}
    unit_of = {**file_units, **dict(units or {})}
    derived_units: dict[str, str] = {}
    windows: dict[str, int] = {}
    for name in derive:
        if name not in signals:
            raise UnknownVariableError(f"derive names {name!r}, not among the columns {_listing(list(signals))}; "
                                       "add it to columns")
    for name, values in signals.items():
        ordered[name] = values
        if method is not None and name in derive:
            suffixes = ("_dot", "_ddot")[:derive_order]
            used = dict(options)
            if derive_method == "savitzky_golay":
                used["window"] = _savgol_windows(values, dt, derive_order, options["window"], options["polyorder"])
                windows.update({name + sfx: w for sfx, w in zip(suffixes, used["window"], strict=True)})
            derivatives = method.function(values, dt, derive_order, **used)
            for suffix, power, values_d in zip(suffixes, ("/s", "/s^2")[:derive_order], derivatives, strict=True):
                new = name + suffix
                if new in signals or new in ordered:
                    raise InvalidSettingError(f"derive would add {new!r}, which is already a column; rename that "
                                              "column")
                ordered[new] = np.asarray(values_d, dtype=float)
                base = unit_of.get(name, "")
                derived_units[new] = f"{base}{power}" if base else ""
    unit_of = {**derived_units, **unit_of}
    for what, mapping in (("roles", roles), ("units", units)):
        unknown = [k for k in (mapping or {}) if k not in ordered]
        if unknown:
            raise UnknownVariableError(f"{what} names {unknown[0]!r}, not among the signals "
                                       f"{_listing(list(ordered))}; check the spelling")
    role_of = {name: raw.roles.get(var, "output") for name, var in plain.items()}
    role_of.update(dict(roles or {}))

    data_meta: dict[str, Any] = {
        "file": str(path), "format": kind, "time": time_name,
        "columns": {c.name: c.text for c in parsed}, "scalars": scalars,
        "derivatives": None if not derive else {
            "of": list(derive), "order": derive_order, "method": derive_method, "options": options,
            **({"windows": windows, "window_from": "data" if options["window"] == "auto" else "given"}
               if derive_method == "savitzky_golay" else {})},
        "resampled": meta_resampled, "time_jitter": None if must_resample else time_shift,
    }
    traj = Trajectory.from_arrays(t, ordered, units={k: unit_of.get(k, "") for k in ordered},
                                  roles={k: role_of.get(k, "output") for k in ordered},
                                  meta={**raw.meta, "data_file": data_meta, "dt": dt})
    return check_excitation(traj) if excitation else traj
