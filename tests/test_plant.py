"""FmuPlant and simulate: discovery, settings, life cycle, errors; an FMU exported by pythonfmu."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cosim import (
    CosimError,
    FmiCallError,
    FmuFormatError,
    FmuNotFoundError,
    FmuPlant,
    FmuPlatformError,
    InvalidSettingError,
    UnknownVariableError,
    build_fmu,
    simulate,
)

DT = 1 / 2257


def test_discovers_inputs_outputs_states_parameters(fmu):
    with FmuPlant(fmu, dt=DT) as plant:
        assert plant.inputs == ("Tm", "TL")
        assert plant.outputs == ("theta_m", "omega_m", "theta_L", "omega_L")
        assert plant.states == plant.outputs
        params = plant.parameters
        assert params["Jm"] == 250.0 and params["KL"] == 2.5e6 and params["Fc"] == 0.0
        assert isinstance(params["nsub"], int)


def test_parameters_and_start_values_are_applied(fmu):
    with FmuPlant(fmu, dt=DT, parameters={"Jm": 400.0}, start={"theta_m": -2.0, "omega_L": 1.0}) as plant:
        assert plant.parameters["Jm"] == 400.0
        np.testing.assert_allclose(plant.read_outputs(), [-2.0, 0.0, 0.0, 1.0])


def test_step_advances_time_and_is_reproducible_after_reset(fmu):
    with FmuPlant(fmu, dt=DT, start={"omega_L": 0.5}) as plant:
        first = np.array([plant.step([100.0, 0.0]) for _ in range(50)])
        assert math.isclose(plant.time, 50 * DT, rel_tol=1e-15)
        plant.reset()
        assert plant.time == 0.0
        again = np.array([plant.step([100.0, 0.0]) for _ in range(50)])
    np.testing.assert_array_equal(first, again)


def test_reset_with_new_parameters_changes_the_response(fmu):
    with FmuPlant(fmu, dt=DT) as plant:
        free = plant.run(np.tile([1000.0, 0.0], (200, 1)))
        plant.reset(parameters={"Fc": 500.0})
        assert plant.parameters["Fc"] == 500.0
        braked = plant.run(np.tile([1000.0, 0.0], (200, 1)))
    assert braked[-1, 1] < 0.8 * free[-1, 1]  # Coulomb friction slows the motor


def test_step_of_a_closed_plant_is_refused_not_crashing(fmu):
    plant = FmuPlant(fmu, dt=DT)
    plant.close()
    plant.close()  # idempotent
    with pytest.raises(InvalidSettingError, match="closed"):
        plant.step([0.0, 0.0])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_step_refuses_a_nonfinite_input_naming_it_and_the_time(fmu, bad):
    with FmuPlant(fmu, dt=DT) as plant:
        plant.step([1.0, 0.0])
        with pytest.raises(InvalidSettingError, match=rf"^step\(\) input TL is {bad} at t={DT:.9g} s; inputs must "
                                                      r"be finite numbers"):
            plant.step([0.0, bad])
        assert plant.time == pytest.approx(DT)  # nothing was passed on to the FMU
        with pytest.raises(FmiCallError, match="diverged"):  # finite, though their sum overflows: passed on
            plant.step([1e300, 1e300])


def test_simulate_returns_inputs_states_units_and_meta(fmu):
    traj = simulate(fmu, {"Tm": "square:amp=500,freq=2"}, duration=1.0, dt=1e-3, parameters={"Fc": 10.0})
    assert len(traj) == 1001
    # only the input driven is recorded; TL, which nobody drives, is left to the FMU and listed with its start value
    assert traj.inputs == ("Tm",) and traj.states == ("theta_m", "omega_m", "theta_L", "omega_L")
    assert set(np.unique(traj["Tm"])) == {-500.0, 500.0}  # 10 % of the declared max torque 5000 N m
    assert traj.meta["left_inputs"] == {"TL": 0.0}
    assert traj.units[traj.names.index("omega_m")] == "rad/s"
    assert traj.meta["parameters"]["Fc"] == 10.0 and traj.meta["dt"] == 1e-3
    np.testing.assert_allclose(np.diff(traj.time), 1e-3, rtol=1e-9)


# ---------------------------------------------------------------------- bad input, each with a clear error
def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and len(text) < 400, text
    return text


def test_missing_path(tmp_path):
    with pytest.raises(FmuNotFoundError) as err:
        FmuPlant(tmp_path / "nope.fmu", dt=DT)
    assert "not found" in one_line(err.value) and isinstance(err.value, FileNotFoundError)


def test_not_a_zip(tmp_path):
    path = tmp_path / "text.fmu"
    path.write_text("hello")
    with pytest.raises(FmuFormatError, match="not a zip"):
        FmuPlant(path, dt=DT)


def test_zip_without_model_description(tmp_path):
    path = tmp_path / "empty.fmu"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("readme.txt", "no model here")
    with pytest.raises(FmuFormatError, match="modelDescription.xml"):
        FmuPlant(path, dt=DT)


def rewrite_fmu(src: Path, dst: Path, *, drop_prefix: str | None = None, edit=None) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            if drop_prefix and item.filename.startswith(drop_prefix):
                continue
            data = zin.read(item.filename)
            if edit and item.filename == "modelDescription.xml":
                data = edit(data.decode()).encode()
            zout.writestr(item, data)
    return dst


def test_fmu_with_only_scheduled_execution_says_so(tmp_path):
    import re

    def to_other(xml: str) -> str:
        return re.sub(r"<CoSimulation\b", "<ScheduledExecution", xml).replace("</CoSimulation>",
                                                                           "</ScheduledExecution>")

    path = rewrite_fmu(build_fmu(fmi_version="3.0"), tmp_path / "other.fmu", edit=to_other)
    with pytest.raises(FmuFormatError, match="has neither a co-simulation nor a Model Exchange interface "
                                             r"\(only Scheduled Execution\)"):
        FmuPlant(path, dt=DT)


def test_kind_me_on_a_cosimulation_only_fmu_says_what_it_has(fmu):
    with pytest.raises(FmuFormatError, match=r"has no Model Exchange interface \(it has co-simulation\); "
                                             "use --kind cs"):
        FmuPlant(fmu, dt=DT, kind="me")


def test_fmu_without_binary_for_this_platform(fmu, tmp_path):
    path = rewrite_fmu(fmu, tmp_path / "nobin.fmu", drop_prefix="binaries/")
    with pytest.raises(FmuPlatformError, match="no binary for this platform"):
        FmuPlant(path, dt=DT)


@pytest.mark.parametrize("kwargs,match", [
    ({"parameters": {"Jmm": 1.0}}, "Jm"),          # suggests the near name
    ({"parameters": {"theta_m": 1.0}}, "not a parameter"),
    ({"start": {"nothing": 1.0}}, "no variable named"),
    ({"inputs": ["Tq"]}, "no input named"),
])
def test_unknown_names(fmu, kwargs, match):
    with pytest.raises(UnknownVariableError, match=match) as err:
        FmuPlant(fmu, dt=DT, **kwargs)
    one_line(err.value)


@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan"), "abc"])
def test_non_positive_step(fmu, dt):
    with pytest.raises(InvalidSettingError, match="step size"):
        FmuPlant(fmu, dt=dt)


def test_bad_parameter_values(fmu):
    with pytest.raises(InvalidSettingError, match="whole number"):
        FmuPlant(fmu, dt=DT, parameters={"nsub": 2.5})
    with pytest.raises(InvalidSettingError, match="finite"):
        FmuPlant(fmu, dt=DT, parameters={"Jm": float("inf")})


def test_fmu_rejects_unphysical_parameter_at_initialisation(fmu):
    with pytest.raises(FmiCallError) as err:
        FmuPlant(fmu, dt=DT, parameters={"Jm": -1.0})
    assert "Jm" in one_line(err.value)


def test_wrong_number_of_inputs(fmu):
    with FmuPlant(fmu, dt=DT) as plant, pytest.raises(InvalidSettingError, match="expected 2"):
        plant.step([1.0])


@pytest.mark.parametrize("fmi_version", ["2.0", "3.0"])
def test_error_status_mid_run_reports_time_and_function(fmi_version):
    # negative damping makes the plant diverge; the FMU returns an error once a state passes 1e12
    with FmuPlant(build_fmu(fmi_version=fmi_version), dt=DT, parameters={"Bm": -2e5},
                  start={"omega_m": 1.0}) as plant:
        with pytest.raises(FmiCallError) as err:
            for _ in range(100_000):
                plant.step([0.0, 0.0])
        exc = err.value
        assert exc.function == f"fmi{fmi_version[0]}DoStep" and exc.status == 3
        assert 0 < exc.time < 100_000 * DT
        assert exc.time == pytest.approx(plant.time, abs=1e-12)  # the failing step started where the plant is
        assert f"{exc.time:.9g}" in one_line(exc)
        assert "diverg" in str(exc)  # the FMU's own log message is attached


def test_instance_is_freed_and_files_removed_also_on_error(fmu):
    with pytest.raises(FmiCallError):
        with FmuPlant(fmu, dt=DT, parameters={"Bm": -2e5}, start={"omega_m": 1.0}) as plant:
            unzipped = Path(plant._unzipdir)
            assert unzipped.is_dir()
            for _ in range(100_000):
                plant.step([0.0, 0.0])
    assert plant._fmu is None and not unzipped.exists()


def test_fmi3_build_runs_through_the_same_api():
    with FmuPlant(build_fmu(fmi_version="3.0"), dt=DT, start={"omega_L": 1.0}) as plant:
        assert plant.fmi_version == "3.0" and plant.states == plant.outputs
        y = plant.run(np.zeros((100, 2)))
    assert y[-1, 2] > 0 and abs(plant.time - 100 * DT) < 1e-12


@pytest.mark.parametrize("kwargs,match", [
    ({"duration": 1.0, "dt": 0.3}, "whole number of steps"),
    ({"duration": -1.0, "dt": 0.1}, "positive"),
])
def test_simulate_bad_duration(fmu, kwargs, match):
    with pytest.raises(InvalidSettingError, match=match):
        simulate(fmu, {}, **kwargs)


def test_simulate_unknown_input(fmu):
    with pytest.raises(UnknownVariableError, match="Tq"):
        simulate(fmu, {"Tq": 1.0}, duration=0.1, dt=0.01)


def test_every_error_is_a_cosim_error():
    for cls in (FmiCallError, FmuFormatError, FmuNotFoundError, FmuPlatformError, InvalidSettingError,
                UnknownVariableError):
        assert issubclass(cls, CosimError)


# ---------------------------------------------------------------------- an FMU this project did not write
PYTHONFMU_SOURCE = textwrap.dedent('''
    import math
    from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


    class FirstOrderLag(Fmi2Slave):
        """y' = (u - y) / tau, integrated exactly over each step for a held input."""

        author = "cosim tests"
        description = "first-order lag"

        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.u = 0.0
            self.y = 0.0
            self.tau = 0.5
            self.register_variable(Real("u", causality=Fmi2Causality.input))
            self.register_variable(Real("y", causality=Fmi2Causality.output))
            self.register_variable(Real("tau", causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))

        def do_step(self, current_time, step_size):
            a = math.exp(-step_size / self.tau)
            self.y = a * self.y + (1.0 - a) * self.u
            return True
