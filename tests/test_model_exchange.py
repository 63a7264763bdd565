"""`ModelExchangeSlave`: Model Exchange FMUs stepped at a communication step, checked against FMPy's own
``simulate_fmu(fmi_type="ModelExchange")`` and against analytic solutions, on the Modelica Association's
Reference FMUs (FMI 2.0 and 3.0).

The slave takes the very solver calls FMPy takes on the same grid (same solver, tolerance, largest step,
events), so it agrees with FMPy far inside the solver's tolerance: the only difference is the communication
times, ``t + h`` here against ``start + (k + 1) h`` in FMPy (an ulp apart).
"""

from __future__ import annotations

import math
import shutil
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

sys.path.insert(0, str(Path(__file__).parent))
from reference_fmus import reference_fmus  # noqa: E402

from cosim.plant._fmi_calls import read_value, write_value  # noqa: E402
from cosim.plant.model_exchange import ModelExchangeSlave, SolverError  # noqa: E402

H = 0.01  # communication step
RTOL = 1e-5  # FMPy's default relative tolerance for CVode


@contextmanager
def me_slave(path: Path, *, terminate: bool = True, **options):
    """An initialised ModelExchangeSlave of the FMU at `path`, terminated (unless an FMI error made that illegal:
    `terminate` False) and freed on exit."""
    md = fmpy.read_model_description(str(path))
    unzipdir = fmpy.extract(str(path))
    slave = ModelExchangeSlave(md.guid, unzipdir, md.modelExchange.modelIdentifier, "test",
                               fmi_version=md.fmiVersion, model_description=md, **options)
    try:
        slave.instantiate()
        variables = {v.name: v for v in md.modelVariables}
        if md.fmiVersion == "2.0":
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
        else:
            slave.enterInitializationMode(startTime=0.0)
        slave.exitInitializationMode()
        slave.variables = variables
        yield slave
        if terminate:
            slave.terminate()
    finally:
        slave.freeInstance()
        shutil.rmtree(unzipdir, ignore_errors=True)


def step_through(slave, names: list[str], stop: float, h: float = H) -> np.ndarray:
    """The values of `names` at 0, h, 2h... stop (read with getReal/getFloat64... after each doStep)."""
    version = "2.0" if slave._v2 else "3.0"
    variables = [slave.variables[name] for name in names]
    rows = [[read_value(slave, version, v) for v in variables]]
    for k in range(round(stop / h)):
        terminated = slave.doStep(k * h, h)
        rows.append([read_value(slave, version, v) for v in variables])
        if terminated:
            break
    return np.array(rows, dtype=float)


def fmpy_me(path: Path, names: list[str], stop: float, solver: str, rtol: float = RTOL) -> np.ndarray:
    result = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", solver=solver, output_interval=H,
                               stop_time=stop, relative_tolerance=rtol, output=names, record_events=False)
    assert np.allclose(np.diff(result["time"]), H)  # the communication grid, no event rows
    return np.column_stack([result[name] for name in names])


def solver_options(solver: str, stop: float) -> dict:
    """FMPy's choices in simulateME: CVode's largest step (stop - start) / 50, Euler's step the output interval."""
    if solver == "CVode":
        return dict(solver="CVode", relative_tolerance=RTOL, max_step=stop / 50)
    return dict(solver="Euler", fixed_step=H)


# CVode: the same solver calls as FMPy, so the results agree to rounding (measured <= 5e-13 on BouncingBall,
# where the event times amplify the ulp differences of the grid); 1e-9 is 4 orders inside the solver's own
# tolerance (1e-5), so a missed, late or doubled event, or a solver reset in the wrong place, would fail it.
# Euler: the very same fixed steps and events, so the same numbers up to the grid's ulps (measured <= 1.3e-14).
TOLERANCE = {"CVode": 1e-9, "Euler": 1e-12}


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("model, names", [("BouncingBall", ["h", "v"]), ("VanDerPol", ["x0", "x1"])])
def test_steps_agree_with_fmpy_simulate_me(model, names, version, solver):
    stop = 3.0
    path = reference_fmus(version)[model]
    with me_slave(path, **solver_options(solver, stop)) as slave:
        mine = step_through(slave, names, stop)
        assert slave.terminated_at is None
        assert slave.time == pytest.approx(stop)
    reference = fmpy_me(path, names, stop, solver)
    assert mine.shape == reference.shape == (301, 2)
    np.testing.assert_allclose(mine, reference, rtol=0, atol=TOLERANCE[solver])
    if model == "BouncingBall":  # the bounces happened (a state event each): the ball came up again
        assert np.any(np.diff(mine[:, 1]) > 1.0)


