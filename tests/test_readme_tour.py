"""The README's tour, run as a new user runs it: every command of its bash block, in order, in a fresh folder,
each ending with exit status 0 and writing the files it names; the controllers designed on the identified model
pass their validation specs. The cluster address is replaced by a local Dask cluster's. The commands go through
the ``cosim`` entry point's click group in this process (tests/test_cli.py runs the installed entry point itself):
a process per command would import cosim and load its compiled models 18 times over, 20 s of CI time.

The two EMPS lines are the commands ``tests/test_emps.py`` runs on the real data (checked here to be the same
command line): run again here they would add a minute and a half to the suite.
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
from summary_checks import summary_rows

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CLUSTER = "tcp://host:8786"
# options naming a file or folder a command writes
WRITES = ("-o", "--output", "--to", "--report", "--plot", "--out-dir", "--out")


def tour_commands(text: str) -> list[list[str]]:
    """The commands of the README's tour block, continuation lines joined, comments dropped, as argv lists."""
    block = re.search(r"## A tour\n.*?```bash\n(.*?)```", text, re.S)
    assert block, "the README has no tour block"
    joined = block.group(1).replace("\\\n", " ")
    commands = [shlex.split(line, comments=True) for line in joined.splitlines()]
    return [argv for argv in commands if argv]


def written(argv: list[str]) -> list[str]:
    return [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg in WRITES]


def test_the_tour_block_is_read_as_a_shell_reads_it():
    commands = tour_commands(README.read_text(encoding="utf-8"))
    assert all(argv[0] in ("cosim", "python") for argv in commands)
    validate = next(argv for argv in commands if argv[:2] == ["cosim", "validate"])
    assert "settling_time<=1" in validate and "overshoot<=10%" in validate  # quoted: not a redirection
    assert written(commands[2]) == ["data.csv"]


def test_the_emps_lines_are_the_commands_the_emps_tests_run():
    from test_emps import DEFAULT_PATH_OPTIONS

    emps = [argv for argv in tour_commands(README.read_text(encoding="utf-8")) if "emps" in " ".join(argv)]
    assert emps == [["cosim", "diagnose", "../shared/data/emps/DATA_EMPS.mat", *DEFAULT_PATH_OPTIONS],
                    ["python", "examples/emps.py", "--data", "../shared/data/emps"]]


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    # workers as threads of this process, which has cosim imported already: a process per worker would import it
    # again (CI time); the command still reaches the cluster through its TCP address, as on a real one
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None,
                      protocol="tcp") as local:
        yield local.scheduler_address


