"""cosim as an importer of FMUs nobody here wrote: the Modelica Association's Reference FMUs, FMI 2.0 and 3.0,
built from ../shared/fmus/reference-fmus by tests/reference_fmus.py, each run through `cosim.simulate` (FmuPlant)
and `cosim simulate` / `cosim fmu info`, and compared with `fmpy.simulate_fmu` on the same output grid.

Float64 outputs must agree within 1e-12, integer and Boolean ones exactly; both importers drive the same binary
with the same communication steps, so any difference is the importer's.
"""

from __future__ import annotations

import json

import fmpy
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from reference_fmus import reference_fmus

import cosim
from cosim.cli import main as cli
from cosim.errors import CosimError, InvalidSettingError, UnknownVariableError

# name -> (duration, communication step): long enough to cross the FMU's events (bounces, stair steps, its end)
CASES = {"BouncingBall": (3.0, 0.01), "Dahlquist": (10.0, 0.1), "VanDerPol": (20.0, 0.01),
         "Feedthrough": (2.0, 0.1), "Resource": (2.0, 0.1), "Stair": (15.0, 0.1), "Roberts": (0.01, 1e-4)}
RUNS = [(version, name) for version in (2, 3) for name in CASES if name != "Roberts" or version == 3]


@pytest.fixture(scope="module")
def ref():
    return {2: reference_fmus(2), 3: reference_fmus(3)}


def _fmpy(path, names, t0, duration, dt, **kw):
    return fmpy.simulate_fmu(str(path), start_time=t0, stop_time=t0 + duration, output_interval=dt, output=names,
                             **kw)


def _assert_same(ours: dict, theirs, types: dict) -> None:
    """Float columns within 1e-12, integer and Boolean columns exactly."""
    for name, values in ours.items():
        expected = np.asarray(theirs[name], dtype=float)
        if types.get(name, "Float64") in ("Float64", "Real", "Float32"):
            np.testing.assert_allclose(values, expected, rtol=1e-12, atol=1e-12, err_msg=name)
        else:
            np.testing.assert_array_equal(values, expected, err_msg=name)


@pytest.mark.parametrize(("version", "name"), RUNS, ids=[f"fmi{v}-{n}" for v, n in RUNS])
def test_outputs_equal_fmpys(ref, tmp_path, version, name):
    """The API and the CLI give fmpy's outputs on fmpy's grid; `fmu info --json` lists the FMU's outputs."""
    path = ref[version][name]
    duration, dt = CASES[name]
    traj = cosim.simulate(path, duration=duration, dt=dt)
    outputs = [n for n, role in zip(traj.names, traj.roles, strict=True) if role != "input"]
    theirs = _fmpy(path, outputs, traj.time[0], duration, dt)
    assert len(theirs) == len(traj)
    np.testing.assert_allclose(traj.time, theirs["time"], rtol=1e-12, atol=1e-12)
    types = traj.meta.get("types", {})
    _assert_same({n: traj[n] for n in outputs}, theirs, types)

    runner = CliRunner()
    info = runner.invoke(cli, ["fmu", "info", str(path), "--json"])
    assert info.exit_code == 0, info.output
    listed = json.loads(info.output)["outputs"]
    assert [v["name"] for v in listed if v["type"] not in ("String", "Binary")] == outputs
    csv = tmp_path / "run.csv"
    done = runner.invoke(cli, ["simulate", str(path), "--duration", repr(duration), "--dt", repr(dt), "-o", str(csv),
                               "--json"])
    assert done.exit_code == 0, done.output
    table = pd.read_csv(csv)  # a plain CSV: integer columns read back as integers
    np.testing.assert_allclose(table["time"], theirs["time"], rtol=1e-12, atol=1e-12)
    _assert_same({n: table[n].to_numpy(dtype=float) for n in outputs}, theirs, types)
    for column, fmi_type in types.items():
        assert pd.api.types.is_integer_dtype(table[column]) == (fmi_type != "Float32"), (column, fmi_type)


