"""What a sweep gives back: :class:`SweepResult` (per case, its result or its :class:`SweepError`), as tables and files.

:func:`~cosim.study.sweep.run_sweep` returns a :class:`SweepResult`: the cases, in their order, each with the
dict its run returned or the :class:`SweepError` that says why it failed. It turns into flat records or a
pandas table, and into versioned JSON (format ``cosim-sweep``, :data:`SWEEP_VERSION`) to save and load.
:class:`CaseFailedError` is what :meth:`SweepResult.raise_if_failed` raises.
"""

from __future__ import annotations

import json
import os
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import CosimError, DataError, FmuNotFoundError
from ..files import check_file_format, json_default, write_text_atomic

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["SweepResult", "SweepError", "CaseFailedError", "SWEEP_FORMAT", "SWEEP_VERSION"]

SWEEP_FORMAT = "cosim-sweep"
SWEEP_VERSION = 1
_IN_PROCESS = "in-process"


class CaseFailedError(CosimError, RuntimeError):
    """A sweep had failed cases and the caller asked for all to succeed (:meth:`SweepResult.raise_if_failed`)."""


@dataclass(frozen=True)
class SweepError:
    """Why one case failed: the exception's type name, its one-line message and the traceback text.

    Examples
    --------
    >>> error = SweepError(type="ValueError", message="level must be >= 0", traceback="Traceback ...")
    >>> str(error)
    'ValueError: level must be >= 0'
    >>> try:
    ...     int("x")
    ... except ValueError as exc:
    ...     error = SweepError.from_exception(exc)
    >>> error.type, error.message, error.traceback.splitlines()[0]
    ('ValueError', "invalid literal for int() with base 10: 'x'", 'Traceback (most recent call last):')
    """

    type: str
    message: str
    traceback: str = ""

    @classmethod
    def from_exception(cls, exc: BaseException) -> SweepError:
        """Record `exc`: its class name, the first line of its message, its formatted traceback."""
        lines = str(exc).strip().splitlines()
        message = lines[0] + (" ..." if len(lines) > 1 else "") if lines else ""
        text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        return cls(type=type(exc).__name__, message=message, traceback=text)

    def __str__(self) -> str:
        return f"{self.type}: {self.message}" if self.message else self.type


def _short(value: Any) -> Any:
    """A table cell's short form: lists and dicts by their size, long text cut."""
    if isinstance(value, (list, tuple)):
        return f"[{len(value)} values]"
    if isinstance(value, Mapping):
        return f"{{{len(value)} keys}}"
    if isinstance(value, str) and len(value) > 60:
        return value[:57] + "..."
    return value


def _json_ready(value: Any) -> Any:
    return json.loads(json.dumps(value, default=json_default))


