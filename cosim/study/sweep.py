"""Batches of independent runs: :func:`run_sweep` runs ``func(**case)`` for each case, locally or on Dask.

One engine for every study made of many runs: the noise sweep of the reference study (noise level x seed x
excitation: simulate, add noise, identify, score), Monte Carlo robustness of a controller over plant
parameters, residual studies. A case is a dict of keyword arguments that holds everything the run needs,
its seed included, so its result depends neither on where nor in which order it ran: the same cases give
the same results in-process, in local processes and on a Dask cluster.

Where the cases run
-------------------
``scheduler=None, workers=1``
    In this process, one after the other: the simplest to debug (a breakpoint in ``func`` works).
``scheduler=None, workers=n`` (default: the CPUs this process may use)
    ``n`` local worker processes (:class:`concurrent.futures.ProcessPoolExecutor`) started with the
    ``"spawn"`` method: a worker is a fresh interpreter that imports what it needs. ``fork`` would copy a
    parent that may hold threads (tqdm's monitor, a Dask client's event loop, BLAS pools) and loaded FMU
    binaries, which can deadlock or corrupt a child (Python 3.12 warns about it; 3.14 stopped using fork by
    default). ``spawn`` is also the only method on Windows and the default on macOS, so a sweep behaves the
    same everywhere; ``forkserver`` would start workers a little faster but exists on POSIX only. The cost is
    a worker start-up once per sweep (a second or two: the workers import cosim), and that a script calling
    :func:`run_sweep` must guard its entry point with ``if __name__ == "__main__":``, as for any spawned pool.
``scheduler="tcp://host:port"`` or a :class:`distributed.Client`
    The cases are submitted to that Dask cluster (start one with ``dask scheduler`` and ``dask worker
    tcp://host:8786`` on each machine). The workers need the same environment: cosim and the module of
    ``func`` installed.

``func`` is a top-level function of an importable module (the workers import it by name); the results it
returns are dicts of JSON-serialisable values (numpy scalars and arrays are converted). A case whose ``func``
raises is recorded as a :class:`SweepError` (type, one-line message, traceback) and the other cases still run.
A local worker process that dies (a crash in native code, an out-of-memory kill) costs only the case it was
running; Dask retries a task whose worker died and reports it failed (``KilledWorker``) after
``distributed.scheduler.allowed-failures`` deaths (3 by default). A progress bar with an ETA on stderr
advances as cases complete; results come back in the order of the cases. ``_example_case`` is a small seeded
case shipped for the examples, the tests and a smoke test of a cluster.

Examples
--------
>>> from cosim.study.sweep import run_sweep, _example_case
>>> cases = [{"level": level, "seed": seed} for level in (0.0, 0.5) for seed in (1, 2)]
>>> sweep = run_sweep(_example_case, cases, workers=2, progress=False)
>>> sweep.ok, len(sweep.results)
(True, 4)
>>> [round(r["amplitude"], 3) for r in sweep.results]
[1.0, 1.0, 1.0, 1.028]
"""

from __future__ import annotations

import concurrent.futures
import inspect
import json
import math
import multiprocessing
import os
import pickle
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm.auto import tqdm

from ..errors import CosimError, DataError, FmuNotFoundError, InvalidSettingError
from ..files import check_file_format, write_text_atomic

if TYPE_CHECKING:
    import distributed
    import pandas as pd

__all__ = ["run_sweep", "SweepResult", "SweepError", "CaseFailedError", "SWEEP_FORMAT", "SWEEP_VERSION"]

SWEEP_FORMAT = "cosim-sweep"
SWEEP_VERSION = 1
#: Seconds :func:`run_sweep` waits for a Dask scheduler to answer, unless told otherwise.
CONNECT_TIMEOUT = 10.0
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


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def _json_ready(value: Any) -> Any:
    return json.loads(json.dumps(value, default=_json_default))


def _run_case(func: Callable[..., Any], case: Mapping[str, Any]) -> tuple[dict | None, SweepError | None, float]:
    """Run one case where it is scheduled: (result, None, seconds) or (None, error, seconds), never raises."""
    start = time.perf_counter()
    try:
        result = func(**case)
        if not isinstance(result, Mapping) or not all(isinstance(key, str) for key in result):
            raise TypeError(f"func returned {type(result).__name__}, expected a dict with str keys; "
                            "return the run's metrics as a dict")
        try:
            result = _json_ready(dict(result))
        except (TypeError, ValueError) as exc:
            raise TypeError(f"func returned a dict that is not JSON-serialisable ({exc}); "
                            "keep its values to numbers, str, lists and dicts") from None
    except Exception as exc:  # a failed case is data, not a crash of the sweep
        return None, SweepError.from_exception(exc), time.perf_counter() - start
    return result, None, time.perf_counter() - start


