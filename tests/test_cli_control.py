"""`cosim design pid|mpc` and `cosim validate` from the command line: files, JSON, exit status, errors."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from cosim.cli import main
from cosim.identify.model import IdentifiedModel
from cosim.study.paper import STATES, two_mass_matrices


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """The bundled plant's linear model as a cosim model file (what `cosim identify` writes)."""
    a, b = two_mass_matrices()
    coef = np.hstack([a, b[:, :1]])
    model = IdentifiedModel(states=STATES, inputs=("Tm",), terms=(*STATES, "Tm"), coef=coef, dt=1 / 2257)
    return model.save(tmp_path_factory.mktemp("model") / "model.json")


def run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture(scope="module")
def pid_file(model_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("pid") / "pid.json"
    code, text, _ = run("design", "pid", model_file, "--input", "Tm", "--output", "theta_L", "--velocity",
                        "omega_m", "--u-max", "5000", "-o", out, "--json")
    assert code == 0, text + _
    data = json.loads(text)
    assert data["kind"] == "pid" and data["info"]["closed_loop_stable"] is True
    assert data["info"]["gain_margin_db"] >= 6.0 and data["info"]["phase_margin_deg"] >= 45.0
    return out


@pytest.fixture(scope="module")
def mpc_file(model_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("mpc") / "mpc.json"
    code, text, _ = run("design", "mpc", model_file, "--measured", "theta_m,theta_L", "--tracked", "theta_L",
                        "--u-max", "5000", "--horizon", "20", "-o", out, "--json")
    assert code == 0, text
    data = json.loads(text)
    assert data["kind"] == "mpc" and data["outputs"] == ["theta_m", "theta_L"] and data["info"]["horizon"] == 20
    return out


@pytest.mark.parametrize("which", ["pid_file", "mpc_file"])
def test_validate_passes_with_friction_and_prints_the_json_keys(which, request, tmp_path):
    ctrl = request.getfixturevalue(which)
    code, text, _ = run("validate", "bundled", ctrl, "--scenario", "step:amp=0.01,duration=2", "--set", "Fc=100",
                        "--spec", "settling_time<=1", "--spec", "overshoot<=10%", "--spec",
                        "steady_state_error<=2e-5", "--spec", "input_limit<=5000", "--json", "--report",
                        tmp_path / "v.html")
    data = json.loads(text)
    assert code == 0 and data["passed"] is True, data["reasons"]
    assert {"passed", "metrics", "solve_time_us", "reasons"} <= set(data)
    assert {"median", "p99"} <= set(data["solve_time_us"]) and data["solve_time_us"]["median"] > 0
    assert data["metrics"]["settling_time"] <= 1.0
    assert (tmp_path / "v.html").stat().st_size > 20_000 and (tmp_path / "closed_loop_1.png").is_file()


def test_validate_exits_nonzero_with_reasons_when_a_spec_fails(mpc_file):
    code, text, _ = run("validate", "bundled", mpc_file, "--scenario", "step:amp=0.01,duration=1",
                        "--spec", "settling_time<=5ms", "--json")
    data = json.loads(text)
    assert code == 1 and data["passed"] is False
    assert any("settling_time<=5ms" in reason for reason in data["reasons"])


@pytest.mark.parametrize(("args", "message"), [
    (["--scenario", "jump:amp=1"], "unknown scenario"),
    (["--spec", "settling_time=1"], "cannot read spec"),
    (["--set", "Fx=1"], "Fx"),
])
def test_validate_bad_input_is_one_line(pid_file, args, message):
    result = CliRunner().invoke(main, ["validate", "bundled", str(pid_file), *args])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0]
    assert "Traceback" not in result.output


def test_design_pid_reads_the_old_output_option_as_the_tracked_signal_with_a_warning(model_file, tmp_path):
    new = CliRunner().invoke(main, ["design", "pid", str(model_file), "--tracked", "theta_L", "-o",
                                    str(tmp_path / "new.json"), "--json"])
    old = CliRunner().invoke(main, ["design", "pid", str(model_file), "--output", "theta_L", "--out",
                                    str(tmp_path / "old.json"), "--json"])
    assert new.exit_code == 0 and old.exit_code == 0, old.output
    assert "warning: --output theta_L (a signal) is deprecated and will be removed; use --tracked theta_L" in old.stderr
    assert "warning: --out FILE is deprecated" in old.stderr and "warning" not in new.stderr
    first, second = (json.loads((tmp_path / f).read_text()) for f in ("new.json", "old.json"))
    assert first["settings"]["outputs"] == ["theta_L"] and first == second


def test_design_errors_are_one_line(model_file, tmp_path):
    result = CliRunner().invoke(main, ["design", "pid", str(model_file), "--tracked", "theta_X"])
    assert result.exit_code == 2 and "theta_X" in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(main, ["design", "pid", str(model_file), "--output", "theta_X"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "-o/--output theta_X is neither a .json file nor an output of the model (theta_m" in result.output
    assert list(tmp_path.iterdir()) == []
    result = CliRunner().invoke(main, ["design", "mpc", str(tmp_path / "none.json")])
    assert result.exit_code == 2 and "not found" in result.output
    bad = tmp_path / "ctrl.json"
    bad.write_text("{}")
    result = CliRunner().invoke(main, ["validate", "bundled", str(bad)])
    assert result.exit_code == 2 and "not a cosim controller" in result.output
