"""A sampled record of named signals: :class:`Trajectory`, with its CSV, Parquet and .mat files.

A trajectory holds the sample times, one column per signal, each signal's unit and role (``"state"``,
``"input"`` or ``"output"``) and a JSON-ready ``meta`` dict (source FMU, dt, parameters, noise...). Inputs are
zero-order held: an input's value at ``time[k]`` is the value applied over ``[time[k], time[k+1])``.

Files
-----
CSV (``.csv``): a plain table, a header ``time,<name>,...`` and one row per sample, floats written so that
they read back exactly (``pandas.read_csv``, MATLAB ``readtable`` and spreadsheets read it as is). Units, roles,
sample time and meta are in the sidecar ``NAME.meta.json``
(``{"format": "cosim-trajectory", "version": 2, "columns": [...], "units": {...}, "roles": {...},
"sample_time": ..., "meta": {...}}``); CSVs of cosim < 0.2, with that header as a first comment line
``# cosim-trajectory v1 {...}``, still read. Parquet (``.parquet``, ``.pq``): columns ``time``, ``<name>``...
as float64, the same JSON (with ``"version": 1``) under the schema metadata key ``cosim-trajectory``.
Plain files from other tools (a header with a time column, or a Parquet table) read too; their roles are
``"output"`` unless given. MATLAB (``.mat``): ``time`` and a variable per signal, the header in a char variable
(:mod:`~cosim.data._trajectory_mat`). Writes are atomic: a temporary file in the same folder, then a rename.

The checks of a trajectory's fields are in :mod:`~cosim.data._trajectory_checks`, the readers and writers of
its files in :mod:`~cosim.data._trajectory_files` (pandas and pyarrow are imported there when a file is used).
"""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError, InvalidSettingError, UnknownVariableError
from ._trajectory_checks import _TIME, ROLES, _as_names, checked_fields
from ._trajectory_files import _file_kind, read_file, write_csv, write_parquet
from ._trajectory_mat import read_mat, write_mat

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["Trajectory", "ROLES"]

_NOISE_CONVENTION = "gaussian, std = level x std of the clean signal, independent per signal"