def _example_case(*, level: float, seed: int, n: int = 200, crash: bool = False) -> dict[str, float]:
    """A seeded toy run for examples, tests and cluster smoke tests: fit a sine's amplitude under noise.

    Samples ``sin(2 pi t)`` at `n` points of one period, adds Gaussian noise of standard deviation `level`
    drawn from ``numpy.random.default_rng(seed)`` and fits the amplitude by least squares. ``crash=True``
    ends the process at once (``os._exit``), as a crash in native code would: never in this process.

    Raises
    ------
    InvalidSettingError
        If `level` is negative: the case designed to fail.

    Examples
    --------
    >>> result = _example_case(level=0.0, seed=1)
    >>> result["amplitude"], result["rms_error"]
    (1.0, 0.0)
    """
    if crash:
        os._exit(70)
    if level < 0:
        raise InvalidSettingError(f"noise level must be >= 0, got {level}; use a non-negative level")
    rng = np.random.default_rng(seed)
    t = np.arange(n) / n
    clean = np.sin(2 * np.pi * t)
    noisy = clean + level * rng.standard_normal(n)
    amplitude = float(noisy @ clean / (clean @ clean))
    rms_error = float(np.sqrt(np.mean((amplitude * clean - clean) ** 2)))
    return {"amplitude": amplitude, "rms_error": rms_error, "noise_std": float(np.std(noisy - clean))}


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
    cosim.study.sweep.CaseFailedError: 1 of 2 cases failed, the first {'level': -1.0, 'seed': 2} with ...
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
            return json.dumps(self.to_dict(), indent=1, default=_json_default)
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


# ----------------------------------------------------------------------------------------------- validation


