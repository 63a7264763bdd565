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
raises is recorded as a
:class:`~cosim.study.sweep_result.SweepError` (type, one-line message, traceback) and the other cases still run.
A local worker process that dies (a crash in native code, an out-of-memory kill) costs only the case it was
running; Dask retries a task whose worker died and reports it failed (``KilledWorker``) after
``distributed.scheduler.allowed-failures`` deaths (3 by default). A progress bar with an ETA on stderr (when
stderr is a terminal, or with ``progress=True``) advances as cases complete; results come back in the order of
the cases. ``_example_case`` is a small seeded case shipped for the examples, the tests and a smoke test of a
cluster.

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

import inspect
import math
import os
import pickle
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InvalidSettingError
from ._sweep_backends import _run_in_process, _run_in_processes, _run_on_dask
from .sweep_result import _IN_PROCESS, SweepResult

if TYPE_CHECKING:
    import distributed

__all__ = ["run_sweep"]

#: Seconds :func:`run_sweep` waits for a Dask scheduler to answer, unless told otherwise.
CONNECT_TIMEOUT = 10.0


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
              progress: bool | None = None, desc: str = "sweep",
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
    progress : bool or None, default None
        Progress bar with an ETA on stderr as cases complete. None shows it only when stderr is a terminal
        (not when it is redirected to a file or a pipe); True shows it anyway, False hides it.
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