def test_an_fmu_that_ends_the_simulation_keeps_its_data(ref, tmp_path):
    """Stair ends the run at t = 9 s (its counter at 10): asked for 15 s, cosim keeps and writes everything up to
    9 s, as fmpy shows it, says status terminated and exits 0."""
    for version in (2, 3):
        path = ref[version]["Stair"]
        csv = tmp_path / f"stair{version}.csv"
        done = CliRunner().invoke(cli, ["simulate", str(path), "--duration", "15", "--dt", "0.1", "-o", str(csv),
                                        "--json"])
        assert done.exit_code == 0, done.output
        summary = json.loads(done.output)
        assert summary["status"] == "terminated" and summary["terminated"]["time"] == pytest.approx(9.0)
        table = pd.read_csv(csv)
        theirs = _fmpy(path, ["counter"], 0.0, 15.0, 0.1)
        np.testing.assert_allclose(table["time"], theirs["time"], atol=1e-12)
        np.testing.assert_array_equal(table["counter"], theirs["counter"])
        assert table["time"].iloc[-1] == pytest.approx(9.0) and table["counter"].iloc[-1] == 10
        text = CliRunner().invoke(cli, ["simulate", str(path), "--duration", "15", "--dt", "0.1"]).output
        assert "ended the simulation at t=9 s" in text
    with cosim.FmuPlant(ref[3]["Stair"], dt=1.0) as plant:
        with pytest.raises(cosim.SimulationTerminated) as ended:
            for _ in range(15):
                plant.step([])
        assert ended.value.time == pytest.approx(9.0) and ended.value.outputs.tolist() == [10.0]
        with pytest.raises(cosim.SimulationTerminated, match="reset"):
            plant.step([])
        assert plant.time == 9.0
        # (plant.reset() would not run Stair again: the Reference FMUs' reset() leaves terminateSimulation set)


# one value per type that a float carries exactly, at the ends of each type's range
TYPE_VALUES = {"Float32": [0.5, -1.25, 2.0**100], "Float64": [1.0e-300, -2.5, 7.0], "Int8": [-128, 0, 127],
               "UInt8": [0, 255, 7], "Int16": [-32768, 32767, 1], "UInt16": [65535, 0, 2],
               "Int32": [-2**31, 2**31 - 1, 3],
               "UInt32": [2**32 - 1, 0, 4], "Int64": [-2**53, 2**53, 5], "UInt64": [2**53, 0, 6],
               "Integer": [-2**31, 2**31 - 1, 3], "Real": [1.0e-300, -2.5, 7.0], "Boolean": [1, 0, 1],
               "Enumeration": [1, 2, 1]}


@pytest.mark.parametrize("version", [2, 3])
def test_feedthrough_round_trips_every_type(ref, version):
    """Every numeric input of Feedthrough, driven through cosim, comes back on its output exactly; String and
    Binary values set as start values come back too; integer columns stay integers."""
    path = ref[version]["Feedthrough"]
    with cosim.FmuPlant(path, dt=0.1) as plant:
        types = {name: plant.variable(name).type for name in plant.inputs}
    inputs = {name: np.array(TYPE_VALUES[fmi_type] * 2, dtype=float) for name, fmi_type in types.items()}
    traj = cosim.simulate(path, inputs, duration=0.6, dt=0.1)
    for name in inputs:
        out = name.replace("_input", "_output")
        np.testing.assert_array_equal(traj[out][1:], traj[name][:-1], err_msg=name)  # held over a step, then out
        assert traj.meta.get("types", {}).get(out, "Real" if version == 2 else "Float64") == types[name]
    start = {"String_input": "héllo, wörld"} | ({"Binary_input": bytes([0, 1, 255])} if version == 3 else {})
    with cosim.FmuPlant(path, dt=0.1, start=start) as plant:
        plant.step([float(v) for v in plant.get(plant.inputs)])
        got = plant.get([name.replace("_input", "_output") for name in start])
    assert got == list(start.values())
    with pytest.raises(InvalidSettingError, match="UInt8_input is UInt8: 256 is outside 0..255"
                       if version == 3 else "Int32_input takes a whole number"):
        with cosim.FmuPlant(path, dt=0.1, start={"UInt8_input" if version == 3 else "Int32_input":
                                                 256 if version == 3 else 0.5}):
            pass