@pytest.mark.parametrize("version", [2, 3])
def test_euler_cuts_a_communication_step_into_fixed_steps(version):
    """fixed_step = h / 4: the same numbers as FMPy's Euler on a grid four times finer."""
    path = reference_fmus(version)["BouncingBall"]
    with me_slave(path, solver="Euler", fixed_step=H / 4) as slave:
        mine = step_through(slave, ["h", "v"], 1.0)
    result = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", solver="Euler", output_interval=H / 4,
                               step_size=H / 4, stop_time=1.0, output=["h", "v"], record_events=False)
    reference = np.column_stack([result["h"], result["v"]])[::4]
    assert mine.shape == reference.shape == (101, 2)
    np.testing.assert_allclose(mine, reference, rtol=0, atol=1e-12)


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
@pytest.mark.parametrize("version", [2, 3])
def test_stair_counts_its_time_events_and_terminates_at_9_s(version, solver):
    """Stair counts at t = 1, 2... (time events) and requests to terminate when it reaches 10, at t = 9 s."""
    path = reference_fmus(version)["Stair"]
    with me_slave(path, solver=solver) as slave:
        counter = step_through(slave, ["counter"], 10.0)[:, 0]
        assert slave.terminated_at == pytest.approx(9.0)
        assert slave.time == slave.terminated_at
        assert slave.doStep(9.0, H) is True  # and stays there
        assert slave.time == slave.terminated_at
    reference = fmpy_me(path, ["counter"], 10.0, solver)[:, 0]
    # FMPy stops its loop at the termination without recording t = 9 s: 0 ... 8.99 s
    assert len(reference) == 900 and len(counter) == 901
    np.testing.assert_array_equal(counter[:900], reference)
    t = np.arange(901) * H
    np.testing.assert_array_equal(counter, 1 + np.floor(t + 1e-9))  # 1 until 1 s, ... 10 at 9 s
    assert counter[-1] == 10


@pytest.mark.parametrize("version", [2, 3])
def test_dahlquist_follows_the_exponential_within_cvode_tolerance(version):
    """x' = -k x, x(0) = 1, k = 1: x = exp(-t). CVode bounds the error of each step by rtol |x| + rtol (the
    absolute tolerance is rtol times the nominal 1); the global error over 10 s stays within 10 rtol (measured
    4.4 rtol) and shrinks with the tolerance."""
    path = reference_fmus(version)["Dahlquist"]
    errors = {}
    for rtol in (1e-6, 1e-9):
        with me_slave(path, solver="CVode", relative_tolerance=rtol) as slave:
            x = step_through(slave, ["x"], 10.0, h=0.1)[:, 0]
        errors[rtol] = np.abs(x - np.exp(-0.1 * np.arange(101))).max()
    assert errors[1e-6] < 10 * 1e-6
    assert errors[1e-9] < errors[1e-6] / 100


