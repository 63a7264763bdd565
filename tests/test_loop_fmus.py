"""Issue 40: the test FMUs of an algebraic loop, checked on their own (the master that solves the loop is tested
elsewhere; :func:`loop_fmus` builds the FMUs for those tests).

Three Co-Simulation FMUs in C (tests/fmus/loop/, FMI 2.0 and 3.0, built by `build_fmu(source=...)`), each with an output
that depends directly on its input, so that wiring ``a.y -> b.u`` and ``b.y -> a.u`` closes an algebraic loop:

* ``loop_a``: ``y = ka*u + x`` with the state ``der(x) = (u - x)/tau``, stepped exactly for a held input
  (defaults ka = 0.5, tau = 0.2, x0 = 1);
* ``loop_b``: ``y = kb*u + c*sin(w*t)`` at the FMU's time t (defaults kb = -0.8, c = 0.3, w = 2);
* ``loop_b_nostate``: ``loop_b`` that cannot save its state (canGetAndSetFMUstate false).

At a time t the loop's consistent output is ``y_a = (ka*c*sin(w*t) + x)/(1 - ka*kb)`` (1 - ka*kb = 1.4). A master
iterates at a communication point by setting an input and reading the output at once, without a step, and by
saving and restoring the FMUs' states: both are checked here on the real FMUs, against the equations above.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

import cosim
from cosim.plant.build import build_fmu

SOURCES = Path(__file__).parent / "fmus" / "loop"  # the three folders share its fmi2.c and fmi3.c
NAMES = ("loop_a", "loop_b", "loop_b_nostate")
KA, TAU, X0 = 0.5, 0.2, 1.0  # loop_a's defaults
KB, C, W = -0.8, 0.3, 2.0  # loop_b's defaults
VR_TIME, VR_U, VR_Y, VR_X = 0, 1, 2, 3  # value references (VR_X: loop_a only)


def loop_fmus(fmi_version: str = "2.0") -> dict[str, Path]:
    """The three loop test FMUs (``loop_a``, ``loop_b``, ``loop_b_nostate``) built for `fmi_version`, by name.

    Built once from tests/fmus/loop/<name> and cached on disk by :func:`cosim.plant.build.build_fmu`, later calls
    return the cached files. For tests of a master solving the loop: ``from test_loop_fmus import loop_fmus``.
    """
    return {name: build_fmu(source=SOURCES / name, fmi_version=fmi_version) for name in NAMES}


@pytest.fixture(scope="module")
def built() -> dict[int, dict[str, Path]]:
    return {v: loop_fmus(f"{v}.0") for v in (2, 3)}


def _b(u: float, t: float) -> float:
    return KB * u + C * math.sin(W * t)


def _state_functions(fmu, version: int):
    """fmpy's get/set/free FMU state of a slave, by FMI version's names."""
    if version == 2:
        return fmu.getFMUstate, fmu.setFMUstate, fmu.freeFMUstate
    return fmu.getFMUState, fmu.setFMUState, fmu.freeFMUState


def _io(fmu, version: int):
    """fmpy's get and set of Float64 (FMI 3) / Real (FMI 2) values of a slave."""
    return (fmu.getReal, fmu.setReal) if version == 2 else (fmu.getFloat64, fmu.setFloat64)


# ---------------------------------------------------------------------------------------------------------------
# the FMUs and their model descriptions


@pytest.mark.parametrize("version", [2, 3])
def test_each_builds_validates_and_declares_its_feedthrough(built, version):
    """fmpy's validation finds no problem; Co-Simulation only, variable steps, FMU state as declared; the output
    `y` depends on the input `u` (and on x, or on time) in ModelStructure, which a master reads to find the loop."""
    for name, path in built[version].items():
        assert path.name == f"{name}.fmu" and path.is_file()
        assert validate_fmu(str(path)) == [], name
        md = fmpy.read_model_description(str(path))
        assert md.fmiVersion == f"{version}.0" and md.modelExchange is None, name
        cs = md.coSimulation
        assert cs.modelIdentifier == name and cs.canHandleVariableCommunicationStepSize, name
        assert cs.canGetAndSetFMUstate is (name != "loop_b_nostate"), name
        [out] = md.outputs
        assert out.variable.name == "y", name
        expected = {"u", "x"} if name == "loop_a" else {"time", "u"}
        assert {d.name for d in out.dependencies} == expected, name
        assert [v.name for v in md.modelVariables if v.causality == "input"] == ["u"], name


# ---------------------------------------------------------------------------------------------------------------
# direct feedthrough: the output for a new input at once, in step mode and in initialisation mode