def _check_cases(cases: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    if isinstance(cases, (Mapping, str, bytes)) or not isinstance(cases, Iterable):
        hint = "; wrap a single case in a list" if isinstance(cases, Mapping) else ""
        raise InvalidSettingError(f"cases must be a sequence of dicts, got {type(cases).__name__}{hint}")
    checked = []
    for i, case in enumerate(cases):
        if not isinstance(case, Mapping):
            raise InvalidSettingError(f"case {i} is a {type(case).__name__}, expected a dict of keyword "
                                      "arguments for func; give each case as a dict")
        bad = [key for key in case if not isinstance(key, str)]
        if bad:
            raise InvalidSettingError(f"case {i} has the key {bad[0]!r}, expected str keys (func's parameter "
                                      "names)")
        checked.append(dict(case))
    return checked


def _check_signature(func: Callable[..., Any], cases: list[dict[str, Any]]) -> None:
    try:
        signature = inspect.signature(func)
    except (TypeError, ValueError):  # some builtins have none: let the cases tell
        return
    name = getattr(func, "__name__", type(func).__name__)
    for i, case in enumerate(cases):
        try:
            signature.bind(**case)
        except TypeError as exc:
            raise InvalidSettingError(f"case {i} does not fit {name}{signature}: {exc}; give each case the "
                                      "keyword arguments of func") from None


def _check_picklable(func: Callable[..., Any], cases: list[dict[str, Any]], *, dumps: Callable[[Any], bytes],
                     where: str) -> None:
    name = getattr(func, "__qualname__", type(func).__name__)
    main = sys.modules.get("__main__")
    if where == "processes" and getattr(func, "__module__", None) == "__main__" and \
            not getattr(main, "__file__", None):
        raise InvalidSettingError(f"func {name} is defined interactively, which worker processes cannot import; "
                                  "define it in a module file, or run with workers=1")
    try:
        dumps(func)
    except Exception as exc:
        raise InvalidSettingError(f"func {name} cannot be sent to the {where} ({type(exc).__name__}: {exc}); "
                                  "define it at the top level of a module (not a lambda or nested function), "
                                  "or run with workers=1") from None
    for i, case in enumerate(cases):
        try:
            dumps(case)
        except Exception as exc:
            raise InvalidSettingError(f"case {i} cannot be sent to the {where} ({type(exc).__name__}: {exc}); "
                                      "keep case values to numbers, str, arrays, lists and dicts") from None


def _default_workers() -> int:
    if hasattr(os, "sched_getaffinity"):  # the CPUs this process may use (containers, taskset)
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


# ----------------------------------------------------------------------------------------------- the engine


def run_sweep(func: Callable[..., Mapping[str, Any]], cases: Iterable[Mapping[str, Any]], *,
              scheduler: str | distributed.Client | None = None, workers: int | None = None,
              progress: bool | None = True, desc: str = "sweep",
              connect_timeout: float = CONNECT_TIMEOUT) -> SweepResult:
    """Run ``func(**case)`` for every case, in parallel, and collect each result or error in case order.

    Parameters
    ----------
    func : callable
        ``func(**case) -> dict`` of JSON-serialisable values (numpy scalars and arrays are converted). For
        worker processes or Dask, a top-level function of an importable module (it is pickled by name).
    cases : sequence of dict
        Each case's keyword arguments, checked against `func`'s signature before anything runs. A case
        holds everything its run needs, its seed included, so results do not depend on where it ran.
    scheduler : None, str or distributed.Client, optional
        None: local processes (or this process if ``workers=1``). A Dask scheduler address such as
        ``"tcp://10.0.0.5:8786"``, or a connected :class:`distributed.Client` (left open afterwards).
    workers : int, optional
        Local worker processes (default: the CPUs this process may use); 1 runs the cases in this process,
        one after the other, handy for debugging. Only with ``scheduler=None``.
    progress : bool or None, default True
        Show a progress bar with an ETA on stderr as cases complete; False hides it, None shows it only on
        a terminal.
    desc : str, default "sweep"
        The progress bar's label.
    connect_timeout : float, default 10
        Seconds to wait for the Dask scheduler to answer.

    Returns
    -------
    SweepResult
        One result or :class:`SweepError` per case, in the order of `cases`.

    Raises
    ------
    InvalidSettingError
        Before running anything: `func` not callable or not picklable for the workers, a case not a dict or
        not fitting `func`'s parameters, bad `workers`, or a Dask scheduler that cannot be reached.
    KeyboardInterrupt
        Re-raised after cancelling the cases not yet started; local worker processes are ended at once, a case
        already running on a Dask worker runs to its end there.

    Examples
    --------
    >>> from cosim.study.sweep import run_sweep, _example_case
    >>> sweep = run_sweep(_example_case, [{"level": 0.1, "seed": s} for s in range(3)], workers=1,
    ...                   progress=False)
    >>> [round(r["noise_std"], 3) for r in sweep.results]
    [0.096, 0.092, 0.096]
    >>> sweep.scheduler
    'in-process'
    """
    if not callable(func):
        raise InvalidSettingError(f"func must be callable, got {type(func).__name__}; pass the function that "
                                  "runs one case")
    if not isinstance(desc, str):
        raise InvalidSettingError(f"desc must be a str, got {type(desc).__name__}")
    if progress is not None and not isinstance(progress, bool):
        raise InvalidSettingError(f"progress must be True, False or None, got {progress!r}")
    case_list = _check_cases(cases)
    _check_signature(func, case_list)
    disable = None if progress is None else not progress
    start = time.perf_counter()

    if scheduler is None:
        if workers is None:
            workers = _default_workers()
        elif isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise InvalidSettingError(f"workers must be an int >= 1, got {workers!r}; use 1 to run in this "
                                      "process")
        if workers == 1 or not case_list:
            outcomes = _run_in_process(func, case_list, desc=desc, disable=disable)
            where = _IN_PROCESS
        else:
            _check_picklable(func, case_list, dumps=pickle.dumps, where="processes")
            n = min(workers, len(case_list))
            outcomes = _run_in_processes(func, case_list, n, desc=desc, disable=disable)
            where = f"processes:{n}"
    else:
        if workers is not None:
            raise InvalidSettingError("workers applies to local processes only; with a Dask scheduler the "
                                      "cluster's workers run the cases, so leave workers unset")
        if isinstance(connect_timeout, bool) or not isinstance(connect_timeout, (int, float)) or \
                not math.isfinite(connect_timeout) or connect_timeout <= 0:
            raise InvalidSettingError(f"connect_timeout must be a positive number of seconds, got "
                                      f"{connect_timeout!r}")
        import cloudpickle

        _check_picklable(func, case_list, dumps=cloudpickle.dumps, where="Dask workers")
        outcomes, where = _run_on_dask(func, case_list, scheduler, connect_timeout=float(connect_timeout),
                                       desc=desc, disable=disable)

    results, errors, durations = (list(column) for column in zip(*outcomes, strict=True)) if outcomes else ([], [], [])
    return SweepResult(cases=case_list, results=results, errors=errors, durations=durations,
                       wall_time=time.perf_counter() - start, scheduler=where)


_Outcome = tuple[dict | None, SweepError | None, float]


def _bar(total: int, desc: str, disable: bool | None) -> tqdm:
    return tqdm(total=total, desc=desc, unit="case", disable=disable, file=sys.stderr, dynamic_ncols=True)


class _Progress:
    """Advance the bar by one case and count the failures in its postfix."""

    def __init__(self, bar: tqdm) -> None:
        self.bar = bar
        self.failed = 0

    def advance(self, outcome: _Outcome | None) -> None:
        if outcome is not None and outcome[1] is not None:
            self.failed += 1
            self.bar.set_postfix(failed=self.failed, refresh=False)
        self.bar.update(1)


def _run_in_process(func: Callable[..., Any], cases: list[dict[str, Any]], *, desc: str,
                    disable: bool | None) -> list[_Outcome]:
    outcomes: list[_Outcome] = []
    with _bar(len(cases), desc, disable) as bar:
        progress = _Progress(bar)
        for case in cases:
            outcomes.append(_run_case(func, case))
            progress.advance(outcomes[-1])
    return outcomes


def _lost(exc: BaseException, what: str, hint: str) -> _Outcome:
    error = SweepError.from_exception(exc)
    message = f"{what} ({error}); {hint}"
    return None, SweepError(type=error.type, message=message, traceback=error.traceback), 0.0


# Set in each local worker process by its pool's initializer: one flag per case, shared with the parent, so
# that when a worker dies the parent knows which cases had started (the suspects) and which had not.
_started_flags: Any = None


def _init_worker(flags: Any) -> None:
    global _started_flags
    _started_flags = flags


def _run_flagged_case(func: Callable[..., Any], case: Mapping[str, Any], index: int) -> _Outcome:
    _started_flags[index] = 1
    return _run_case(func, case)


def _stop(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """Cancel the cases not started and end the worker processes now, rather than after their current case."""
    # the executor's table of its processes: private but stable since Python 3.8 (3.14 adds terminate_workers)
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=10)


_DIED = ("the worker process died while running this case (a crash in native code, or killed, e.g. out of "
         "memory); run the case alone with workers=1 to debug it")
_NOT_STARTED = ("the worker processes died before running a case: they could not start or import func (their "
                "traceback is on stderr); check that func's module imports in a fresh Python, or use workers=1")


def _pool_round(func: Callable[..., Any], cases: list[dict[str, Any]], indices: list[int],
                outcomes: list[_Outcome | None], progress: _Progress, *, workers: int,
                isolate: bool = False) -> tuple[set[int], set[int]]:
    """Run ``cases[indices]`` in fresh processes and fill `outcomes`.

    The cases share a pool of `workers` processes, or with ``isolate=True`` each runs alone in its own
    process, all at once. Returns the cases lost because a worker died, and those of them that had started.
    """
    context = multiprocessing.get_context("spawn")  # see the module's docstring for why not fork
    flags = context.RawArray("b", len(cases))
    sizes = [1] * len(indices) if isolate else [min(workers, len(indices))]
    pools = [concurrent.futures.ProcessPoolExecutor(max_workers=size, mp_context=context, initializer=_init_worker,
                                                    initargs=(flags,)) for size in sizes]
    lost: set[int] = set()
    try:
        futures = {pools[k if isolate else 0].submit(_run_flagged_case, func, cases[i], i): i
                   for k, i in enumerate(indices)}
        for future in concurrent.futures.as_completed(futures):
            i = futures[future]
            try:
                outcomes[i] = future.result()
            except concurrent.futures.process.BrokenProcessPool:
                lost.add(i)
                continue
            except Exception as exc:  # e.g. a result the pool could not send back
                outcomes[i] = _lost(exc, "the worker process could not run the case",
                                    "rerun with workers=1 to see why")
            progress.advance(outcomes[i])
    except BaseException:  # KeyboardInterrupt, or an error of the engine
        for pool in pools:
            _stop(pool)
        raise
    for pool in pools:
        pool.shutdown(wait=True)
    return lost, {i for i in lost if flags[i]}


def _run_in_processes(func: Callable[..., Any], cases: list[dict[str, Any]], workers: int, *, desc: str,
                      disable: bool | None) -> list[_Outcome]:
    """Run the cases in `workers` processes; a worker that dies costs only the case it was running.

    When a worker dies (segfault, out-of-memory kill) its pool breaks, and every unfinished case with it. The
    cases that had started then run again, each alone in a fresh process, so that the one that kills its
    process is recorded as failed and the others succeed; then the cases not started go on in parallel.
    """
    outcomes: list[_Outcome | None] = [None] * len(cases)
    with _bar(len(cases), desc, disable) as bar:
        progress = _Progress(bar)
        todo = list(range(len(cases)))
        while todo:
            lost, started = _pool_round(func, cases, todo, outcomes, progress, workers=workers)
            if not lost:
                break
            if not started:  # no case had started: the workers themselves cannot start
                died, started = lost, set()
            else:
                died, started = _pool_round(func, cases, sorted(started), outcomes, progress, workers=1,
                                            isolate=True)
            for i in sorted(died):
                outcomes[i] = (None, SweepError("BrokenProcessPool", _DIED if i in started else _NOT_STARTED), 0.0)
                progress.advance(outcomes[i])
            todo = [i for i in todo if outcomes[i] is None]
    return outcomes  # type: ignore[return-value]


def _connect(scheduler: Any, timeout: float) -> tuple[distributed.Client, bool]:
    """A client for `scheduler` and whether this call owns it (and must close it)."""
    distributed = sys.modules.get("distributed")
    if distributed is not None and isinstance(scheduler, distributed.Client):
        if scheduler.asynchronous:
            raise InvalidSettingError("run_sweep needs a synchronous distributed.Client; create it without "
                                      "asynchronous=True or pass the scheduler's address")
        if scheduler.status != "running":
            raise InvalidSettingError(f"the distributed.Client passed is {scheduler.status}, expected running; "
                                      "pass a connected client or the scheduler's address")
        return scheduler, False
    if not isinstance(scheduler, str) or not scheduler.strip():
        hint = "; pass its scheduler_address" if hasattr(scheduler, "scheduler_address") else ""
        raise InvalidSettingError(f"scheduler must be None, a Dask scheduler address such as "
                                  f"'tcp://127.0.0.1:8786' or a distributed.Client, got {scheduler!r}{hint}")
    from distributed import Client

    try:
        return Client(scheduler, timeout=timeout, set_as_default=False), True
    except ValueError as exc:  # unknown scheme, malformed address
        raise InvalidSettingError(f"scheduler address {scheduler!r} is not valid ({exc}); expected e.g. "
                                  "'tcp://127.0.0.1:8786'") from None
    except (OSError, TimeoutError) as exc:
        raise InvalidSettingError(f"cannot reach a Dask scheduler at {scheduler!r} within {timeout:g} s "
                                  f"({type(exc).__name__}); check the address, or start one with `dask scheduler` "
                                  "and pass the address it prints") from None


def _run_on_dask(func: Callable[..., Any], cases: list[dict[str, Any]], scheduler: Any, *, connect_timeout: float,
                 desc: str, disable: bool | None) -> tuple[list[_Outcome], str]:
    from distributed import as_completed

    client, owned = _connect(scheduler, connect_timeout)
    futures: list[Any] = []
    try:
        where = str(client.scheduler.address)
        outcomes: list[_Outcome | None] = [None] * len(cases)
        futures = [client.submit(_run_case, func, case, pure=False) for case in cases]
        index = {future.key: i for i, future in enumerate(futures)}
        with _bar(len(cases), desc, disable) as bar:
            progress = _Progress(bar)
            for future in as_completed(futures, loop=client.loop):
                i = index[future.key]
                try:
                    outcomes[i] = future.result()
                except Exception as exc:  # the worker could not run it: func not importable there, worker lost
                    outcomes[i] = _lost(exc, "the Dask workers could not run the case",
                                          "check that cosim and func's module are installed on the workers")
                future.release()
                progress.advance(outcomes[i])
        return outcomes, where  # type: ignore[return-value]
    except BaseException:  # KeyboardInterrupt, or an error of the engine: drop the cases not finished
        if futures:
            client.cancel(futures)
        raise
    finally:
        if owned:
            client.close()
