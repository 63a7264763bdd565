"""The `cosim` command: results on stdout (--json), one-line errors, non-zero exit, no traceback."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from cosim import Trajectory
from cosim.cli import main


def run(*args: str):
    result = CliRunner().invoke(main, list(args), catch_exceptions=False)
    return result


def assert_clean_error(result, *fragments: str) -> None:
    assert result.exit_code != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output + result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_fmu_build_json_gives_the_path():
    result = run("fmu", "build", "--json")
    assert result.exit_code == 0, result.stderr
    payload = json.loads(result.stdout)
    assert payload["path"].endswith("two_mass_servo.fmu")


def test_fmu_info_lists_variables():
    result = run("fmu", "info", "bundled", "--json")
    info = json.loads(result.stdout)
    assert [v["name"] for v in info["inputs"]] == ["Tm", "TL"]
    assert {"Jm", "JL", "KL", "Bm", "BL", "Fc", "delay"} <= {p["name"] for p in info["parameters"]}
    assert info["states"] == ["theta_m", "omega_m", "theta_L", "omega_L"]
    # numbers as numbers, of the variable's type (issue 15): reals as floats, integers as ints
    tm = info["inputs"][0]
    assert (tm["start"], tm["min"], tm["max"]) == (0.0, -5000.0, 5000.0) and isinstance(tm["max"], float)
    params = {p["name"]: p for p in info["parameters"]}
    assert params["KL"]["start"] == 2.5e6 and params["nsub"]["start"] == 10 and isinstance(params["nsub"]["start"], int)
    assert isinstance(info["default_step"], float)


def test_simulate_the_issue_example(tmp_path):
    out = tmp_path / "data.csv"
    result = run("simulate", "bundled", "--input", "Tm=square:amp=500,freq=2", "--duration", "4", "--dt", "1/2257",
                 "--set", "Fc=0.3", "--noise", "0.1", "--seed", "0", "-o", str(out), "--json")
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["samples"] == 4 * 2257 + 1 and summary["noise"] == 0.1
    traj = Trajectory.read(out)
    assert traj.meta["parameters"]["Fc"] == 0.3
    assert np.isclose(traj.dt, 1 / 2257, rtol=1e-9)
    assert set(np.unique(traj["Tm"])) == {-500.0, 500.0}  # inputs carry no noise


@pytest.mark.parametrize("args,fragments", [
    (["simulate", "missing.fmu", "--duration", "1", "--dt", "0.01"], ["not found"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "0"], ["positive"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "x/2"], ["--dt", "not a number"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "0.01", "--set", "Jmm=3"], ["Jm"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "0.01", "--set", "Fc"], ["NAME=VALUE"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "0.01", "--input", "Tm=triangle:amp=1"], ["triangle"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "0.01", "--input", "Tq=1"], ["Tq"]),
    (["simulate", "bundled", "--duration", "1", "--dt", "0.01", "--noise", "-1"], ["noise"]),
    (["fmu", "info", "missing.fmu"], ["not found"]),
])
def test_bad_input_is_one_line(args, fragments):
    assert_clean_error(run(*args), *fragments)


def test_failed_run_writes_no_file(tmp_path):
    out = tmp_path / "data.csv"
    result = run("simulate", "bundled", "--duration", "5", "--dt", "1e-3", "--set", "Bm=-2e5",
                 "--start", "omega_m=1", "-o", str(out))
    assert_clean_error(result, "fmi2DoStep", "t=")
    assert list(tmp_path.iterdir()) == []


def test_real_command_exits_nonzero_without_traceback():
    proc = subprocess.run([sys.executable, "-m", "cosim.cli", "simulate", "nowhere.fmu", "--duration", "1",
                           "--dt", "0.1"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: ") and "Traceback" not in proc.stderr


@pytest.mark.parametrize("text,fragment", [
    ("time,x\n0,1\n1,nan\n", "is nan at t=1"),
    ("time,x\n0,1\n0,2\n", "increas"),
    ("s,x\n0,1\n1,2\n", "time"),  # a column t would be the time (default t, else time)
])
def test_bad_data_files_are_one_line_errors(tmp_path, text, fragment):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    assert_clean_error(run("data", "info", str(path)), fragment)


def test_data_info_missing_columns_and_good_file(tmp_path):
    out = tmp_path / "d.csv"
    assert run("simulate", "bundled", "--duration", "0.1", "--dt", "1e-3", "-o", str(out)).exit_code == 0
    assert_clean_error(run("data", "info", str(out), "--columns", "theta_m,torque"), "torque")
    info = json.loads(run("data", "info", str(out), "--json").stdout)
    assert info["samples"] == 101 and info["uniform"] is True
    assert {s["name"]: s["role"] for s in info["signals"]}["theta_L"] == "state"


@pytest.fixture()
def model_file(tmp_path):
    from cosim.identify.model import IdentifiedModel
    from cosim.study.paper import INPUTS, STATES, two_mass_matrices

    a, b = two_mass_matrices()
    model = IdentifiedModel(states=STATES, inputs=INPUTS, terms=STATES + INPUTS, coef=np.hstack([a, b]), dt=1e-3)
    return model.save(tmp_path / "model.json")


def test_export_writes_mat_and_fmu(model_file, tmp_path):
    from scipy.io import loadmat

    result = run("export", str(model_file), "--to", str(tmp_path / "ss.mat"), "--to", str(tmp_path / "m.fmu"),
                 "--json")
    assert result.exit_code == 0, result.stderr
    written = json.loads(result.stdout)["written"]
    assert [w.rsplit(".", 1)[1] for w in written] == ["mat", "fmu"]
    mat = loadmat(tmp_path / "ss.mat")
    assert mat["A"][1, 0] == pytest.approx(-1e4) and mat["B"].shape == (4, 2)
    info = json.loads(run("fmu", "info", str(tmp_path / "m.fmu"), "--json").stdout)
    assert info["states"] == ["theta_m", "omega_m", "theta_L", "omega_L"]


def test_export_bad_input(model_file, tmp_path):
    assert_clean_error(run("export", str(model_file), "--to", str(tmp_path / "m.xyz")), ".xyz")
    assert_clean_error(run("export", str(tmp_path / "none.json"), "--to", str(tmp_path / "m.mat")), "not found")
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert_clean_error(run("export", str(bad), "--to", str(tmp_path / "m.mat")), "not a cosim model")


def test_a_library_warning_prints_as_one_warning_line(tmp_path):
    """Python's ``file:line: UserWarning:`` becomes one ``warning: ...`` line on stderr (here: a stale sidecar)."""
    from cosim.data.trajectory import Trajectory

    t = np.arange(5) * 0.1
    Trajectory.from_arrays(t, {"a": t, "b": t}).write(tmp_path / "run.csv")
    Trajectory.from_arrays(t, {"a": t}).write(tmp_path / "other.csv")
    (tmp_path / "other.meta.json").replace(tmp_path / "run.meta.json")
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "data", "info", str(tmp_path / "run.csv")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stderr.splitlines() == [
        "warning: run.meta.json describes columns ['time', 'a'], not those of run.csv; its units, roles and meta "
        "are ignored (rewrite or delete it)"]