def test_statespace_with_a_set_a_matrix_is_control_forced_response(ref, tmp_path):
    """StateSpace (FMI 3 arrays) with A and B set from the CLI gives python-control's response of the same system,
    and its state x, a local variable recorded by name, python-control's states.

    The FMU's co-simulation integrates with forward Euler at a fixed 1 ms, so "the same system" is the discrete
    one Euler makes of it: x+ = (I + h A) x + h B u, y = C x + D u, h = 1 ms, simulated by
    ``control.forced_response`` and read at the 10 ms communication points.
    """
    import control

    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-6.0, -11.0, -6.0]])
    b = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.5]])
    csv = tmp_path / "ss.csv"
    done = CliRunner().invoke(cli, [
        "simulate", str(ref[3]["StateSpace"]), "--duration", "2", "--dt", "0.01", "--set", f"A={a.tolist()}",
        "--set", "B[2,2]=1", "--set", "B[1,1]=0", "--set", "B[3,3]=0.5", "--set", "B[3,1]=1",
        "--input", "u[1]=sine:value=1,freq=1", "--input", "u[2]=step:value=1,at=0.5",
        "--record", "y[1],y[2],y[3],x[1],x[2],x[3]", "-o", str(csv)])
    assert done.exit_code == 0, done.output
    table = pd.read_csv(csv)
    h, t = 1e-3, table["time"].to_numpy()
    # u[3], which nobody drives, is no column: an element of a partly driven array, it keeps its start value (3)
    left = json.loads(csv.with_name("ss.meta.json").read_text())["meta"]["left_inputs"]
    assert "u[3]" not in table.columns and left == {"u[3]": 3.0}
    u = np.column_stack([table["u[1]"], table["u[2]"], np.full(len(table), left["u[3]"])])
    fine = np.arange(round(t[-1] / h) + 1) * h
    u_fine = u[np.minimum(np.floor(fine / 0.01 + 1e-9).astype(int), len(t) - 1)]  # held over each 10 ms step
    system = control.ss(np.eye(3) + h * a, h * b, np.eye(3), np.eye(3), h)
    response = control.forced_response(system, fine, u_fine.T, X0=np.zeros(3))
    y = response.outputs.T[::10]
    # y at t_k is read after the step, with the input of the step before: D u of the held value
    y[1:] += (np.eye(3) @ (u[:-1] - u[1:]).T).T
    np.testing.assert_allclose(table[["y[1]", "y[2]", "y[3]"]].to_numpy(), y, atol=1e-9)
    assert np.abs(y).max() > 0.1  # a response, not zeros
    # the state x, a local variable (not an output), recorded by name: python-control's states
    np.testing.assert_allclose(table[["x[1]", "x[2]", "x[3]"]].to_numpy(), response.states.T[::10], atol=1e-9)


def test_a_state_that_is_not_an_output_is_recorded_as_fmpy_reads_it(ref):
    """BouncingBall's der(h) and der(v) are local variables; recorded by name they equal fmpy's values."""
    path = ref[2]["BouncingBall"]
    traj = cosim.simulate(path, duration=2.0, dt=0.01, outputs=["h", "der(h)", "der(v)"])
    theirs = _fmpy(path, ["h", "der(h)", "der(v)"], 0.0, 2.0, 0.01)
    _assert_same({n: traj[n] for n in ("h", "der(h)", "der(v)")}, theirs, {})
    done = CliRunner().invoke(cli, ["simulate", str(path), "--duration", "2", "--dt", "0.01", "--record", "der(v)",
                                    "--json"])
    assert done.exit_code == 0 and json.loads(done.output)["final"]["der(v)"] == traj["der(v)"][-1]


@pytest.mark.parametrize(("args", "message"), [
    (["simulate", "{Feedthrough3}", "--duration", "1", "--dt", "0.1", "--input", "String_input=1"],
     "String_input of Feedthrough.fmu is a String variable: only numbers can be driven"),
    (["simulate", "{StateSpace3}", "--duration", "1", "--dt", "0.1", "--set", "A[4,1]=1"],
     "A[4,1] is out of range: A is a 3x3 array, its elements are A[1,1] to A[3,3]"),
    (["simulate", "{StateSpace3}", "--duration", "1", "--dt", "0.1", "--set", "A=[[1,2],[3,4]]"],
     "A is a 3x3 array; got a value of shape 2x2"),
    (["fmu", "info", "{Clocks3}"], "has neither a co-simulation nor a Model Exchange interface (only Scheduled "
                                   "Execution)"),
    (["fmu", "info", "{notanfmu}"], "is not an FMU: the zip has no modelDescription.xml"),
])
def test_bad_input_is_one_line_exit_2(ref, tmp_path, args, message):
    zipped = tmp_path / "notanfmu.fmu"
    import zipfile

    with zipfile.ZipFile(zipped, "w") as archive:
        archive.writestr("readme.txt", "not an FMU")
    paths = {"Feedthrough3": ref[3]["Feedthrough"], "StateSpace3": ref[3]["StateSpace"], "Clocks3": ref[3]["Clocks"],
             "notanfmu": zipped}
    done = CliRunner().invoke(cli, [arg.format(**paths) for arg in args])
    assert done.exit_code == 2, done.output
    assert message in done.output and done.output.count("\n") == 1, done.output