''')


@pytest.fixture(scope="module")
def pythonfmu_fmu(tmp_path_factory):
    pytest.importorskip("pythonfmu")
    folder = tmp_path_factory.mktemp("pythonfmu")
    script = folder / "FirstOrderLag.py"
    script.write_text(PYTHONFMU_SOURCE)
    exe = shutil.which("pythonfmu") or sys.executable
    cmd = [exe, "build", "-f", str(script), "-d", str(folder)]
    if exe == sys.executable:
        cmd = [exe, "-m", "pythonfmu", "build", "-f", str(script), "-d", str(folder)]
    subprocess.run(cmd, check=True, capture_output=True)
    return folder / "FirstOrderLag.fmu"


def test_foreign_fmu_through_fmuplant(pythonfmu_fmu):
    tau, dt = 0.2, 0.01
    with FmuPlant(pythonfmu_fmu, dt=dt, parameters={"tau": tau}) as plant:
        assert plant.inputs == ("u",) and plant.outputs == ("y",) and plant.states == ()
        y = [plant.step([1.0])[0] for _ in range(100)]
    expected = 1.0 - np.exp(-dt * np.arange(1, 101) / tau)
    np.testing.assert_allclose(y, expected, rtol=1e-12)


def test_foreign_fmu_through_simulate(pythonfmu_fmu):
    traj = simulate(pythonfmu_fmu, {"u": "step:value=2,at=0.5"}, duration=1.0, dt=0.01, parameters={"tau": 0.1})
    y, t = traj["y"], traj.time
    assert np.all(y[t <= 0.5 + 1e-9] == 0.0)
    np.testing.assert_allclose(y[-1], 2.0 * (1 - np.exp(-0.5 / 0.1)), rtol=1e-12)
    assert traj.outputs == ("y",)


def test_example_closed_loop_asserts_its_result():
    import runpy

    figures = runpy.run_path(str(Path(__file__).parents[1] / "examples" / "closed_loop_pd.py"))["main"]()
    assert figures["settling_time_2pct_s"] < 1.0


def test_fmu_messages_after_a_plant_is_gone_do_not_crash():
    """FMPy's C logger proxy is process-wide: a freed plant must not leave it pointing at a dead callback."""
    script = textwrap.dedent("""
        import gc, fmpy
        from cosim import build_fmu, simulate
        fmu = build_fmu()
        simulate(fmu, {"Tm": 1.0}, duration=0.01, dt=1e-3)
        gc.collect()
        try:
            fmpy.simulate_fmu(str(fmu), start_values={"Jm": 0.0}, stop_time=0.01)  # logs an error message
        except Exception:
            pass
        print("survived")
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "survived" in proc.stdout, proc.stderr[-500:]


def test_each_plant_gets_its_own_fmu_messages(fmu):
    with FmuPlant(fmu, dt=DT) as good, FmuPlant(fmu, dt=DT, parameters={"Bm": -2e5},
                                                start={"omega_m": 1.0}) as bad:
        with pytest.raises(FmiCallError, match="diverged"):
            for _ in range(100_000):
                good.step([0.0, 0.0])
                bad.step([0.0, 0.0])
        assert not any("diverged" in m for m in good._messages)


def test_any_float_variable_can_be_recorded_not_only_outputs(fmu):
    """Issue 15: a state or local variable the FMU does not declare as an output (here the derivatives)."""
    traj = simulate(fmu, {"Tm": 1000.0}, duration=0.01, dt=1e-3, outputs=["omega_m", "der_theta_m", "der_omega_m"])
    assert traj.names == ("Tm", "omega_m", "der_theta_m", "der_omega_m")
    np.testing.assert_array_equal(traj["der_theta_m"], traj["omega_m"])  # theta_m' = omega_m, at every sample
    assert np.all(traj["der_omega_m"][1:] > 0)  # a positive torque from rest accelerates the motor
    every = simulate(fmu, {"Tm": 1000.0}, duration=0.01, dt=1e-3, outputs="all")
    assert {"theta_L", "der_omega_L", "KL"} <= set(every.names) and "time" not in every.names
    assert simulate(fmu, duration=0.01, dt=1e-3).names == ("theta_m", "omega_m", "theta_L", "omega_L")
    with pytest.raises(UnknownVariableError, match="has no variable named 'der_omega_x'"):
        FmuPlant(fmu, dt=1e-3, outputs=["der_omega_x"])


def test_plants_opened_at_once_in_threads_leave_the_working_directory_alone(fmu, tmp_path, monkeypatch):
    # FMPy loads a library with os.chdir there and back; unserialised, plants loading at once in a Dask worker's
    # threads left the process in another plant's deleted temporary folder (the README's Monte Carlo on a
    # threaded worker failed 39 of 50 cases, and the next command could not find its files)
    from concurrent.futures import ThreadPoolExecutor

    monkeypatch.chdir(tmp_path)

    def run(k: int) -> float:
        with FmuPlant(fmu, dt=1e-3, parameters={"Fc": 0.0}, instance_name=f"p{k}") as plant:
            return float(plant.step([100.0 + k, 0.0])[1])

    with ThreadPoolExecutor(max_workers=16) as pool:
        speeds = list(pool.map(run, range(80)))
    assert Path.cwd() == tmp_path
    assert speeds == [run(k) for k in range(80)]  # every plant loaded and stepped as it does alone


@pytest.mark.parametrize("fmi_version", ["2.0", "3.0"])
def test_the_c_step_gives_the_python_steps_bits(fmi_version, monkeypatch):
    """FmuPlant's step and run through the system master's C loop (one ctypes call a step, one a run) against its
    Python step (three ctypes calls a step): the same outputs to the bit, the same time after."""
    from cosim.plant import _system_engine

    rng = np.random.default_rng(3)
    u = np.c_[rng.normal(0.0, 500.0, 400), rng.normal(0.0, 50.0, 400)]
    parameters = {"Fc": 30.0, "Tcog": 5.0, "ncog": 12, "backlash": 1e-4, "delay": 0.0015}
    results = []
    for python in (False, True):
        if python:
            monkeypatch.setattr(_system_engine, "single_loop", lambda plant: None)
        with FmuPlant(build_fmu(fmi_version=fmi_version), dt=1e-3, parameters=parameters) as plant:
            assert (plant._loop is None) == python
            stepped = np.array([plant.step(row) for row in u[:200]])
            ran = plant.run(u[200:])
            results.append((stepped, ran, plant.time))
    assert np.array_equal(results[0][0], results[1][0]) and np.array_equal(results[0][1], results[1][1])
    assert results[0][2] == results[1][2] == pytest.approx(0.4)
