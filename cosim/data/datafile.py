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
    time, or a scalar (a gain, say) that an expression broadcasts over time. MATLAB v7.3 files are HDF5 files
    that cosim does not read: re-save them with ``save(file, '-v7')`` (or export a CSV).

Columns
-------
A column is a variable of the file (``"qm"``) or a named expression of the file's variables (``"force=gtau*vir"``,
``"force=35.15*vir + pulses_N"``): numbers and variables combined with ``+ - * /``, unary minus and
parentheses, parsed with :mod:`ast` (nothing is passed to ``eval``). Scalars broadcast over time. Give them as a
sequence of such strings or as a mapping ``{name: expression}``.

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
by one of :data:`DERIVATIVE_METHODS` (see :func:`differentiate`). Inputs are zero-order held between samples
everywhere in cosim; a resampled input is linearly interpolated at the new sample times, then held.

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
"""

from __future__ import annotations

import ast
import csv
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from ..errors import DataError, FmuNotFoundError, InvalidSettingError, UnknownVariableError
from .trajectory import Trajectory

__all__ = ["load_data", "differentiate", "check_excitation", "DERIVATIVE_METHODS", "MIN_SAMPLES", "UNIFORM_RTOL"]

#: Fewest samples a record may have: two give a time step, three a central difference.
MIN_SAMPLES = 3
#: Time counts as uniform when every step is within this fraction of the median step.
UNIFORM_RTOL = 1e-3

_SUFFIXES = MappingProxyType({".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".mat": "mat"})
_TIME_NAMES = ("t", "time")
_OPS: dict[type, Callable[[Any, Any], Any]] = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
                                               ast.Div: np.divide}
_EXPRESSION_HELP = ("write numbers and the file's variables joined by + - * /, e.g. force=gtau*vir or "
                    "force=35.15*vir+pulses_N")


# ------------------------------------------------------------------------------------------------ derivatives
@dataclass(frozen=True)
class _Method:
    function: Callable[..., list[np.ndarray]]
    defaults: Mapping[str, Any]
    min_samples: Callable[..., int]
    summary: str


def _check_int(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise InvalidSettingError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _savgol(x: np.ndarray, dt: float, order: int, *, window: int, polyorder: int) -> list[np.ndarray]:
    from scipy.signal import savgol_filter

    return [savgol_filter(x, window, polyorder, deriv=k, delta=dt, mode="interp") for k in range(1, order + 1)]


def _savgol_min(order: int, *, window: int, polyorder: int) -> int:
    window = _check_int("savitzky_golay window", window, 3)
    polyorder = _check_int("savitzky_golay polyorder", polyorder, 1)
    if window % 2 == 0:
        raise InvalidSettingError(f"savitzky_golay window must be odd (samples centred on the point), got {window}")
    if not order <= polyorder < window:
        raise InvalidSettingError(f"savitzky_golay needs derive_order ({order}) <= polyorder ({polyorder}) < "
                                  f"window ({window}); raise the polyorder or the window")
    return window


def _butterworth(x: np.ndarray, dt: float, order: int, *, cutoff: float | None, filter_order: int
                 ) -> list[np.ndarray]:
    from scipy.signal import butter, sosfiltfilt

    cutoff = 0.1 / dt if cutoff is None else float(cutoff)
    if not 0.0 < cutoff < 0.5 / dt:
        raise InvalidSettingError(f"butterworth cutoff must lie between 0 and the Nyquist frequency "
                                  f"{0.5 / dt:g} Hz, got {cutoff:g} Hz")
    sos = butter(filter_order, cutoff, fs=1.0 / dt, output="sos")
    smooth = sosfiltfilt(sos, x)
    out = [np.gradient(smooth, dt)]
    if order == 2:
        out.append(np.gradient(out[0], dt))
    return out


def _butterworth_min(order: int, *, cutoff: float | None, filter_order: int) -> int:
    filter_order = _check_int("butterworth filter_order", filter_order, 1)
    if cutoff is not None and (isinstance(cutoff, bool) or not isinstance(cutoff, (int, float, np.floating))
                               or not math.isfinite(cutoff)):
        raise InvalidSettingError(f"butterworth cutoff must be a frequency in Hz, got {cutoff!r}")
    sections = (filter_order + 1) // 2
    return 3 * (2 * sections + 1) + 1  # scipy's sosfiltfilt pads 3 * (2 * sections + 1) samples at each end


def _finite_difference(x: np.ndarray, dt: float, order: int) -> list[np.ndarray]:
    out = [np.gradient(x, dt, edge_order=2)]
    if order == 2:
        out.append(np.gradient(out[0], dt, edge_order=2))
    return out


#: Differentiators by name: what each does, its options and their defaults.
DERIVATIVE_METHODS: Mapping[str, _Method] = MappingProxyType({
    "savitzky_golay": _Method(
        _savgol, MappingProxyType({"window": 21, "polyorder": 3}), _savgol_min,
        "least-squares polynomial of degree `polyorder` (3) over a centred window of `window` samples (21; "
        "the first and last windows at the ends), differentiated at each sample (scipy.signal.savgol_filter)"),
    "butterworth": _Method(
        _butterworth, MappingProxyType({"cutoff": None, "filter_order": 4}), _butterworth_min,
        "zero-phase Butterworth low-pass of order `filter_order` (4) at `cutoff` Hz (default a tenth of the "
        "sampling rate), run forward and backward (scipy.signal.sosfiltfilt), then central differences "
        "(numpy.gradient, applied twice for the second derivative): the EMPS reference's band-pass filtering"),
    "finite_difference": _Method(
        _finite_difference, MappingProxyType({}), lambda order: 3,
        "central differences without smoothing (numpy.gradient, second-order one-sided at the ends): exact for "
        "clean data, amplifies noise by about 1/dt"),
})


def _method(method: str, options: Mapping[str, Any] | None, order: int) -> tuple[_Method, dict[str, Any], int]:
    if method not in DERIVATIVE_METHODS:
        raise InvalidSettingError(f"unknown derive_method {method!r}; expected one of "
                                  f"{', '.join(DERIVATIVE_METHODS)}")
    if isinstance(order, bool) or order not in (1, 2):
        raise InvalidSettingError(f"derive_order must be 1 (velocity) or 2 (velocity and acceleration), "
                                  f"got {order!r}")
    entry = DERIVATIVE_METHODS[method]
    options = dict(options or {})
    unknown = [k for k in options if k not in entry.defaults]
    if unknown:
        allowed = ", ".join(entry.defaults) or "none"
        raise InvalidSettingError(f"derive_method {method!r} has no option {unknown[0]!r}; its options: {allowed}")
    options = {**entry.defaults, **options}
    return entry, options, entry.min_samples(order, **options)


def differentiate(x: Sequence[float] | np.ndarray, dt: float, *, order: int = 1, method: str = "savitzky_golay",
                  options: Mapping[str, Any] | None = None) -> tuple[np.ndarray, ...]:
    """Time derivatives of a uniformly sampled signal: ``(dx/dt,)`` or ``(dx/dt, d2x/dt2)``.

    Methods (:data:`DERIVATIVE_METHODS`, options in brackets with their defaults):

    * ``"savitzky_golay"`` (``window=21`` samples, ``polyorder=3``): a cubic fitted by least squares over the
      21 samples centred on each sample (the first and last 21 at the ends), differentiated there
      (``scipy.signal.savgol_filter``). Its -3 dB bandwidth is about ``(polyorder + 1) / (3.2 * window - 4.6)``
      times the Nyquist frequency: 73 Hz at 1 kHz with the defaults.
    * ``"butterworth"`` (``cutoff=fs/10`` Hz, ``filter_order=4``): zero-phase Butterworth low-pass (forward and
      backward, ``scipy.signal.sosfiltfilt``), then central differences (``numpy.gradient``, applied twice for
      the second derivative). This is the band-pass filtering of the robotics identification practice (the
      EMPS benchmark's reference method), with the rule of thumb cutoff >= 5 x the closed-loop bandwidth.
    * ``"finite_difference"``: central differences, no smoothing; for clean data.

    Parameters
    ----------
    x : array_like, shape (n,)
        Samples, finite, uniformly spaced in time.
    dt : float
        Sampling step in s.
    order : {1, 2}
        Highest derivative returned.
    method : str
        One of :data:`DERIVATIVE_METHODS`.
    options : mapping, optional
        The method's options (see above); others are refused.

    Returns
    -------
    tuple of ndarray
        The first derivative, and the second with ``order=2``.

    Raises
    ------
    InvalidSettingError
        Unknown method or option, bad option value, order not 1 or 2, dt not positive.
    DataError
        `x` not a finite 1-D array, or shorter than the method needs (the message says the minimum).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(101) * 0.01
    >>> v, a = differentiate(t**3, 0.01, order=2, method="savitzky_golay")
    >>> bool(np.allclose(v, 3 * t**2)), bool(np.allclose(a, 6 * t))
    (True, True)
    >>> differentiate(np.sin(t), 0.01, method="butterworth", options={"cutoff": 5.0})[0][50].round(3)
    np.float64(0.878)
    """
    entry, options, minimum = _method(method, options, order)
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not (math.isfinite(dt) and dt > 0):
        raise InvalidSettingError(f"dt must be a positive time step in s, got {dt!r}")
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise DataError(f"differentiate takes one signal, a 1-D array; got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        row = int(np.argmin(np.isfinite(x)))
        raise DataError(f"the signal is {x[row]} at sample {row}; differentiate finite samples only")
    if x.size < minimum:
        raise DataError(f"the signal has {x.size} samples; {method} needs at least {minimum} "
                        f"(options {options}); use a longer record or a smaller window")
    return tuple(np.asarray(d, dtype=float) for d in entry.function(x, float(dt), order, **options))


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


# ------------------------------------------------------------------------------------------------ columns
@dataclass(frozen=True)
class _Column:
    name: str
    text: str
    tree: ast.Expression

    @property
    def variables(self) -> tuple[str, ...]:
        seen: dict[str, None] = {}
        for node in ast.walk(self.tree):
            if isinstance(node, ast.Name):
                seen.setdefault(node.id, None)
        return tuple(seen)

    @property
    def plain(self) -> bool:
        """The column is a variable of the file, not an expression."""
        return isinstance(self.tree.body, ast.Name)

    def describe(self) -> str:
        return self.name if self.plain and self.text == self.name else f"{self.name}={self.text}"


def _check_node(node: ast.AST, spec: str) -> None:
    if isinstance(node, ast.Expression):
        _check_node(node.body, spec)
    elif isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        _check_node(node.left, spec)
        _check_node(node.right, spec)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check_node(node.operand, spec)
    elif isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        pass
    elif isinstance(node, ast.Name):
        pass
    else:
        raise InvalidSettingError(f"column {spec!r}: {ast.unparse(node)!r} is not allowed; {_EXPRESSION_HELP}")


def _parse_column(name: str, text: str, spec: str) -> _Column:
    name, text = str(name).strip(), str(text).strip()
    if not name.isidentifier() or name == "time":
        raise InvalidSettingError(f"column {spec!r}: {name!r} is not a usable name; use letters, digits and _ "
                                  "(not 'time'), e.g. force=gtau*vir")
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError:
        raise InvalidSettingError(f"column {spec!r}: {text!r} is not an expression; {_EXPRESSION_HELP}") from None
    _check_node(tree, spec)
    return _Column(name, text, tree)


def _plain_column(name: str) -> _Column:
    """A column that is a variable of the file, whatever its name (a CSV header may say "motor speed")."""
    name = str(name).strip()
    if not name or name == "time":
        raise InvalidSettingError(f"column {name!r} is not a usable name; 'time' and '' are reserved, rename it "
                                  "with new_name=variable")
    return _Column(name, name, ast.Expression(body=ast.Name(id=name, ctx=ast.Load())))


def _parse_columns(columns: Mapping[str, str] | Sequence[str] | str) -> list[_Column]:
    if isinstance(columns, Mapping):
        parsed = [_plain_column(name) if str(text).strip() == str(name).strip() else
                  _parse_column(name, text, f"{name}={text}") for name, text in columns.items()]
    else:
        items = [columns] if isinstance(columns, str) else list(columns)
        parsed = []
        for item in items:
            if not isinstance(item, str):
                raise InvalidSettingError(f"columns must be names or 'name=expression' strings, got {item!r}")
            name, sep, text = item.partition("=")
            parsed.append(_parse_column(name, text, item) if sep else _plain_column(item))
    if not parsed:
        raise InvalidSettingError("columns is empty; name at least one column, e.g. columns=['qm', 'force=gtau*vir']")
    names = [c.name for c in parsed]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InvalidSettingError(f"column name {repeated[0]!r} is given twice; give each column one name")
    return parsed


def _evaluate(node: ast.AST, env: Mapping[str, float | np.ndarray]) -> float | np.ndarray:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, env)
    if isinstance(node, ast.BinOp):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return _OPS[type(node.op)](_evaluate(node.left, env), _evaluate(node.right, env))
    if isinstance(node, ast.UnaryOp):
        value = _evaluate(node.operand, env)
        return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, ast.Constant):
        return float(node.value)
    return env[node.id]  # type: ignore[attr-defined]  # names only, checked by _check_node


# ------------------------------------------------------------------------------------------------ reading
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
    resample: bool = False,
) -> Trajectory:
    """Read measured data from a ``.csv``, ``.parquet`` or ``.mat`` file into a checked :class:`Trajectory`.

    Parameters
    ----------
    path : path-like
        The file; its suffix says the format (``.csv``, ``.parquet``/``.pq``, ``.mat``).
    time : str, optional
        Name of the time variable in s; default ``"t"``, else ``"time"``.
    columns : sequence of str or mapping, optional
        The signals, in order: a variable of the file (``"qm"``) or a named expression of its variables
        (``"force=gtau*vir"``; mapping form ``{"force": "gtau*vir"}``) built from numbers, variables (vectors
        or scalars, which broadcast), ``+ - * /``, unary minus and parentheses. Default: every variable that
        is a vector of one value per time.
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
        ``"savitzky_golay"`` (default: cubic over 21 samples), ``"butterworth"`` (zero-phase low-pass at a tenth
        of the sampling rate, order 4, then central differences) or ``"finite_difference"``; see
        :func:`differentiate`.
    derive_options : mapping, optional
        The method's options, e.g. ``{"window": 31}`` or ``{"cutoff": 100.0}``.
    resample : bool
        Put a record whose time steps are not uniform (beyond :data:`UNIFORM_RTOL` of the median step) onto the
        uniform grid ``t0 + k * dt`` (dt the median step) by linear interpolation of every column, instead of
        refusing it. Time must still be strictly increasing.

    Returns
    -------
    Trajectory
        The signals with their roles and units, at times ``t0 + k*dt`` (a uniform record's stored times, whose
        jitter is below :data:`UNIFORM_RTOL` of a step, are replaced by that grid with ``dt`` = span / steps;
        the largest shift is ``meta["data_file"]["time_jitter"]`` in s). ``meta["data_file"]`` records the file,
        its format, the time variable, each column's expression, the scalars used, the derivative method with its
        options and any resampling; ``meta["dt"]`` is the time step. A cosim file's own meta is kept.

    Raises
    ------
    FmuNotFoundError
        No file at `path`.
    InvalidSettingError
        An unknown suffix, a malformed column, an unknown derivative method or option.
    UnknownVariableError
        A variable (time, column, derived or role name) that is not there; the message lists what there is.
    DataError
        Unreadable file (a MATLAB v7.3 file included), a variable that is not a vector of one value per time, too
        few samples (the message gives the minimum), NaN or inf (naming column, time and row), time not strictly
        increasing or not uniform (naming the row), a constant input (:func:`check_excitation`).

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
        raise InvalidSettingError(f"time must be the name of the time variable, got {time!r}")
    parsed = None if columns is None else _parse_columns(columns)
    derive = (derive,) if isinstance(derive, str) else tuple(dict.fromkeys(derive))
    method, options, min_derive = _method(derive_method, derive_options, derive_order) if derive else (None, {}, 0)

    raw, parsed = _read_mat(path, time, parsed) if kind == "mat" else _read_table(path, kind, time, parsed)
    t = _vector(path, raw.time, raw.variables[raw.time], None)
    n = t.size
    env: dict[str, float | np.ndarray] = {}
    scalars: dict[str, float] = {}
    for var in dict.fromkeys(v for c in parsed for v in c.variables):
        env[var] = _vector(path, var, raw.variables[var], n, raw.time)
        if np.ndim(env[var]) == 0:
            scalars[var] = float(env[var])
    signals: dict[str, np.ndarray] = {}
    for column in parsed:
        signals[column.name] = np.broadcast_to(np.asarray(_evaluate(column.tree, env), dtype=float), (n,)).copy()

    minimum = max(MIN_SAMPLES, min_derive)
    if n < minimum:
        why = f" ({derive_method} with {options})" if min_derive > MIN_SAMPLES else ""
        raise DataError(f"{path.name} has {n} samples; at least {minimum} are needed{why}; use a longer record")
    _check_time(path, raw.time, t)
    for name, values in signals.items():
        finite = np.isfinite(values)
        if not finite.all():
            row = int(np.argmin(finite))
            raise DataError(f"column {name!r} of {path.name} is {values[row]} at t={_fmt(t[row])} s (row {row}); "
                            "expected finite values; drop or fill the bad samples")
    dt, must_resample = _uniform_step(path, raw.time, t, resample)
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
    for name in derive:
        if name not in signals:
            raise UnknownVariableError(f"derive names {name!r}, not among the columns {_listing(list(signals))}; "
                                       "add it to columns")
    for name, values in signals.items():
        ordered[name] = values
        if method is not None and name in derive:
            suffixes = ("_dot", "_ddot")[:derive_order]
            derivatives = method.function(values, dt, derive_order, **options)
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
        "file": str(path), "format": kind, "time": raw.time,
        "columns": {c.name: c.text for c in parsed}, "scalars": scalars,
        "derivatives": None if not derive else {"of": list(derive), "order": derive_order,
                                                "method": derive_method, "options": options},
        "resampled": meta_resampled, "time_jitter": None if must_resample else time_shift,
    }
    traj = Trajectory.from_arrays(t, ordered, units={k: unit_of.get(k, "") for k in ordered},
                                  roles={k: role_of.get(k, "output") for k in ordered},
                                  meta={**raw.meta, "data_file": data_meta, "dt": dt})
    return check_excitation(traj)