def test_a_binary_takes_its_hex_digits_as_text_whatever_they_are(ref, tmp_path):
    """Issue 38 item 2: `--set Binary_input=626172`, hex digits that are all decimal digits, sets the bytes 62 61 72
    (not the number 626172, which a Binary refuses, from Python too, in one line)."""
    from cosim.cli._command import _settings

    path = ref[3]["Feedthrough"]
    done = CliRunner().invoke(cli, ["simulate", str(path), "--duration", "0.2", "--dt", "0.1", "--set",
                                    "Binary_input=626172", "--set", "String_input=42", "-o", str(tmp_path / "r.csv")])
    assert done.exit_code == 0, done.output
    assert cosim.Trajectory.read(tmp_path / "r.csv").meta["start"] == {"Binary_input": "626172", "String_input": "42"}
    with cosim.FmuPlant(path, dt=0.1, start=_settings(("Binary_input=626172", "String_input=42"), "--set")) as plant:
        plant.step([float(v) for v in plant.get(plant.inputs)])
        assert plant.get(["Binary_output", "String_output"]) == [bytes([0x62, 0x61, 0x72]), "42"]
    with pytest.raises(InvalidSettingError, match=r"^Binary_input is a Binary variable: give bytes \(b'bar'\) or their "
                                                  r"hex digits as text \('626172'\), got the int 626172$"):
        cosim.FmuPlant(path, dt=0.1, start={"Binary_input": 626172})


def test_api_errors_name_the_variable(ref):
    with pytest.raises(UnknownVariableError, match=r"y\[4\] is out of range: y is a 3 array"):
        cosim.FmuPlant(ref[3]["StateSpace"], dt=0.1, outputs=["y[4]"])
    with pytest.raises(CosimError, match="y of StateSpace.fmu is an array: name its elements"):
        cosim.FmuPlant(ref[3]["StateSpace"], dt=0.1, outputs=["y"])


def _on_grid(theirs, t: np.ndarray) -> np.ndarray:
    """The rows of an FMPy Model Exchange result at the times `t`: FMPy also records a row before and after each
    event; the last row at a time is the state after its events, which is what a communication point shows."""
    rows = [np.nonzero(np.abs(theirs["time"] - ti) <= 1e-9 * max(1.0, abs(ti)))[0][-1] for ti in t]
    return theirs[rows]


ME_RUNS = [(v, name, solver) for v in (2, 3) for name in ("BouncingBall", "VanDerPol") for solver in ("cvode", "euler")]


@pytest.mark.parametrize(("version", "name", "solver"), ME_RUNS, ids=[f"fmi{v}-{n}-{s}" for v, n, s in ME_RUNS])
def test_model_exchange_gives_fmpys_outputs_with_the_same_solver(ref, version, name, solver):
    """As Model Exchange, integrated by FMPy's CVode or Euler inside FmuPlant, BouncingBall (state events) and
    VanDerPol give FMPy's own Model Exchange outputs at the communication points.

    Both run the same solver with the same settings (tolerance and largest step from the default experiment, whose
    stop time is the run's), so they agree far inside CVode's 1e-5: 1e-9 for CVode, 1e-12 for Euler."""
    path = ref[version][name]
    duration = 3.0 if name == "BouncingBall" else 20.0  # the default experiments' stop times
    traj = cosim.simulate(path, duration=duration, dt=0.01, kind="me", solver=solver)
    assert traj.meta["kind"] == "me" and traj.meta["solver"] == ("CVode" if solver == "cvode" else "Euler")
    theirs = _on_grid(fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", solver=traj.meta["solver"],
                                        stop_time=duration, output_interval=0.01), traj.time)
    tolerance = 1e-9 if solver == "cvode" else 1e-12
    for column in ("h", "v") if name == "BouncingBall" else ("x0", "x1"):
        np.testing.assert_allclose(traj[column], theirs[column], rtol=0, atol=tolerance, err_msg=column)
    if name == "BouncingBall":
        assert np.sum(np.diff(np.sign(traj["v"])) > 0) >= 3  # it bounced: the state events were met