def test_identify_a_model_with_no_inputs_and_the_polynomial_library(tmp_path):
    """Issue 15: a plant without inputs (Van der Pol, simulated by scipy) through `cosim identify`, cubic library."""
    from scipy.integrate import solve_ivp

    from cosim.data.trajectory import Trajectory
    from cosim.identify.model import IdentifiedModel

    t = np.arange(3001) * 0.01
    sol = solve_ivp(lambda _, z: [z[1], (1 - z[0] ** 2) * z[1] - z[0]], (0, 30), [2.0, 0.0], t_eval=t,
                    rtol=1e-10, atol=1e-12)
    Trajectory.from_arrays(t, {"x": sol.y[0], "y": sol.y[1]}).write(tmp_path / "vdp.csv")
    result = run("identify", str(tmp_path / "vdp.csv"), "--state", "x,y", "--library", "polynomial", "--degree", "3",
                 "-o", str(tmp_path / "m.json"), "--json")
    assert result.exit_code == 0, result.stderr
    assert min(json.loads(result.stdout)["fit"]["fit_pct"].values()) > 99.0
    model = IdentifiedModel.load(tmp_path / "m.json")
    row = dict(zip(model.terms, model.coef[model.states.index("y")], strict=True))
    assert model.inputs == ()
    assert (row["x"], row["y"], row["x**2*y"]) == pytest.approx((-1.0, 1.0, -1.0), rel=0.01)


@pytest.mark.parametrize(("args", "message"), [
    (["compare", "model.json", "data.csv", "--horizon", "0"],
     "error: Invalid value for '--horizon': 0 is not in the range x>=1. (see `cosim compare --help`)"),
    (["simulate", "bundled", "--bogus"], "error: No such option '--bogus'. (see `cosim simulate --help`)"),
    (["compare", "model.json"], "error: Missing argument 'DATA'. (see `cosim compare --help`)"),
    (["nosuchcommand"], "error: No such command 'nosuchcommand'. (see `cosim --help`)"),
])
def test_usage_errors_are_one_line_exit_2(args, message):
    proc = subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.splitlines() == [message] and proc.stdout == ""


def test_simulate_records_named_variables_and_fmu_info_lists_locals(tmp_path):
    out = tmp_path / "r.csv"
    result = run("simulate", "bundled", "--input", "Tm=1000", "--duration", "0.01", "--dt", "1e-3",
                 "--record", "theta_m,der_omega_m", "-o", str(out))
    assert result.exit_code == 0, result.stderr
    assert out.read_text().splitlines()[0] == "time,Tm,theta_m,der_omega_m"  # TL, not driven, is left to the FMU
    assert run("simulate", "bundled", "--duration", "0.01", "--dt", "1e-3", "--record", "all", "-o",
               str(tmp_path / "a.csv")).exit_code == 0
    assert "der_omega_L" in (tmp_path / "a.csv").read_text().splitlines()[0]
    info = json.loads(run("fmu", "info", "bundled", "--all", "--json").stdout)
    assert [v["name"] for v in info["locals"]] == ["der_theta_m", "der_omega_m", "der_theta_L", "der_omega_L"]
    assert "locals" not in json.loads(run("fmu", "info", "bundled", "--json").stdout)


def test_every_command_that_writes_a_folder_or_file_takes_o():
    """`-o` is how every command names where its result goes (`cosim identify -o`, `cosim diagnose -o`...): the
    demo's folder too (`cosim demo -o DIR` was refused)."""
    from cosim.cli import main

    for name in ("demo", "identify", "diagnose", "simulate"):
        option = next(p for p in main.commands[name].params if p.name in ("out_dir", "out"))
        assert "-o" in option.opts, (name, option.opts)
