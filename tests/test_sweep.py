"""run_sweep and SweepResult: in-process, local processes and a real Dask LocalCluster agree; failures are data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cosim import CosimError, DataError, InvalidSettingError
from cosim.study.sweep import _example_case, run_sweep
from cosim.study.sweep_result import CaseFailedError, SweepError, SweepResult

# The toy case lives in cosim.study.sweep so that spawned processes and Dask workers import it by name from any
# checkout, whatever pytest's import mode. Case 2 is designed to fail (negative noise level).
CASES = [
    {"level": 0.0, "seed": 1},
    {"level": 0.2, "seed": 1},
    {"level": -1.0, "seed": 2},
    {"level": 0.2, "seed": 2},
    {"level": 0.5, "seed": 3, "n": 50},
]
FAILING = 2


@pytest.fixture(scope="module")
def reference() -> SweepResult:
    return run_sweep(_example_case, CASES, workers=1, progress=False)


def check_outcome(sweep: SweepResult) -> None:
    assert sweep.cases == CASES
    assert not sweep.ok and sweep.n_failed == 1
    assert sweep.results[FAILING] is None
    error = sweep.errors[FAILING]
    assert error.type == "InvalidSettingError"
    assert error.message == "noise level must be >= 0, got -1.0; use a non-negative level"
    assert "Traceback" in error.traceback and "_example_case" in error.traceback
    assert sweep.failures() == [(CASES[FAILING], error)]
    for i, case in enumerate(CASES):  # order preserved: each result is its own case's, computed afresh
        if i != FAILING:
            assert sweep.errors[i] is None
            assert sweep.results[i] == _example_case(**case)
            assert sweep.durations[i] >= 0.0
    assert sweep.wall_time > 0.0


def test_in_process_reports_the_failing_case_and_keeps_the_order(reference):
    check_outcome(reference)
    assert reference.scheduler == "in-process"
    assert reference.results[0] == {"amplitude": 1.0, "rms_error": 0.0, "noise_std": 0.0}


def test_local_processes_give_the_same_results(reference):
    sweep = run_sweep(_example_case, CASES, workers=2, progress=False)
    check_outcome(sweep)
    assert sweep.scheduler == "processes:2"
    assert sweep.results == reference.results
    assert [str(e) if e else None for e in sweep.errors] == [str(e) if e else None for e in reference.errors]


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=40) as local_cluster:
        yield local_cluster


@pytest.mark.slow
def test_dask_cluster_by_address_gives_the_same_results(reference, cluster):
    sweep = run_sweep(_example_case, CASES, scheduler=cluster.scheduler_address, progress=False)
    check_outcome(sweep)
    assert sweep.scheduler == cluster.scheduler_address
    assert sweep.results == reference.results
    assert [str(e) if e else None for e in sweep.errors] == [str(e) if e else None for e in reference.errors]


@pytest.mark.slow
def test_dask_client_object_is_used_and_left_open(reference, cluster):
    from distributed import Client

    with Client(cluster, set_as_default=False) as client:
        sweep = run_sweep(_example_case, CASES[:2], scheduler=client, progress=False)
        assert client.status == "running"
        assert client.submit(sum, [1, 2]).result() == 3
    assert sweep.ok and sweep.results == reference.results[:2]
    with pytest.raises(InvalidSettingError, match="closed"):
        run_sweep(_example_case, CASES[:1], scheduler=client, progress=False)


def test_json_round_trip_and_files(reference, tmp_path):
    again = SweepResult.from_json(reference.to_json())
    assert again == reference
    assert isinstance(again.errors[FAILING], SweepError)
    path = reference.save(tmp_path / "sweeps" / "noise.json")
    assert SweepResult.load(path) == reference
    assert not list(path.parent.glob(".*tmp"))  # written atomically, nothing left over


def test_records_and_table(reference):
    records = reference.to_records()
    assert records[0] == {"level": 0.0, "seed": 1, "amplitude": 1.0, "rms_error": 0.0, "noise_std": 0.0,
                          "error": None}
    assert records[FAILING] == {"level": -1.0, "seed": 2,
                                "error": "InvalidSettingError: noise level must be >= 0, got -1.0; "
                                         "use a non-negative level"}
    table = reference.to_pandas()
    assert list(table.columns) == ["level", "seed", "n", "amplitude", "rms_error", "noise_std", "error"]
    assert len(table) == len(CASES)
    assert math.isnan(table["amplitude"][FAILING]) and table["seed"].tolist() == [1, 1, 2, 2, 3]


def test_jupyter_shows_the_counts_and_the_records(reference):
    text = reference._repr_html_()
    assert text.startswith("<table>") and "5 cases, 1 failed" in text and "in-process" in text
    assert text.count("<tr>") == 1 + len(CASES) and "noise level must be &gt;= 0" in text
    assert 'class="bad"' in text  # the failed case's error cell is marked
    many = SweepResult(cases=[{"i": i} for i in range(12)], results=[{"v": [1, 2, 3]}] * 12, errors=[None] * 12)
    text = many._repr_html_()
    assert text.count("<tr>") == 11 and "the first 10 shown" in text and "[3 values]" in text


def test_clashing_names_are_prefixed():
    sweep = SweepResult(cases=[{"seed": 1, "error": "case's own"}], results=[{"seed": 7, "value": 1.0}],
                        errors=[None])
    assert sweep.to_records() == [{"seed": 1, "case.error": "case's own", "result.seed": 7, "value": 1.0,
                                   "error": None}]


def test_raise_if_failed(reference):
    with pytest.raises(CaseFailedError, match=r"^1 of 5 cases failed, the first .*level': -1\.0") as info:
        reference.raise_if_failed()
    assert isinstance(info.value, RuntimeError) and isinstance(info.value, CosimError)
    ok = run_sweep(_example_case, [CASES[0]], workers=1, progress=False)
    assert ok.raise_if_failed() is ok


def test_bad_results_are_failures_and_numpy_values_are_converted():
    def func(*, kind):
        if kind == "list":
            return [1.0]
        if kind == "object":
            return {"x": object()}
        return {"x": np.float64(0.5), "v": np.arange(2), "i": np.int64(3)}

    sweep = run_sweep(func, [{"kind": "list"}, {"kind": "object"}, {"kind": "numpy"}], workers=1, progress=False)
    assert sweep.errors[0].type == "TypeError" and "expected a dict" in sweep.errors[0].message
    assert sweep.errors[1].type == "TypeError" and "not JSON-serialisable" in sweep.errors[1].message
    assert sweep.results[2] == {"x": 0.5, "v": [0, 1], "i": 3}
    assert type(sweep.results[2]["x"]) is float


def test_keyboard_interrupt_stops_the_sweep():
    ran = []

    def func(*, i):
        ran.append(i)
        if i == 1:
            raise KeyboardInterrupt
        return {"i": i}

    with pytest.raises(KeyboardInterrupt):
        run_sweep(func, [{"i": i} for i in range(4)], workers=1, progress=False)
    assert ran == [0, 1]


def test_progress_bar_on_stderr(capsys):
    run_sweep(_example_case, CASES, workers=1, desc="noise sweep", progress=True)  # stderr is no terminal here
    captured = capsys.readouterr()
    assert captured.out == ""
    assert "noise sweep" in captured.err and "5/5" in captured.err and "failed=1" in captured.err
    run_sweep(_example_case, CASES, workers=1, progress=False)
    assert capsys.readouterr().err == ""


def test_no_cases():
    sweep = run_sweep(_example_case, [], progress=False)
    assert sweep.ok and sweep.results == [] and sweep.to_records() == []


@pytest.mark.parametrize(("func", "cases", "options", "match"), [
    ("not callable", [{}], {}, "func must be callable"),
    (_example_case, {"level": 0.1, "seed": 1}, {}, "wrap a single case in a list"),
    (_example_case, [{"level": 0.1, "seed": 1}, ("level", 0.2)], {}, "case 1 is a tuple, expected a dict"),
    (_example_case, [{1: 0.1}], {}, "expected str keys"),
    (_example_case, [{"levl": 0.1, "seed": 1}], {}, "case 0 does not fit _example_case"),
    (_example_case, [{"level": 0.1}], {}, "missing a required argument: 'seed'"),
    (lambda level: {"x": level}, [{"level": 1}], {"workers": 2}, "not a lambda or nested function"),
    (_example_case, [{"level": 0.1, "seed": 1, "n": lambda: 3}], {"workers": 2}, "case 0 cannot be sent"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"workers": 0}, "workers must be an int >= 1"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"workers": 2.0}, "workers must be an int >= 1"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"scheduler": "tcp://127.0.0.1:8786", "workers": 2},
     "workers applies to local processes only"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"scheduler": 8786}, "scheduler must be None, a Dask"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"scheduler": "bogus://x"}, "is not valid"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"scheduler": "tcp://h:1", "connect_timeout": 0},
     "connect_timeout must be a positive number"),
    (_example_case, [{"level": 0.1, "seed": 1}], {"progress": "yes"}, "progress must be True, False or None"),
])
def test_bad_input_is_refused_before_running(func, cases, options, match):
    with pytest.raises(InvalidSettingError, match=match) as info:
        run_sweep(func, cases, progress=options.pop("progress", False), **options)
    assert "\n" not in str(info.value)


def test_unreachable_scheduler():
    with pytest.raises(InvalidSettingError, match=r"cannot reach a Dask scheduler at 'tcp://127\.0\.0\.1:1' "
                                                  r"within 1 s .*`dask scheduler`") as info:
        run_sweep(_example_case, CASES, scheduler="tcp://127.0.0.1:1", connect_timeout=1, progress=False)
    assert "\n" not in str(info.value)


def test_unknown_keyword_is_refused():
    with pytest.raises(TypeError, match="worker"):
        run_sweep(_example_case, CASES, worker=2)  # type: ignore[call-arg]


def test_inconsistent_result_is_refused():
    with pytest.raises(DataError, match="case 0 has both a result and an error"):
        SweepResult(cases=[{}], results=[{"x": 1}], errors=[SweepError("E", "m")])
    with pytest.raises(DataError, match="one result, error and duration per case"):
        SweepResult(cases=[{}, {}], results=[{"x": 1}], errors=[None])
    with pytest.raises(DataError, match="not a cosim sweep result"):
        SweepResult.from_json('{"format": "cosim-identified-model", "version": 1}')
    with pytest.raises(DataError, match="not JSON"):
        SweepResult.from_json("{")


@pytest.mark.slow
def test_a_dead_worker_costs_only_its_own_case():
    cases = [{"level": 0.1, "seed": seed, "crash": seed == 2} for seed in range(5)]
    sweep = run_sweep(_example_case, cases, workers=2, progress=False)
    assert [error is None for error in sweep.errors] == [True, True, False, True, True]
    assert sweep.errors[2].type == "BrokenProcessPool"
    assert sweep.errors[2].message.startswith("the worker process died while running this case")
    assert sweep.results[3] == _example_case(level=0.1, seed=3)


class _StarvedLoopClient:
    """Fails as distributed's LoopRunner does when its event-loop thread does not start in 10 s, `fails` times."""

    made = 0

    def __init__(self, scheduler, *, timeout, set_as_default, fails):
        type(self).made += 1
        if type(self).made <= fails:
            raise AssertionError  # what distributed.utils.LoopRunner's bare `assert loop is not None` raises
        self.scheduler = scheduler