def test_a_pid_loop_runs_on_a_model_exchange_fmu(ref):
    """A PID closed loop, unchanged, on StateSpace as Model Exchange (CVode): y[1] follows a step set-point."""
    from controllers.pid import PID
    from cosim.loop.closed_loop import closed_loop

    pid = PID(kp=2.0, ki=4.0, dt=0.01, inputs="u[1]", outputs="y[1]", u_min=-50.0, u_max=50.0)
    with cosim.FmuPlant(ref[3]["StateSpace"], dt=0.01, kind="me",
                        parameters={"A": [[-1.0, 0, 0], [0, -1, 0], [0, 0, -1]],
                                    "D": [[0.0] * 3] * 3}) as plant:
        assert plant.kind == "me"
        result = closed_loop(pid, plant, duration=6.0, reference=1.0, model=None)
    y = result.fmu["y[1]"]
    assert abs(y[-1] - 1.0) < 0.01 and abs(y[0]) < 1e-12  # from rest to the set-point


def test_fmu_info_and_simulate_show_the_kind(ref, tmp_path):
    runner = CliRunner()
    info = json.loads(runner.invoke(cli, ["fmu", "info", str(ref[2]["VanDerPol"]), "--json"]).output)
    assert info["kinds"] == ["cs", "me"]
    done = runner.invoke(cli, ["simulate", str(ref[2]["VanDerPol"]), "--kind", "me", "--solver", "euler",
                               "--duration", "1", "--dt", "0.01", "--json"])
    assert done.exit_code == 0 and json.loads(done.output)["kind"] == "me", done.output
    bundled = json.loads(runner.invoke(cli, ["fmu", "info", "bundled", "--json"]).output)
    assert bundled["kinds"] == ["cs"]
    done = runner.invoke(cli, ["simulate", "bundled", "--kind", "me", "--duration", "1", "--dt", "0.01"])
    assert done.exit_code == 2 and done.output.count("\n") == 1
    assert "has no Model Exchange interface (it has co-simulation); use --kind cs" in done.output


def test_cosim_validate_runs_a_pid_on_the_model_exchange_interface(ref, tmp_path):
    """`cosim validate --kind me` on StateSpace (which has both interfaces), its matrices set with --set: the
    verdict passes, and the same loop through co-simulation gives the same response within the solvers' gap."""
    from controllers.pid import PID

    ctrl = tmp_path / "pid.json"
    PID(kp=2.0, ki=4.0, dt=0.01, inputs="u[1]", outputs="y[1]", u_min=-50.0, u_max=50.0).save(ctrl)
    args = ["validate", str(ref[3]["StateSpace"]), str(ctrl), "--scenario", "step:amp=1,duration=6",
            "--set", "A=[[-1,0,0],[0,-1,0],[0,0,-1]]", "--set", "D=[[0,0,0],[0,0,0],[0,0,0]]",
            "--spec", "steady_state_error<=0.01", "--spec", "overshoot<=20%", "--no-model", "--json"]
    me = CliRunner().invoke(cli, args + ["--kind", "me"])
    cs = CliRunner().invoke(cli, args + ["--kind", "cs"])
    assert me.exit_code == 0 and cs.exit_code == 0, me.output + cs.output
    me_metrics, cs_metrics = json.loads(me.output)["metrics"], json.loads(cs.output)["metrics"]
    assert json.loads(me.output)["passed"]
    # CVode against the FMU's own 1 ms Euler: the same loop, a few parts in a thousand apart
    assert me_metrics["overshoot_pct"] == pytest.approx(cs_metrics["overshoot_pct"], abs=0.5)
    assert me_metrics["settling_time"] == pytest.approx(cs_metrics["settling_time"], abs=0.05)
