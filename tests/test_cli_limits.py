"""Issue 38 from the command line: `cosim design pid` with an input limit, `cosim validate` with the defaults the
plant and the design call for, misspelt scenario keys, the Monte Carlo on any FMU's parameters, short summaries.

The end-to-end case is the issue's: a 1.6 Hz mass on a spring with Coulomb friction, simulated here with scipy's
``solve_ivp`` (its own equations, not cosim's), identified, designed for with ``--u-max 50``, exported, validated.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cosim.cli import main
from cosim.identify.model import IdentifiedModel

MASS, ZETA = 2.0, 0.02


def run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def spring_constants(f0: float) -> tuple[float, float]:
    k = MASS * (2 * math.pi * f0) ** 2
    return k, 2 * ZETA * math.sqrt(k * MASS)


@pytest.fixture(scope="module")
def spring(tmp_path_factory):
    """A 1.6 Hz mass-spring model as `cosim identify` writes it (the true coefficients), a PID designed on it with
    --u-max 50 and the model's FMU: the design and validation steps without the identification's time."""
    folder = tmp_path_factory.mktemp("spring")
    k, c = spring_constants(1.6)
    coef = np.array([[0.0, 1.0, 0.0], [-k / MASS, -c / MASS, 1.0 / MASS]])
    model = IdentifiedModel(states=("x", "v"), inputs=("F",), terms=("x", "v", "F"), coef=coef, dt=1 / 2000)
    model.save(folder / "model.json")
    code, text, err = run("design", "pid", folder / "model.json", "--tracked", "x", "--velocity", "v", "--u-max",
                          "50", "-o", folder / "pid.json")
    assert code == 0, err
    code, _, err = run("export", folder / "model.json", "-o", folder / "model.fmu")
    assert code == 0, err
    return folder, text


def test_design_pid_prints_a_short_summary_and_the_json_everything(spring):
    folder, text = spring
    lines = text.strip().splitlines()
    assert len(lines) <= 6, text
    assert lines[0] == "PI+velocity on F -> x, velocity v; dt 1/2000 s; F in [-50, 50]"
    assert lines[1].startswith("  gains: kp ") and "crossover" in lines[2] and "phase margin" in lines[2]
    assert "step 0.12 (steady input 50% of the limit), with the limits: overshoot" in lines[3]
    assert lines[-1] == f"written: {folder / 'pid.json'}"
    assert re.search(r"\d{7,}", text.replace(str(folder), "")) is None  # numbers rounded to their meaning
    code, out, _ = run("design", "pid", folder / "model.json", "--tracked", "x", "--velocity", "v", "--u-max", "50",
                       "--json")
    info = json.loads(out)["info"]
    saved = json.loads((folder / "pid.json").read_text())["info"]
    assert code == 0 and set(saved) <= set(info) and len(info) > 40
    assert info["design_step"] == 0.12 and info["delivers_step"] is True
    code, out, _ = run("design", "mpc", folder / "model.json", "--tracked", "x", "--u-max", "50", "--no-codegen")
    lines = out.strip().splitlines()
    assert code == 0 and len(lines) == 3 and lines[0] == "MPC on F -> x (measures x, v); dt 1/2000 s; F in [-50, 50]"
    assert lines[1].startswith("  horizon 20 moves (0.01 s); solver ") and "(stable)" in lines[2]


def test_design_warns_when_the_actuator_cannot_deliver_the_step(spring):
    folder, _ = spring
    code, out, err = run("design", "pid", folder / "model.json", "--tracked", "x", "--u-max", "50", "--step", "0.5")
    assert code == 0 and err.count("\n") == 1
    assert err.startswith("warning: a step of 0.5 needs a steady input of 101.1, beyond the limits [-50, 50]: no "
                          "design can hold it; kept the linear design, steps up to ")
    assert "step 0.5, with the limits: overshoot" in out


@pytest.mark.parametrize("dt", ["0", "-1e-3"])
def test_design_refuses_a_sample_time_that_is_not_positive(spring, dt):
    folder, _ = spring
    code, out, err = run("design", "pid", folder / "model.json", "--tracked", "x", "--dt", dt, "-o",
                         folder / "never.json")
    assert code == 2 and out == "" and not (folder / "never.json").exists()
    assert err.strip() == f"error: --dt must be a positive sample time in seconds, e.g. --dt 1/2257 (got {dt})"


def test_validate_defaults_come_from_the_plant_and_the_design(spring):
    """No --scenario, no --spec: a step of the design step, the predicted settling time with a margin, 2 % of the
    step, the controller's 50 N; the loop shows the predicted overshoot; the text says which defaults and why."""
    folder, _ = spring
    code, out, err = run("validate", folder / "model.fmu", folder / "pid.json", "--json")
    data = json.loads(out)
    info = json.loads((folder / "pid.json").read_text())["info"]
    assert code == 0 and data["passed"], data["reasons"]
    assert data["scenarios"][0]["amplitude"] == info["design_step"] == 0.12
    specs = data["defaults"]["specs"]
    assert specs[1:] == ["overshoot<=10%", "steady_state_error<=0.0024", "input_limit<=50"]
    assert float(specs[0].split("<=")[1]) >= 2 * info["step_settling_time_s"]
    assert data["metrics"]["overshoot_pct"] == pytest.approx(info["step_overshoot_pct"], abs=0.5)
    assert data["metrics"]["input_peak"] == pytest.approx(50.0)  # the step saturates the force, as designed
    code, text, _ = run("validate", folder / "model.fmu", folder / "pid.json")
    assert "defaults: scenario step:amp=0.12," in text and "the controller's limit on F" in text


