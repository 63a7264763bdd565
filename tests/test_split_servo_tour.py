"""The README tour's path on the split servo (issue 40): the servo as two FMUs wired by an SSP file
(``bundled-split``), through simulate -> identify -> diagnose (a friction switched on in the motor FMU, named on
the motor's speed) -> design pid and mpc -> validate -> robustness with ``load.JL`` perturbed on a local Dask
cluster. Every name is ``component.variable``. The commands go through the ``cosim`` entry point's click group in
this process, as tests/test_readme_tour.py runs the tour."""

from __future__ import annotations

import json
import re

import pytest


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None,
                      protocol="tcp") as local:
        yield local.scheduler_address


STATES = "motor.theta_m,motor.omega_m,load.theta_L,load.omega_L"


@pytest.mark.slow
def test_the_tour_runs_on_the_split_servo(tmp_path, cluster, monkeypatch):
    from click.testing import CliRunner

    from cosim.cli import main

    monkeypatch.chdir(tmp_path)

    def cosim(*args: str) -> str:
        result = CliRunner().invoke(main, list(args), catch_exceptions=False)
        assert result.exit_code == 0, f"cosim {' '.join(args)}\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"
        assert "Traceback" not in result.stderr
        return result.stdout

    cosim("simulate", "bundled-split", "--input", "motor.Tm=square:amp=500,freq=2", "--duration", "4", "--dt",
          "1/2257", "--set", "motor.Fc=0.3", "--noise", "0.1", "--seed", "0", "-o", "data.csv")
    cosim("identify", "data.csv", "--state", STATES, "--input", "motor.Tm", "-o", "model.json")
    assert json.loads((tmp_path / "model.json").read_text())["meta"]["stable"] is True
    # a Coulomb friction of 100 N m switched on in the motor FMU: named on the motor's speed, within 10 %
    cosim("simulate", "bundled-split", "--input", "motor.Tm=square:amp=500,freq=2", "--duration", "2", "--dt",
          "1/2257", "--set", "motor.Fc=100", "--noise", "0.1", "--seed", "0", "-o", "friction.csv")
    diagnosis = json.loads(cosim("diagnose", "friction.csv", "--state", STATES, "--input", "motor.Tm", "--json"))
    first = diagnosis["effects"][0]
    assert (first["name"], first["attached_to"]) == ("coulomb_friction", "motor.omega_m")
    assert first["parameters"]["Fc"] == pytest.approx(100.0, rel=0.1)
    cosim("design", "pid", "model.json", "--input", "motor.Tm", "--tracked", "load.theta_L", "--velocity",
          "motor.omega_m", "--u-max", "5000", "-o", "pid.json")
    cosim("design", "mpc", "model.json", "--measured", "motor.theta_m,load.theta_L", "--tracked", "load.theta_L",
          "--u-max", "5000", "-o", "mpc.json")
    assert cosim("validate", "bundled-split", "pid.json").startswith("PASSED")
    mpc = json.loads(cosim("validate", "bundled-split", "mpc.json", "--scenario", "step:amp=0.01,duration=2",
                           "--scenario", "disturbance:amp=500,at=0.5,input=load.TL", "--set", "motor.Fc=100",
                           "--spec", "settling_time<=1", "--spec", "overshoot<=10%", "--json"))
    assert mpc["passed"] is True
    robust = cosim("validate", "bundled-split", "pid.json", "--robustness", "4", "--spread", "0.2", "--vary",
                   "load.JL", "--effect", "motor.Fc=0:50", "--scheduler", cluster)
    assert robust.startswith("PASSED") and f"run on {cluster}" in robust
    line = next(ln for ln in robust.splitlines() if ln.startswith("robustness:"))
    assert "pass rate 100.0%" in line and re.search(r"worst case load\.JL=[\d.e+]+, motor\.Fc=[\d.e+]+$", line), line
    # the system driven from a recorded file: its column motor.Tm is the input of that name
    cosim("simulate", "bundled-split", "--input-file", "data.csv", "--set", "motor.Fc=0.3", "-o", "replay.csv")
    import pandas as pd

    replay, data = pd.read_csv(tmp_path / "replay.csv"), pd.read_csv(tmp_path / "data.csv")
    assert (replay["motor.Tm"] == data["motor.Tm"]).all() and len(replay) == len(data)


@pytest.mark.slow
def test_the_demo_runs_on_the_split_servo(tmp_path):
    """`cosim demo --plant split`: the main job on the servo as two FMUs. Its tested claims hold there too: the
    motor's friction named on the motor's speed (within 5 %), the four controllers pass on the system with friction,
    and the diagnosed model predicts each loop better than the linear one."""
    from click.testing import CliRunner

    from cosim.cli import main

    result = CliRunner().invoke(main, ["demo", "--plant", "split", "--out-dir", str(tmp_path), "--json"],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.stderr[-2000:]
    summary = json.loads(result.stdout)
    friction = summary["diagnosis"]["effects"][0]
    assert (friction["name"], friction["attached_to"]) == ("coulomb_friction", "motor.omega_m")
    assert friction["parameters"]["Fc"] == pytest.approx(100.0, rel=0.05)
    assert summary["fmu"].endswith("two_mass_servo_split.ssp")
    for group in ("controllers", "controllers_diagnosed"):
        assert all(c["passed"] for c in summary[group].values()), summary[group]
    for name, d in summary["model_discrepancy"].items():
        assert d["diagnosed_pct"] < d["linear_pct"], (name, d)