@pytest.mark.parametrize("version", [2, 3])
def test_loop_a_passes_a_new_input_through_at_once_and_keeps_its_state(built, version):
    """set_inputs([v]) then read_outputs() gives ka*v + x before and after steps; setting u never moves x."""
    dt = 0.05
    with cosim.FmuPlant(built[version]["loop_a"], dt=dt) as plant:
        assert plant.inputs == ("u",) and plant.outputs == ("y",)
        assert plant.read_outputs()[0] == pytest.approx(X0, abs=1e-15)  # u starts at 0
        x = X0
        for k, u in enumerate([0.7, -2.0, 3.5, 0.0, 1.25]):
            for v in (4.0, -1.5, u):  # a master trying values at one communication point: u is the last
                plant.set_inputs([v])
                assert plant.read_outputs()[0] == pytest.approx(KA * v + x, abs=1e-14), (k, v)
                assert plant.get(["x"])[0] == pytest.approx(x, abs=1e-15), (k, v)
            y = plant.step([u])[0]
            x = u + (x - u) * math.exp(-dt / TAU)
            assert plant.time == pytest.approx((k + 1) * dt, abs=1e-15)
            assert y == pytest.approx(KA * u + x, abs=1e-14), k  # after the step, for the input held over it


@pytest.mark.parametrize("name", ["loop_b", "loop_b_nostate"])
@pytest.mark.parametrize("version", [2, 3])
def test_loop_b_passes_a_new_input_through_at_its_time(built, version, name):
    """set_inputs([v]) then read_outputs() gives kb*v + c*sin(w*t), t the start time after initialisation and the
    step's end after a step; parameters set before initialisation count."""
    dt, t0 = 0.1, 0.4
    with cosim.FmuPlant(built[version][name], dt=dt, t0=t0) as plant:
        assert plant.inputs == ("u",) and plant.outputs == ("y",)
        assert plant.read_outputs()[0] == pytest.approx(_b(0.0, t0), abs=1e-15)
        for k, u in enumerate([1.0, -0.5, 2.5, 0.3]):
            t = t0 + k * dt
            for v in (3.0, -2.0, u):
                plant.set_inputs([v])
                assert plant.read_outputs()[0] == pytest.approx(_b(v, t), abs=1e-14), (k, v)
            y = plant.step([u])[0]
            assert y == pytest.approx(_b(u, t + dt), abs=1e-14), k
    with cosim.FmuPlant(built[version][name], dt=dt, parameters={"kb": 0.6, "c": -1.1, "w": 5.0}) as plant:
        plant.set_inputs([2.0])
        plant.step([2.0])
        plant.set_inputs([-1.0])
        assert plant.read_outputs()[0] == pytest.approx(0.6 * -1.0 - 1.1 * math.sin(5.0 * dt), abs=1e-14)


@pytest.mark.parametrize("version", [2, 3])
def test_feedthrough_in_initialisation_mode(built, version, tmp_path):
    """Between Enter- and ExitInitializationMode too, reading y after setting u gives the output for the new u
    (loop_a: with the start value of x set there; loop_b: at the start time)."""
    t0 = 0.3
    for name, x0 in (("loop_a", -0.6), ("loop_b", None)):
        path = built[version][name]
        md = fmpy.read_model_description(str(path))
        common = dict(guid=md.guid, unzipDirectory=fmpy.extract(str(path), unzipdir=tmp_path / f"{name}{version}"),
                      modelIdentifier=name, instanceName=name)
        fmu = fmpy.fmi2.FMU2Slave(**common) if version == 2 else fmpy.fmi3.FMU3Slave(**common)
        get, put = _io(fmu, version)
        fmu.instantiate()
        try:
            if version == 2:
                fmu.setupExperiment(startTime=t0)
                fmu.enterInitializationMode()
            else:
                fmu.enterInitializationMode(startTime=t0)
            if x0 is not None:
                put([VR_X], [x0])
            for v in (1.5, -4.0, 0.25):
                put([VR_U], [v])
                expected = KA * v + x0 if name == "loop_a" else _b(v, t0)
                assert get([VR_Y])[0] == pytest.approx(expected, abs=1e-14), (name, v)
            assert get([VR_TIME])[0] == t0
            fmu.exitInitializationMode()
            expected = KA * 0.25 + x0 if name == "loop_a" else _b(0.25, t0)
            assert get([VR_Y])[0] == pytest.approx(expected, abs=1e-14), name
            fmu.terminate()
        finally:
            fmu.freeInstance()


# ---------------------------------------------------------------------------------------------------------------
# the state of loop_a, and the loop's consistent values