@dataclass(frozen=True, eq=False, repr=False)
class Trajectory:
    """Sampled record of named signals with units, roles and metadata; arrays are read-only.

    Parameters
    ----------
    time : array_like, shape (n_samples,)
        Sample times in s, finite and strictly increasing (uniform or not).
    values : array_like, shape (n_samples, n_signals)
        One column per signal, finite.
    names : tuple of str
        Unique signal names (``"time"`` is reserved for the time column).
    units : tuple of str, optional
        One unit per signal, ``""`` when unknown (the default).
    roles : tuple of str, optional
        One of ``"state"``, ``"input"``, ``"output"`` per signal (default ``"output"``).
    meta : dict, optional
        JSON-serialisable facts about the record: source FMU, dt, parameters, noise level and seed...
        It is copied through JSON (numpy scalars and arrays, tuples become plain numbers and lists), so it
        reads back from a file exactly as stored; treat it as read-only and use :meth:`with_meta` for a
        changed copy.

    Raises
    ------
    DataError
        Wrong shapes, repeated or empty names, a non-finite value (naming the column and the first bad time),
        time not strictly increasing (naming the first index where it is not), meta not JSON-serialisable.
    InvalidSettingError
        An unknown role.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.data.trajectory import Trajectory
    >>> t = np.arange(5) * 0.5
    >>> traj = Trajectory.from_arrays(t, {"u": np.ones(5), "x": t**2}, units={"x": "rad"},
    ...                               roles={"u": "input", "x": "state"}, meta={"dt": 0.5})
    >>> traj
    Trajectory(5 samples, t=0..2 s, dt=0.5 s; u [] input, x [rad] state)
    >>> traj["x"].tolist(), traj.inputs, traj.states, traj.dt
    ([0.0, 0.25, 1.0, 2.25, 4.0], ('u',), ('x',), 0.5)
    """

    time: np.ndarray
    values: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...] | None = None
    roles: tuple[str, ...] | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        fields = checked_fields(self.time, self.values, self.names, self.units, self.roles, self.meta)
        for name, value in zip(("time", "values", "names", "units", "roles", "meta"), fields, strict=True):
            object.__setattr__(self, name, value)

    # construction ----------------------------------------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        time: Sequence[float] | np.ndarray,
        signals: Mapping[str, Sequence[float] | np.ndarray],
        *,
        units: Mapping[str, str] | None = None,
        roles: Mapping[str, str] | None = None,
        meta: Mapping[str, Any] | None = None,
    ) -> Trajectory:
        """Build from a time array and one 1-D array per signal name.

        Parameters
        ----------
        time : array_like
            Sample times in s.
        signals : Mapping[str, array_like]
            Name -> samples, one per time; the order of the mapping is the column order.
        units, roles : Mapping[str, str], optional
            By name; missing names get ``""`` and ``"output"``.
        meta : Mapping, optional
            JSON-serialisable metadata.

        Raises
        ------
        DataError
            A signal whose length differs from time's, plus everything the constructor checks.
        UnknownVariableError
            `units` or `roles` naming a signal that is not in `signals`.

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 0.5, 1.0], {"y": [1.0, 2.0, 3.0]}, units={"y": "m"})
        >>> len(traj), traj.units, traj.roles
        (3, ('m',), ('output',))
        """
        names = tuple(signals)
        for what, mapping in (("units", units), ("roles", roles)):
            extra = [name for name in (mapping or {}) if name not in signals]
            if extra:
                raise UnknownVariableError(f"{what} names {', '.join(map(repr, extra))}, not among the "
                                           "signals "
                                           f"{', '.join(names) or '(none)'}; check the spelling")
        n = np.shape(time)[0] if np.ndim(time) else 0
        columns = []
        for name, samples in signals.items():
            column = np.asarray(samples)
            if column.ndim != 1 or column.shape[0] != n:
                raise DataError(f"signal {name!r} has shape {column.shape}, expected ({n},) like time; "
                                "pass one value per time")
            columns.append(column)
        values = np.column_stack(columns) if columns else np.empty((n, 0))
        return cls(time, values, names,
                   units=tuple((units or {}).get(name, "") for name in names),
                   roles=tuple((roles or {}).get(name, "output") for name in names),
                   meta=dict(meta or {}))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Trajectory:
        """Inverse of :meth:`to_dict`.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}, meta={"a": 1})
        >>> Trajectory.from_dict(traj.to_dict()) == traj
        True
        """
        try:
            return cls.from_arrays(data["time"], data["signals"], units=data.get("units"),
                                   roles=data.get("roles"), meta=data.get("meta"))
        except KeyError as exc:
            raise DataError(f"trajectory dict lacks key {exc}; expected time, signals, units, roles, meta"
                            ) from None

    # access ----------------------------------------------------------------------------------------------
    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            available = ", ".join(self.names) or "(none)"
            raise UnknownVariableError(f"no signal named {name!r}; available: {available}") from None

    def __getitem__(self, key: str | Sequence[str]) -> np.ndarray:
        """``traj["x"]``: the 1-D read-only column; ``traj[["x", "y"]]``: an (n_samples, 2) array."""
        if isinstance(key, str):
            return self.values[:, self._index(key)]
        if isinstance(key, (list, tuple)) and all(isinstance(k, str) for k in key):
            return self.values[:, [self._index(k) for k in key]]
        raise TypeError(f"index a Trajectory by a signal name or a list of names, not {type(key).__name__}")

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __len__(self) -> int:
        return self.time.shape[0]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Trajectory):
            return NotImplemented
        return (self.names == other.names and self.units == other.units and self.roles == other.roles
                and self.meta == other.meta and np.array_equal(self.time, other.time)
                and np.array_equal(self.values, other.values))

    __hash__ = None  # type: ignore[assignment]  # equal by value, arrays are not hashable

    def __repr__(self) -> str:
        shown = [f"{n} [{u}] {r}" for n, u, r in zip(self.names, self.units, self.roles, strict=True)]
        if len(shown) > 8:
            shown = [*shown[:8], f"... {len(shown) - 8} more"]
        span = f"t={self.time[0]:g}..{self.time[-1]:g} s"
        step = f", dt={self.dt:g} s" if len(self) > 1 and self.is_uniform() else ""
        return f"Trajectory({len(self)} samples, {span}{step}; {', '.join(shown) or 'no signals'})"

    @property
    def dt(self) -> float:
        """Median time step in s (the step of a uniform record)."""
        if len(self) < 2:
            raise DataError("dt needs at least two samples, this trajectory has one; use a longer record")
        return float(np.median(np.diff(self.time)))

    def is_uniform(self, *, rtol: float = 1e-6) -> bool:
        """Whether every time step is within ``rtol`` (relative) of :attr:`dt`.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> Trajectory.from_arrays([0.0, 0.1, 0.2, 0.4], {"y": [0.0, 1.0, 2.0, 3.0]}).is_uniform()
        False
        """
        if len(self) < 2:
            return True
        return bool(np.all(np.abs(np.diff(self.time) - self.dt) <= rtol * self.dt))

    def _by_role(self, role: str) -> tuple[str, ...]:
        return tuple(n for n, r in zip(self.names, self.roles, strict=True) if r == role)

    @property
    def states(self) -> tuple[str, ...]:
        """Names of the signals whose role is ``"state"``, in column order."""
        return self._by_role("state")

    @property
    def inputs(self) -> tuple[str, ...]:
        """Names of the signals whose role is ``"input"``, in column order."""
        return self._by_role("input")

    @property
    def outputs(self) -> tuple[str, ...]:
        """Names of the signals whose role is ``"output"``, in column order."""
        return self._by_role("output")

    # copies ----------------------------------------------------------------------------------------------
    def with_roles(
        self,
        *,
        states: str | Sequence[str] = (),
        inputs: str | Sequence[str] = (),
        outputs: str | Sequence[str] = (),
    ) -> Trajectory:
        """Copy in which the named signals get the given roles; the others keep theirs.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 1.0], {"u": [0.0, 1.0], "x": [1.0, 2.0]})
        >>> traj.with_roles(inputs=["u"], states=["x"]).roles
        ('input', 'state')
        """
        roles = dict(zip(self.names, self.roles, strict=True))
        seen: dict[str, str] = {}
        for role, names in (("state", states), ("input", inputs), ("output", outputs)):
            for name in _as_names(names):
                self._index(name)
                if name in seen and seen[name] != role:
                    raise InvalidSettingError(f"{name!r} is given two roles, {seen[name]} and {role}; "
                                              "give it one")
                seen[name] = roles[name] = role
        return replace(self, roles=tuple(roles[name] for name in self.names))

    def select(self, names: str | Sequence[str]) -> Trajectory:
        """Copy with only the named signals, in the order given.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 1.0], {"a": [0.0, 1.0], "b": [1.0, 2.0]})
        >>> traj.select(["b"]).names
        ('b',)
        """
        names = _as_names(names)
        index = [self._index(name) for name in names]
        return replace(self, values=self.values[:, index], names=names,
                       units=tuple(self.units[i] for i in index), roles=tuple(self.roles[i] for i in index))

    def slice(self, t_start: float | None = None, t_end: float | None = None) -> Trajectory:
        """Copy with the samples whose time lies in ``[t_start, t_end]`` (both ends included; None: open).

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 0.1, 0.2, 0.3], {"y": [0.0, 1.0, 2.0, 3.0]})
        >>> traj.slice(0.1, 0.2)["y"].tolist()
        [1.0, 2.0]
        """
        keep = np.ones(len(self), dtype=bool)
        if t_start is not None:
            keep &= self.time >= t_start
        if t_end is not None:
            keep &= self.time <= t_end
        if not keep.any():
            raise DataError(f"no sample lies in [{t_start}, {t_end}] s; the record spans "
                            f"{self.time[0]:g}..{self.time[-1]:g} s")
        return replace(self, time=self.time[keep], values=self.values[keep])

    def with_meta(self, updates: Mapping[str, Any]) -> Trajectory:
        """Copy whose ``meta`` is updated with `updates` (JSON-serialisable).

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> Trajectory.from_arrays([0.0], {"y": [1.0]}).with_meta({"source": "bench"}).meta
        {'source': 'bench'}
        """
        return replace(self, meta={**self.meta, **dict(updates)})

    def with_noise(self, level: float, *, seed: int, names: str | Sequence[str] | None = None) -> Trajectory:
        """Copy with Gaussian measurement noise, in the reference study's convention.

        Each noisy signal gets independent Gaussian noise of standard deviation ``level`` times the standard
        deviation (over the whole record, ``ddof=0``) of that clean signal, drawn from
        ``numpy.random.default_rng(seed)``: ``level=0.1`` is "10 % noise". A constant signal has standard
        deviation 0 and so gets no noise. By default the states and outputs are noisy and the inputs are not
        (an input is the known excitation); name signals to choose. The draw is reproducible: the same data,
        level, seed and names give the same noise. ``meta["noise"]`` records the level, seed, the signals and
        the absolute standard deviation added to each.

        Parameters
        ----------
        level : float
            Noise standard deviation as a fraction of each clean signal's standard deviation, >= 0.
        seed : int
            Seed of the random generator, >= 0.
        names : sequence of str, optional
            Signals to make noisy (inputs included if named); default all states and outputs.

        Raises
        ------
        InvalidSettingError
            Negative or non-finite level, bad seed, or a trajectory that already has noise (the convention
            is relative to the clean signal).
        UnknownVariableError
            A name that is not a signal.

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.data.trajectory import Trajectory
        >>> t = np.linspace(0.0, 1.0, 10001)
        >>> clean = Trajectory.from_arrays(t, {"u": np.sign(np.sin(9 * t)), "x": np.sin(2 * np.pi * t)},
        ...                                roles={"u": "input", "x": "state"})
        >>> noisy = clean.with_noise(0.1, seed=1)
        >>> np.array_equal(noisy["u"], clean["u"]), round(float(np.std(noisy["x"] - clean["x"])), 2)
        (True, 0.07)
        >>> noisy.meta["noise"]["level"], noisy.meta["noise"]["signals"]
        (0.1, ['x'])
        """
        if isinstance(level, bool) or not isinstance(level, numbers.Real) or not 0.0 <= level < math.inf:
            raise InvalidSettingError(f"noise level must be a finite number >= 0, got {level!r}; "
                                      "e.g. 0.1 for 10 % of each signal's standard deviation")
        if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
            raise InvalidSettingError(f"seed must be an integer >= 0, got {seed!r}; e.g. seed=0")
        if "noise" in self.meta:
            raise InvalidSettingError("this trajectory already has noise (meta['noise']); add noise once, "
                                      "to the clean trajectory")
        if names is None:
            index = [i for i, role in enumerate(self.roles) if role != "input"]
        else:
            index = sorted({self._index(name) for name in _as_names(names)})
        clean = self.values[:, index]
        sigma = float(level) * clean.std(axis=0)
        values = self.values.copy()
        values[:, index] = clean + np.random.default_rng(int(seed)).standard_normal(clean.shape) * sigma
        noise = {"level": float(level), "seed": int(seed), "signals": [self.names[i] for i in index],
                 "std": {self.names[i]: float(s) for i, s in zip(index, sigma, strict=True)},
                 "convention": _NOISE_CONVENTION}
        return replace(self, values=values, meta={**self.meta, "noise": noise})

    # conversions -----------------------------------------------------------------------------------------
    def to_pandas(self) -> pd.DataFrame:
        """DataFrame indexed by time (``"time"``), one column per signal; units, roles, meta in ``df.attrs``.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> df = Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}, units={"y": "m"}).to_pandas()
        >>> df.index.name, list(df.columns), df.attrs["units"]
        ('time', ['y'], {'y': 'm'})
        """
        import pandas as pd

        frame = pd.DataFrame(self.values.copy(), index=pd.Index(self.time.copy(), name=_TIME),
                             columns=list(self.names))
        frame.attrs = {"units": dict(zip(self.names, self.units, strict=True)),
                       "roles": dict(zip(self.names, self.roles, strict=True)),
                       "meta": json.loads(json.dumps(self.meta))}
        return frame

    @classmethod
    def from_pandas(
        cls,
        frame: pd.DataFrame,
        *,
        time: str | None = None,
        units: Mapping[str, str] | None = None,
        roles: Mapping[str, str] | None = None,
        meta: Mapping[str, Any] | None = None,
    ) -> Trajectory:
        """A trajectory from a DataFrame: time from column `time`, else a ``"time"`` column, else the index.

        A datetime or timedelta index counts seconds from its first row. Units, roles and meta default to
        ``frame.attrs`` (as :meth:`to_pandas` leaves them); every other column must be numeric.

        Examples
        --------
        >>> import pandas as pd
        >>> from cosim.data.trajectory import Trajectory
        >>> df = pd.DataFrame({"t": [0.0, 0.5], "u": [1.0, 0.0], "y": [0.0, 0.2]})
        >>> Trajectory.from_pandas(df, time="t", roles={"u": "input"}).roles
        ('input', 'output')
        >>> Trajectory.from_pandas(Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]},
        ...                                              units={"y": "m"}).to_pandas()).units
        ('m',)
        """
        from ._trajectory_frames import arrays_from_frame

        t, data, units, roles, meta = arrays_from_frame(frame, time=time, units=units, roles=roles, meta=meta)
        return cls.from_arrays(t, data, units=units, roles=roles, meta=meta)

    def plot(self, names: str | Sequence[str] | None = None, *, path: str | os.PathLike | None = None,
             title: str | None = None) -> Any:
        """A matplotlib Figure of `names` (default: every signal) against time, one panel each, with units.

        Inputs are drawn first, as steps (zero-order hold). With `path`, the figure is also written as PNG.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> fig = Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}, units={"y": "m"}).plot()
        >>> fig.axes[0].get_ylabel()
        'y\\n[m]'
        """
        from ._trajectory_figure import trajectory_figure

        fig = trajectory_figure(self if names is None else self.select(names), title=title)
        if path is not None:
            from ..figures import save_figure

            save_figure(fig, path, close=False)
        return fig

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict: ``time``, ``signals`` (name -> list), ``units``, ``roles``, ``meta``.

        Examples
        --------
        >>> from cosim.data.trajectory import Trajectory
        >>> Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}).to_dict()["signals"]
        {'y': [1.0, 2.0]}
        """
        return {"time": self.time.tolist(),
                "signals": {name: self.values[:, i].tolist() for i, name in enumerate(self.names)},
                "units": dict(zip(self.names, self.units, strict=True)),
                "roles": dict(zip(self.names, self.roles, strict=True)),
                "meta": json.loads(json.dumps(self.meta))}

    # files -----------------------------------------------------------------------------------------------
    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write a CSV file atomically and return its path (format: see the module docstring).

        Examples
        --------
        >>> import tempfile, pathlib
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}, units={"y": "m"})
        >>> path = traj.to_csv(pathlib.Path(tempfile.mkdtemp()) / "run.csv")
        >>> print(path.read_text())
        time,y
        0.0,1.0
        1.0,2.0
        <BLANKLINE>
        >>> import json; json.loads(path.with_name("run.meta.json").read_text())["units"]
        {'y': 'm'}
        """
        return write_csv(self, path)

    def to_parquet(self, path: str | os.PathLike) -> Path:
        """Write a Parquet file atomically and return its path (format: see the module docstring).

        Examples
        --------
        >>> import tempfile, pathlib
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}, roles={"y": "state"})
        >>> path = traj.to_parquet(pathlib.Path(tempfile.mkdtemp()) / "run.parquet")
        >>> Trajectory.read(path) == traj
        True
        """
        return write_parquet(self, path)

    def write(self, path: str | os.PathLike) -> Path:
        """Write to `path` atomically, as CSV (``.csv``), Parquet (``.parquet``, ``.pq``) or MATLAB (``.mat``, one
        variable per signal and ``time``: :mod:`~cosim.data._trajectory_mat`); return the path.

        Examples
        --------
        >>> import tempfile, pathlib
        >>> from cosim.data.trajectory import Trajectory
        >>> traj = Trajectory.from_arrays([0.0, 1.0], {"y": [1.0, 2.0]}, meta={"dt": 1.0})
        >>> Trajectory.read(traj.write(pathlib.Path(tempfile.mkdtemp()) / "run.csv")).meta
        {'dt': 1.0}
        """
        kind = _file_kind(Path(path))
        writer = {"csv": write_csv, "parquet": write_parquet, "mat": write_mat}[kind]
        return writer(self, path)

    @classmethod
    def read(
        cls,
        path: str | os.PathLike,
        *,
        columns: Sequence[str] | None = None,
        time: str = _TIME,
        roles: Mapping[str, str] | None = None,
    ) -> Trajectory:
        """Read a CSV (``.csv``), Parquet (``.parquet``, ``.pq``) or MATLAB (``.mat``) file, cosim's or another tool's.

        Names, units, roles and meta come back as written. A plain file needs a header row with a time
        column; its signals get unit ``""`` and role ``"output"`` unless `roles` says otherwise.

        Parameters
        ----------
        path : path-like
            The file.
        columns : sequence of str, optional
            Signals to read, in this order (default: all).
        time : str, optional
            Name of the time column (seconds).
        roles : Mapping[str, str], optional
            Name -> role, overriding the file's.

        Raises
        ------
        FmuNotFoundError
            No file at `path`.
        DataError
            No time column, missing requested columns (both listing the columns present), a non-numeric
            column, NaN or non-increasing time, an unreadable file.
        InvalidSettingError
            A suffix other than .csv, .parquet, .pq, .mat.

        Examples
        --------
        >>> import tempfile, pathlib
        >>> from cosim.data.trajectory import Trajectory
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "bench.csv"
        >>> _ = path.write_text("t,torque,angle\\n0.0,1.0,0.0\\n0.001,1.0,0.5\\n")
        >>> traj = Trajectory.read(path, time="t", roles={"torque": "input"})
        >>> traj.names, traj.roles
        (('torque', 'angle'), ('input', 'output'))
        """
        path = Path(path)
        t, data, header = (read_mat if _file_kind(path) == "mat" else read_file)(path, time, columns)
        roles = dict(roles or {})
        extra = [name for name in roles if name not in data]
        if extra:
            raise UnknownVariableError(f"roles names {', '.join(extra)}, not among the signals read from "
                                       f"{path.name}: {', '.join(data) or '(none)'}; check the spelling")
        file_units, file_roles = header.get("units", {}), header.get("roles", {})
        return cls.from_arrays(t, data, units={name: str(file_units.get(name, "")) for name in data},
                               roles={name: roles.get(name, file_roles.get(name, "output")) for name in data},
                               meta=header.get("meta", {}))