@dataclass(frozen=True)
class SweepResult:
    """The outcome of :func:`run_sweep`: for each case, in the order of the cases, its result or its error.

    Attributes
    ----------
    cases : list of dict
        The cases as given.
    results : list of (dict or None)
        ``results[i]`` is what ``func(**cases[i])`` returned (JSON-ready), None if the case failed.
    errors : list of (SweepError or None)
        ``errors[i]`` says why case ``i`` failed, None if it succeeded.
    durations : list of float
        Seconds each case took where it ran (0.0 for a case that never started).
    wall_time : float
        Seconds the whole sweep took, start-up of the workers included.
    scheduler : str
        Where the cases ran: ``"in-process"``, ``"processes:<n>"`` or the Dask scheduler's address.

    Examples
    --------
    >>> from cosim.study.sweep import run_sweep, _example_case
    >>> sweep = run_sweep(_example_case, [{"level": 0.1, "seed": 1}, {"level": -1.0, "seed": 2}],
    ...                   workers=1, progress=False)
    >>> sweep.ok, sweep.n_failed, str(sweep.errors[1])
    (False, 1, 'InvalidSettingError: noise level must be >= 0, got -1.0; use a non-negative level')
    >>> table = sweep.to_pandas()
    >>> list(table.columns)
    ['level', 'seed', 'amplitude', 'rms_error', 'noise_std', 'error']
    >>> table["amplitude"].round(3).tolist()
    [1.0, nan]
    >>> SweepResult.from_json(sweep.to_json()) == sweep
    True
    >>> sweep.raise_if_failed()  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    cosim.study.sweep_result.CaseFailedError: 1 of 2 cases failed, the first {'level': -1.0, 'seed': 2} with ...
    """

    cases: list[dict[str, Any]]
    results: list[dict[str, Any] | None]
    errors: list[SweepError | None]
    durations: list[float] = field(default_factory=list)
    wall_time: float = 0.0
    scheduler: str = _IN_PROCESS

    def __post_init__(self) -> None:
        n = len(self.cases)
        durations = self.durations if self.durations else [0.0] * n
        object.__setattr__(self, "durations", durations)
        if not len(self.results) == len(self.errors) == len(durations) == n:
            raise DataError(f"a sweep result needs one result, error and duration per case; got {n} cases, "
                            f"{len(self.results)} results, {len(self.errors)} errors, {len(durations)} durations")
        for i, (result, error) in enumerate(zip(self.results, self.errors, strict=True)):
            if (result is None) == (error is None):
                raise DataError(f"case {i} has {'both' if result is not None else 'neither'} a result and an "
                                "error; each case has exactly one of them")

    @property
    def ok(self) -> bool:
        """True if every case succeeded."""
        return self.n_failed == 0

    @property
    def n_failed(self) -> int:
        """How many cases failed."""
        return sum(error is not None for error in self.errors)

    def failures(self) -> list[tuple[dict[str, Any], SweepError]]:
        """The failed cases and their errors, in the order of the cases."""
        return [(case, error) for case, error in zip(self.cases, self.errors, strict=True) if error is not None]

    def raise_if_failed(self) -> SweepResult:
        """Raise :class:`CaseFailedError` naming the first failure if any case failed; else return self."""
        failures = self.failures()
        if failures:
            case, error = failures[0]
            raise CaseFailedError(f"{len(failures)} of {len(self.cases)} cases failed, the first {case} with "
                                  f"{error}; see SweepResult.failures() for all, with tracebacks")
        return self

    def _columns(self) -> tuple[dict[str, str], dict[str, str]]:
        case_keys = list(dict.fromkeys(key for case in self.cases for key in case))
        result_keys = list(dict.fromkeys(key for result in self.results if result for key in result))
        case_names = {key: f"case.{key}" if key == "error" else key for key in case_keys}
        taken = set(case_names.values()) | {"error"}
        result_names = {key: f"result.{key}" if key in taken else key for key in result_keys}
        return case_names, result_names

    def _repr_html_(self) -> str:
        """Jupyter's view: how many cases ran, failed and how long it took, and the first ten records."""
        from ..report import html_table

        rows = [{key: _short(value) for key, value in record.items()} for record in self.to_records()[:10]]
        marks = {(i, "error"): False for i, error in enumerate(self.errors[:10]) if error is not None}
        more = "; the first 10 shown (to_pandas() has all)" if len(self.cases) > 10 else ""
        caption = (f"sweep: {len(self.cases)} cases, {self.n_failed} failed, {self.wall_time:.3g} s wall time "
                   f"({self.scheduler}){more}")
        return html_table(rows or [{"cases": 0}], caption=caption, highlight=marks)

    def to_records(self) -> list[dict[str, Any]]:
        """One flat dict per case: the case's keys, the result's keys, and ``"error"``.

        ``"error"`` is ``"<type>: <message>"`` for a failed case and None otherwise; a failed case has no
        result keys. A result key that repeats a case key (or ``"error"``) is written ``"result.<key>"``, a
        case key ``"error"`` is written ``"case.error"``.
        """
        case_names, result_names = self._columns()
        records = []
        for case, result, error in zip(self.cases, self.results, self.errors, strict=True):
            record = {case_names[key]: value for key, value in case.items()}
            record.update({result_names[key]: value for key, value in (result or {}).items()})
            record["error"] = None if error is None else str(error)
            records.append(record)
        return records

    def to_pandas(self) -> pd.DataFrame:
        """The records as a table, one row per case: case columns, result columns, then ``error``."""
        import pandas as pd

        case_names, result_names = self._columns()
        columns = [*case_names.values(), *result_names.values(), "error"]
        return pd.DataFrame.from_records(self.to_records(), columns=columns)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict with ``"format"`` and ``"version"`` fields."""
        return {"format": SWEEP_FORMAT, "version": SWEEP_VERSION, "scheduler": self.scheduler,
                "wall_time": self.wall_time, "cases": self.cases, "results": self.results,
                "errors": [None if error is None else {"type": error.type, "message": error.message,
                                                       "traceback": error.traceback} for error in self.errors],
                "durations": self.durations}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SweepResult:
        """Rebuild a result from :meth:`to_dict`'s output."""
        check_file_format(data, SWEEP_FORMAT, SWEEP_VERSION, what="sweep result",
                          hint="save sweeps with SweepResult.save or to_json")
        try:
            errors = [None if error is None else SweepError(**error) for error in data["errors"]]
            return cls(cases=list(data["cases"]), results=list(data["results"]), errors=errors,
                       durations=list(data.get("durations") or []), wall_time=float(data.get("wall_time", 0.0)),
                       scheduler=str(data.get("scheduler", "")))
        except KeyError as exc:
            raise DataError(f"the sweep file lacks the field {exc.args[0]!r}") from None
        except TypeError as exc:
            raise DataError(f"the sweep file has a malformed error entry ({exc})") from None

    def to_json(self) -> str:
        """The result as JSON text; numpy values and paths in the cases are written as numbers, lists, str."""
        try:
            return json.dumps(self.to_dict(), indent=1, default=json_default)
        except (TypeError, ValueError) as exc:
            raise DataError(f"the cases are not JSON-serialisable ({exc}); keep case values to numbers, str, "
                            "lists and dicts to save a sweep") from None

    @classmethod
    def from_json(cls, text: str) -> SweepResult:
        """Read a result written by :meth:`to_json`."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"the sweep file is not JSON ({exc.msg} at line {exc.lineno})") from None
        return cls.from_dict(data)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the result as versioned JSON, atomically, and return the path."""
        return write_text_atomic(path, self.to_json() + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> SweepResult:
        """Read a result written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise FmuNotFoundError(f"no sweep file at {path}; check the path")
        return cls.from_json(path.read_text(encoding="utf-8"))