def test_the_bundled_servo_keeps_the_telescope_defaults(fmu, tmp_path):
    from controllers.pid import PID
    from cosim.loop.validation import TELESCOPE_SPECS

    PID(kp=1.5e4, ki=1.3e4, kd=6.4e3, tf=0.022, b=0.33, dt=1e-3, inputs="Tm", outputs="theta_L",
        u_min=-5000, u_max=5000).save(tmp_path / "pid.json")
    code, out, _ = run("validate", "bundled", tmp_path / "pid.json", "--no-model", "--json")
    data = json.loads(out)
    assert data["defaults"]["specs"] == list(TELESCOPE_SPECS)
    assert data["scenarios"][0]["amplitude"] == 0.01 and data["scenarios"][0]["duration"] == 2.0


def test_a_misspelt_scenario_key_is_refused_before_anything_runs(spring):
    folder, _ = spring
    report = folder / "never.html"
    code, out, err = run("validate", folder / "model.fmu", folder / "pid.json", "--scenario",
                         "step:amp=0.01,duraton=2", "--report", report)
    assert code == 2 and out == "" and not report.exists() and not (folder / "closed_loop_1.png").exists()
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("error: scenario option 'duraton' in 'step:amp=0.01,at=0.05,duraton=2' is neither a "
                          "scenario key (amp, at, duration, rate, input, setpoint, band, name) nor a parameter of "
                          "model.fmu; did you mean duration?")
    code, _, err = run("validate", "bundled", folder / "pid.json", "--scenario", "step:amp=0.01,Jmm=300")
    assert code == 2 and "did you mean Jm?" in err and "its parameters: Jm, JL, KL" in err


def test_print_verdict_is_a_summary_not_the_trajectories(spring):
    from controllers.base import load_controller
    from cosim.loop.validation import validate

    folder, _ = spring
    verdict = validate(folder / "model.fmu", load_controller(folder / "pid.json"), model="design")
    text, short = str(verdict), repr(verdict)
    lines = text.splitlines()
    assert lines[0].startswith("PASSED: 4 of 4 checks met in 1 scenario(s); controller compute per call median")
    assert len(lines) == 5 and "[step:amp=0.12,at=0.05] overshoot<=10%: " in lines[2] and "(limit 10) met" in text
    assert "array" not in text + short and len(text) < 800
    assert short == "Verdict(passed=True, checks=4, failed=0, scenarios=['step:amp=0.12,at=0.05'])"