@pytest.mark.parametrize("version", [2, 3])
def test_loop_a_state_follows_the_exact_exponential(built, version):
    """Over 10 steps of a held u, x(t) = u + (x0 - u)*exp(-t/tau) to rounding, with parameters and x0 set."""
    ka, tau, x0, u, dt = 0.7, 0.3, -0.4, 1.5, 0.05
    with cosim.FmuPlant(built[version]["loop_a"], dt=dt, parameters={"ka": ka, "tau": tau}, start={"x": x0},
                        outputs=["y", "x"]) as plant:
        assert plant.states == ("x",)  # der(x) declares x a state
        assert plant.read_outputs()[1] == x0
        y = plant.run(np.full((10, 1), u))
    t = dt * np.arange(1, 11)
    x = u + (x0 - u) * np.exp(-t / tau)
    np.testing.assert_allclose(y[:, 1], x, rtol=0, atol=1e-14)
    np.testing.assert_allclose(y[:, 0], ka * u + x, rtol=0, atol=1e-14)
    assert abs(y[-1, 1] - u) < 0.2 * abs(x0 - u)  # it moved: 10 steps are 1.7 time constants, exp(-1.7) = 0.19


@pytest.mark.parametrize("version", [2, 3])
def test_wired_as_a_loop_the_fmus_reach_the_consistent_values(built, version):
    """Gauss-Seidel at each communication point through set_inputs/read_outputs (no step) converges to
    y_a = (ka*c*sin(w*t) + x)/(1 - ka*kb); stepping with those inputs, x follows an independent solution."""
    dt = 0.1
    with (cosim.FmuPlant(built[version]["loop_a"], dt=dt) as a,
          cosim.FmuPlant(built[version]["loop_b"], dt=dt) as b):
        x_ref = X0
        for k in range(5):
            t = k * dt
            ya = a.read_outputs()[0]
            for _ in range(60):  # contraction |ka*kb| = 0.4: 1e-16 well within 60 sweeps
                b.set_inputs([ya])
                yb = b.read_outputs()[0]
                a.set_inputs([yb])
                ya = a.read_outputs()[0]
            consistent = (KA * C * math.sin(W * t) + x_ref) / (1.0 - KA * KB)
            assert ya == pytest.approx(consistent, abs=1e-12), k
            assert yb == pytest.approx(KB * ya + C * math.sin(W * t), abs=1e-12), k
            a.step([yb])
            b.step([ya])
            x_ref = yb + (x_ref - yb) * math.exp(-dt / TAU)  # a's input held over the step
            assert a.get(["x"])[0] == pytest.approx(x_ref, abs=1e-12), k


# ---------------------------------------------------------------------------------------------------------------
# saving and restoring the FMU state


@pytest.mark.parametrize("name", ["loop_a", "loop_b"])
@pytest.mark.parametrize("version", [2, 3])
def test_fmu_state_round_trips(built, version, name):
    """Save the state, take 5 steps, restore it, take the same 5 steps: the same outputs, bit for bit. The restored
    state holds the time, x and the input last set (y reads as it did when saved, before any input is set)."""
    dt = 0.05
    with cosim.FmuPlant(built[version][name], dt=dt) as plant:
        for u in (0.4, -1.2, 2.0):
            plant.step([u])
        plant.set_inputs([0.9])
        fmu = plant._fmu
        get_state, set_state, free_state = _state_functions(fmu, version)
        get, put = _io(fmu, version)
        t_saved = plant.time
        y_saved = get([VR_Y])[0]
        state = get_state()
        try:
            runs = []
            for _ in range(2):
                assert get([VR_TIME])[0] == pytest.approx(t_saved, abs=1e-15)
                assert get([VR_Y])[0] == y_saved  # the saved input and state, before any input is set
                ys = []
                for k, u in enumerate([1.0, -0.3, 0.8, 2.2, -1.7]):
                    put([VR_U], [u])
                    fmu.doStep(currentCommunicationPoint=t_saved + k * dt, communicationStepSize=dt)
                    ys.append(get([VR_Y, VR_TIME]))
                runs.append(np.array(ys))
                assert get([VR_Y])[0] != y_saved
                set_state(state)
        finally:
            free_state(state)
        np.testing.assert_array_equal(runs[0], runs[1])
        np.testing.assert_allclose(runs[0][:, 1], t_saved + dt * np.arange(1, 6), rtol=0, atol=1e-14)


@pytest.mark.parametrize("version", [2, 3])
def test_loop_b_nostate_cannot_save_its_state(built, version, caplog):
    """Its getFMUstate fails with an FMI error (and says why in its log); it steps as loop_b does after."""
    with cosim.FmuPlant(built[version]["loop_b_nostate"], dt=0.1) as plant:
        get_state, set_state, _ = _state_functions(plant._fmu, version)
        function = "fmi2GetFMUstate" if version == 2 else "fmi3GetFMUState"
        with caplog.at_level(logging.ERROR, logger="cosim.fmu"), pytest.raises(FMICallException) as failed:
            get_state()
        assert failed.value.function == function and failed.value.status == 3  # fmiError
        assert "cannot save and restore its state" in caplog.text and function in caplog.text
        assert plant.step([1.0])[0] == pytest.approx(_b(1.0, 0.1), abs=1e-14)