def test_an_input_set_between_steps_is_seen_by_the_next_step():
    """StateSpace (FMI 3.0), x' = A x + B u with A = -I, B = I: each x relaxes to its u. The input changes at 1 s;
    the solution is exponential pieces, followed within CVode's tolerance (the solver restarts at the change)."""
    path = reference_fmus(3)["StateSpace"]
    minus_identity = (-np.eye(3)).ravel().tolist()
    with me_slave(path, solver="CVode", relative_tolerance=1e-8) as slave:
        slave.setFloat64([4], minus_identity)  # A, tunable: also between steps, here before the run
        u1, u2 = np.array([1.0, 2.0, 3.0]), np.array([-1.0, 0.0, 5.0])
        slave.setFloat64([9], u1.tolist())
        xs = []
        for k in range(200):
            if k == 100:
                slave.setFloat64([9], u2.tolist())
            assert slave.doStep(k * H, H) is False
            xs.append(slave.getFloat64([11], 3))
        y = slave.getFloat64([10], 3)
    t = (np.arange(200) + 1)[:, None] * H
    x1 = u1 * (1 - np.exp(-np.minimum(t, 1.0)))  # from x(0) = 0
    expected = np.where(t <= 1.0, x1, u2 + (x1 - u2) * np.exp(-(t - 1.0)))
    np.testing.assert_allclose(np.array(xs), expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(y, np.array(xs[-1]) + u2)  # y = C x + D u, C = D = I


@pytest.mark.parametrize("version", [2, 3])
def test_discrete_inputs_set_between_steps_go_through_event_mode(version):
    """Feedthrough refuses a discrete input in Continuous-Time Mode ("Variable Float64_discrete_input can only be
    set after instantiation, in initialization mode or event mode", and the instance is then unusable): the slave
    enters Event Mode before it sets a changed value, and iterates the event at the next doStep."""
    path = reference_fmus(version)["Feedthrough"]
    v = str(version) + ".0"
    with me_slave(path) as slave:
        var = slave.variables
        for k, value in enumerate((2.5, -4.0)):
            write_value(slave, v, var["Float64_discrete_input"], value)
            assert slave._mode == "event"
            write_value(slave, v, var["Float64_continuous_input"], 10 * value)
            write_value(slave, v, var["Int32_input"], k + 7)
            assert slave.doStep(k * H, H) is False
            assert slave._mode == "continuous"
            assert read_value(slave, v, var["Float64_discrete_output"]) == value
            assert read_value(slave, v, var["Float64_continuous_output"]) == 10 * value
            assert read_value(slave, v, var["Int32_output"]) == k + 7
        # the same value again is no event: nothing to re-initialise
        write_value(slave, v, var["Float64_continuous_input"], -40.0)
        assert slave._mode == "continuous"


@pytest.mark.parametrize("version", [2, 3])
def test_a_failing_fmi_call_names_the_function_and_the_status(version):
    """Stair's counter can only be set before initialisation: FMPy's exception carries function and status, and
    the FMU's message reaches `log` (FMI 2.0 through cosim's process-wide logger, FMI 3.0 through logMessage)."""
    messages = []
    path = reference_fmus(version)["Stair"]
    with me_slave(path, log=lambda status, category, message: messages.append((status, message)),
                  terminate=False) as slave:
        counter = slave.variables["counter"]
        with pytest.raises(Exception) as failed:
            write_value(slave, f"{version}.0", counter, 5)
        assert failed.value.function == ("fmi2SetInteger" if version == 2 else "fmi3SetInt32")
        assert failed.value.status == 3
        assert any(status == 3 and b"counter" in message for status, message in messages)


def test_reset_starts_again_and_misuse_is_refused():
    path = reference_fmus(2)["BouncingBall"]
    with me_slave(path, **solver_options("CVode", 1.0)) as slave:
        first = step_through(slave, ["h", "v"], 1.0)
        with pytest.raises(SolverError) as wrong_time:
            slave.doStep(0.5, H)
        assert wrong_time.value.function == "doStep" and wrong_time.value.status == 3
        slave.reset()
        with pytest.raises(SolverError):
            slave.doStep(0.0, H)  # not initialised
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        np.testing.assert_array_equal(step_through(slave, ["h", "v"], 1.0), first)
    with me_slave(path, solver="CVode", max_step=1e-6) as slave:  # > 500 steps to the communication point
        with pytest.raises(SolverError, match="CVode failed at t=0 s") as too_much_work:
            slave.doStep(0.0, H)
        assert too_much_work.value.function == "CVode" and too_much_work.value.status == 3
    with pytest.raises(ValueError, match="solver"):
        ModelExchangeSlave("guid", ".", "model", "test", fmi_version="2.0", model_description=None, solver="RK4")


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
@pytest.mark.parametrize("version", [2, 3])
def test_ten_seconds_of_van_der_pol_take_well_under_a_second(version, solver):
    path = reference_fmus(version)["VanDerPol"]
    with me_slave(path, solver=solver) as slave:
        get, vr = (slave.getReal if version == 2 else slave.getFloat64), [slave.variables["x0"].valueReference]
        begin = time.perf_counter()
        for k in range(1000):
            slave.doStep(k * H, H)
            get(vr)
        elapsed = time.perf_counter() - begin
        assert math.isclose(slave.time, 10.0)
    assert elapsed < 0.5, f"{elapsed:.3f} s"