def test_robustness_varies_any_fmus_parameters(tmp_path):
    """StateSpace (a Reference FMU, FMI 3 arrays): the Monte Carlo spreads its real parameters whose value is not
    zero, A's diagonal as --set gives it and B's and C's from their start values; a name that is not a parameter
    is refused with the FMU's parameters only (no inputs, outputs or time)."""
    from reference_fmus import reference_fmus

    from controllers.pid import PID

    state_space = reference_fmus(3)["StateSpace"]
    PID(kp=2.0, ki=4.0, dt=0.01, inputs="u[1]", outputs="y[1]", u_min=-50.0, u_max=50.0).save(tmp_path / "pid.json")
    args = ["validate", state_space, tmp_path / "pid.json", "--set", "A=[[-1,0,0],[0,-1,0],[0,0,-1]]", "--set",
            "D=[[0,0,0],[0,0,0],[0,0,0]]", "--scenario", "step:amp=1,duration=6", "--spec", "overshoot<=20%",
            "--spec", "steady_state_error<=0.01", "--no-model", "--workers", "1"]
    code, out, err = run(*args, "--robustness", "4", "--json")
    assert code == 0, err
    rob = json.loads(out)["robustness"]
    diagonal = {f"{m}[{i},{i}]": -1.0 if m == "A" else 1.0 for m in "ABC" for i in (1, 2, 3)}
    assert rob["nominal"] == diagonal and rob["pass_rate"] == 1.0
    drawn = rob["worst"]["parameters"]
    assert set(drawn) == set(diagonal) and all(0.8 <= v / diagonal[k] <= 1.2 for k, v in drawn.items())
    assert len({round(v, 9) for v in drawn.values()}) == 9  # each element drawn on its own
    code, _, err = run(*args, "--robustness", "2", "--vary", "Jm")
    assert code == 2 and err.strip() == ("error: StateSpace.fmu has no real parameter 'Jm' to vary (its real "
                                         "parameters: A, B, C, D, x0)")
    code, _, err = run("validate", state_space, tmp_path / "pid.json", "--robustness", "2", "--effect", "u=0:1")
    assert code == 2 and "has no real parameter 'u' to vary as an effect" in err and "time" not in err


def record(f0: float, limit: float, fs: float, duration: float, seed: int = 1) -> pd.DataFrame:
    """The issue's plant: m x'' = F - k x - c x' - Fc tanh(v / 1 mm/s), a force of 25 sines from 0.2 Hz to 10 f0
    within ±0.9 limit held over each sample, Coulomb friction 5 % of the limit; columns t, F, x, v."""
    from scipy.integrate import solve_ivp

    k, c = spring_constants(f0)
    fc = 0.05 * limit
    dt = 1 / fs
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    freqs = np.geomspace(0.2, 10 * f0, 25)
    force = np.sin(2 * np.pi * freqs[:, None] * t[None, :] + rng.uniform(0, 2 * np.pi, freqs.size)[:, None]).sum(0)
    force = 0.9 * limit * force / np.abs(force).max()

    def rhs(time, s):
        f = force[min(int(time / dt + 1e-9), n - 1)]
        return [s[1], (f - k * s[0] - c * s[1] - fc * np.tanh(s[1] / 1e-3)) / MASS]

    sol = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t, method="LSODA", max_step=dt, rtol=1e-7, atol=1e-9)
    return pd.DataFrame({"t": t, "F": force, "x": sol.y[0], "v": sol.y[1]})


def test_the_issues_plant_end_to_end_overshoots_as_predicted(tmp_path, monkeypatch):
    """Issue 38: identify a 1.6 Hz mass-spring record (5 kHz, ±50 N, Coulomb friction), design with --u-max 50,
    export, validate with the defaults: the overshoot on the FMU is the predicted one (before: 2.7 % predicted,
    65 % measured, judged by the telescope's input_limit<=5000)."""
    monkeypatch.chdir(tmp_path)
    record(1.6, 50.0, 5000.0, 5.0).to_csv("data.csv", index=False)
    for argv in (["identify", "data.csv", "--state", "x,v", "--input", "F", "-o", "model.json"],
                 ["design", "pid", "model.json", "--tracked", "x", "--velocity", "v", "--u-max", "50", "-o",
                  "pid.json"],
                 ["export", "model.json", "-o", "model.fmu"]):
        code, _, err = run(*argv)
        assert code == 0 and "warning" not in err, (argv, err)
    code, out, err = run("validate", "model.fmu", "pid.json", "--json")
    data = json.loads(out)
    info = json.loads((tmp_path / "pid.json").read_text())["info"]
    assert code == 0 and data["passed"], data["reasons"]
    assert data["defaults"]["specs"][-1] == "input_limit<=50" and "input_limit<=5000" not in data["defaults"]["specs"]
    assert data["scenarios"][0]["amplitude"] == info["design_step"] == 0.12
    measured = data["metrics"]["overshoot_pct"]
    assert abs(measured - info["step_overshoot_pct"]) <= 5.0 and measured <= 10.0
    assert info["crossover_hz"] < 100.0  # not the 159 Hz of the sample rate's ceiling the limit cannot follow