@pytest.mark.parametrize("fails, connects", [(2, True), (3, False)])
def test_a_client_whose_event_loop_did_not_start_is_tried_again(fails, connects):
    from functools import partial

    from cosim.errors import CosimError
    from cosim.study._sweep_backends import _client

    _StarvedLoopClient.made = 0
    starved = partial(_StarvedLoopClient, fails=fails)
    if connects:
        assert _client(starved, "tcp://127.0.0.1:8786", 1.0).scheduler == "tcp://127.0.0.1:8786"
        assert _StarvedLoopClient.made == 3
    else:
        with pytest.raises(CosimError, match=r"could not start its event loop in 3 tries of 10 s each"):
            _client(starved, "tcp://127.0.0.1:8786", 1.0)


def test_a_refused_connection_leaves_no_half_made_client_behind():
    """A Client whose constructor failed sits in a reference cycle; collected later, at a moment nobody chose,
    its __del__ closes a loop runner, and when that moment fell inside another Client's start the two waited on
    each other for ever (a CI run hung in test_unreachable_scheduler, 2026-12-02). The sweep collects it at once."""
    import gc

    import distributed

    for scheduler in ("bogus://x", "tcp://127.0.0.1:1"):
        with pytest.raises(InvalidSettingError):
            run_sweep(_example_case, CASES, scheduler=scheduler, connect_timeout=1, progress=False)
        assert not [o for o in gc.get_objects() if isinstance(o, distributed.Client)], scheduler
