"""Where the cases of a sweep run: in this process, in local worker processes, or on a Dask cluster.

The three back-ends of :func:`~cosim.study.sweep.run_sweep` (see :mod:`cosim.study.sweep` for when each is
used, and why local workers are spawned rather than forked). Each takes the checked cases and returns one
outcome per case, in the order of the cases: ``(result, None, seconds)`` or ``(None, SweepError, seconds)``,
advancing a progress bar as cases complete. :func:`_run_case` is what runs one case wherever it is scheduled
(workers import it from this module by name); it never raises.
"""

from __future__ import annotations

import concurrent.futures
import gc
import multiprocessing
import sys
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from tqdm.auto import tqdm

from ..errors import CosimError, InvalidSettingError
from .sweep_result import SweepError, _json_ready

if TYPE_CHECKING:
    import distributed

#: One case's outcome: (result, None, seconds) or (None, error, seconds).
_Outcome = tuple[dict | None, SweepError | None, float]


def _run_case(func: Callable[..., Any], case: Mapping[str, Any]) -> _Outcome:
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


def _bar(total: int, desc: str, disable: bool | None) -> tqdm:
    """The sweep's bar on stderr; ``disable=None`` lets tqdm show it only when stderr is a terminal."""
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
    context = multiprocessing.get_context("spawn")  # see cosim.study.sweep's docstring for why not fork
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


_LOOP_START_ATTEMPTS = 3


def _client(client_class: Callable[..., Any], scheduler: str, timeout: float) -> distributed.Client:
    """``Client(scheduler)``, tried again when Dask's own event-loop thread did not start.

    distributed's ``LoopRunner`` gives the thread that runs a client's event loop a fixed 10 s to start and then
    fails on a bare ``assert loop is not None``; on a starved machine (a CI runner busy with other work) that
    happened once in a full test run. The thread has nothing to do with the scheduler's address, so a new client
    is tried, up to `_LOOP_START_ATTEMPTS` times, before saying so in one line.
    """
    for _ in range(_LOOP_START_ATTEMPTS):
        error: BaseException | None = None
        try:
            return client_class(scheduler, timeout=timeout, set_as_default=False)
        except AssertionError:
            pass
        except BaseException as exc:  # noqa: BLE001 - raised again below
            error = exc.with_traceback(None)  # its frames hold the half-made client
        # A client whose constructor failed is left in a reference cycle. Collected later, its __del__ closes its
        # loop runner, and if that collection runs while another client is starting the loop runner, both wait
        # on its lock for ever (seen in CI, 2026-12-02: test_sweep.py's unreachable scheduler hung in
        # Client.__init__ -> LoopRunner.start -> gc -> Client.__del__ -> LoopRunner.stop). Collected now, it
        # closes while no other client is starting.
        gc.collect()
        if error is not None:
            raise error
    raise CosimError(f"Dask's client could not start its event loop in {_LOOP_START_ATTEMPTS} tries of "
                     "10 s each: this machine is too busy; try again when it is less loaded")


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
        return _client(Client, scheduler, timeout), True
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