@pytest.mark.slow
def test_the_tour_runs_from_a_fresh_folder(tmp_path, cluster, monkeypatch):
    from click.testing import CliRunner

    from cosim.cli import main

    monkeypatch.chdir(tmp_path)
    outputs = {}
    for argv in tour_commands(README.read_text(encoding="utf-8")):
        if "emps" in " ".join(argv):
            continue  # run by tests/test_emps.py (see the test above)
        args = [cluster if arg == CLUSTER else arg for arg in argv[1:]]
        # the command as the `cosim` entry point runs it, in this process (a process per command would import
        # cosim 18 times: CI time); tests/test_cli.py checks the entry point itself
        result = CliRunner().invoke(main, args, catch_exceptions=False)
        line = " ".join(argv)
        assert result.exit_code == 0, f"{line}\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"
        assert "Traceback" not in result.stderr and "UserWarning" not in result.stderr, line
        for name in written(argv):
            assert (tmp_path / name).exists(), f"{line} did not write {name}"
        outputs[line] = result.stdout
    # the data file is a plain table another tool reads
    data = pd.read_csv(tmp_path / "data.csv")
    assert list(data.columns) == ["time", "Tm", "theta_m", "omega_m", "theta_L", "omega_L"]  # TL not driven: left
    assert json.loads((tmp_path / "data.meta.json").read_text())["units"]["theta_m"] == "rad"
    np.testing.assert_array_equal(pd.read_csv(tmp_path / "replay.csv")["Tm"], data["Tm"])
    # the same replay for MATLAB: a variable per signal, the values of the CSV's
    mat = scipy.io.loadmat(tmp_path / "replay.mat")
    for name in data.columns:
        np.testing.assert_array_equal(mat[name].ravel(), pd.read_csv(tmp_path / "replay.csv")[name])
    # the split servo, a system of two FMUs: its columns named component.variable, its motor near the one-FMU servo's
    split = pd.read_csv(tmp_path / "split.csv")
    assert list(split.columns) == ["time", "motor.Tm", "motor.theta_m", "motor.omega_m", "load.Tc", "load.theta_L",
                                   "load.omega_L"]
    replay = pd.read_csv(tmp_path / "replay.csv")  # the one-FMU servo under the same torque, without noise
    np.testing.assert_allclose(split["motor.theta_m"], replay["theta_m"], atol=1e-3 * np.ptp(replay["theta_m"]))
    # any FMU: validate's checks come from the plant and the design, said with their reasons
    exported = next(out for line, out in outputs.items() if line.startswith("cosim validate model.fmu"))
    assert exported.startswith("PASSED") and "input_limit<=5000: the controller's limit on Tm" in exported
    # the identified model is stable, the MPC and the PID designed on it pass their specs on the FMU
    model = json.loads((tmp_path / "model.json").read_text())
    assert model["meta"]["stable"] is True
    mpc = json.loads(next(out for line, out in outputs.items() if "mpc.json --scenario" in line))
    assert mpc["passed"] is True and all(c["passed"] is not False for c in mpc["checks"])
    local, dask = (out for line, out in outputs.items() if "pid.json --robustness" in line)
    assert local.startswith("PASSED") and "pass rate 100.0%" in local
    # the same draws and verdicts on the cluster as in local processes (the Monte Carlo's pass rate, worst case)
    robust = [[ln for ln in out.splitlines() if ln.startswith("robustness:")] for out in (local, dask)]
    assert robust[0] == robust[1] and robust[0]
    assert f"run on {cluster}" in dask and "run on tcp://" not in local
    diagnosis = json.loads(next(out for line, out in outputs.items() if "--report diagnosis.html" in line))
    assert diagnosis["after"]["nrmse_pct"] <= diagnosis["before"]["nrmse_pct"]
    # every report opens with its summary box, with the time the command measured
    box = summary_rows(tmp_path / "diagnosis.html")
    assert box["Plant"].startswith("two_mass_servo.fmu (") and box["Data"].startswith("data.csv: 9029 samples")
    box = summary_rows(tmp_path / "validation.html")
    assert box[""] == "Summary PASSED" and box["Plant"].endswith("; set: Fc=100") and box["Time"].endswith(" s")
    assert summary_rows(tmp_path / "paper-repro" / "report.html")["Data"].startswith("12 cases: square and sine")
    two = next(out for line, out in outputs.items() if "run1.csv run2.csv" in line)
    assert two.startswith("found coulomb_friction on omega_m")  # the records' Fc = 100 N m, within 5 %
    assert float(re.search(r"Fc=([\d.]+)", two).group(1)) == pytest.approx(100.0, rel=0.05)
    fit = next(out for line, out in outputs.items() if line.startswith("cosim compare"))
    assert all(float(v) > 85.0 for v in re.findall(r"fit (-?[\d.]+) %", fit))


@pytest.mark.slow
def test_the_python_example_runs(tmp_path, monkeypatch):
    block = re.search(r"From Python:\n\n```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert block, "the README has no Python example"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(block.group(1), "README.md", "exec"), namespace)  # noqa: S102 - the README's own example
    assert (tmp_path / "data.parquet").is_file()
    assert 0.005 < namespace["y"][2] < 0.0105  # the proportional loop took theta_L more than half way to 0.01
