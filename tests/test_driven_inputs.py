"""Issue 38, item 1: only the inputs something drives are set; the others are left to the FMU, as FMPy leaves them.

The test FMU tests/fmus/sliding_mass (C, FMI 2.0 and 3.0, co-simulation and Model Exchange, built by
`build_fmu(source=...)` like the bundled one) is a mass on a spring with friction whose two inputs, ``extForce``
and ``force.f``, reach one force, the one set last winning, as in the Dymola 2023x export the issue measured.
Driving only ``extForce`` from a file, cosim must give `fmpy.simulate_fmu`'s answer exactly; setting ``force.f``
to its start value at every step, as cosim did before, gives another answer (shown, so that the test could fail).
"""

from __future__ import annotations

import json
from pathlib import Path

import fmpy
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import cosim
from cosim.cli import main as cli
from cosim.loop.closed_loop import closed_loop
from cosim.plant.build import build_fmu

SOURCE = Path(__file__).parent / "fmus" / "sliding_mass"
DT, DURATION = 0.01, 5.0


@pytest.fixture(scope="module")
def sliding() -> dict[int, Path]:
    return {v: build_fmu(source=SOURCE, fmi_version=f"{v}.0") for v in (2, 3)}


@pytest.fixture(scope="module")
def force(tmp_path_factory) -> tuple[Path, np.ndarray, np.ndarray]:
    """force.csv: extForce as steps between -8 and 8 N, each held half a second (seeded)."""
    t = np.round(np.arange(round(DURATION / DT) + 1) * DT, 12)
    levels = np.random.default_rng(38).uniform(-8.0, 8.0, 11)
    f = levels[np.minimum((t / 0.5 + 1e-9).astype(int), 10)]
    path = tmp_path_factory.mktemp("driven") / "force.csv"
    pd.DataFrame({"time": t, "extForce": f}).to_csv(path, index=False)
    return path, t, f


def _fmpy(path: Path, t: np.ndarray, f: np.ndarray, **options):
    signals = np.array(list(zip(t, f, strict=True)), dtype=[("time", float), ("extForce", float)])
    return fmpy.simulate_fmu(str(path), stop_time=t[-1], output_interval=DT, input=signals,
                             output=["mass.s", "mass.v"], **options)


def _old_rule(path: Path, f: np.ndarray) -> np.ndarray:
    """cosim before issue 38: every input set at every step, force.f (nobody drives it) to its start value."""
    with cosim.FmuPlant(path, dt=DT, outputs=["mass.s", "mass.v"]) as plant:
        assert plant.inputs == ("extForce", "force.f")
        start = plant.get(["force.f"])[0]
        plant.set_inputs([f[0], start])
        return np.vstack([plant.read_outputs(), plant.run(np.column_stack([f[:-1], np.full(len(f) - 1, start)]))])


@pytest.mark.parametrize("version", [2, 3])
def test_a_file_driving_one_of_two_inputs_gives_fmpys_motion(sliding, force, tmp_path, version):
    """`cosim simulate FMU --input-file force.csv --record mass.s,mass.v`: fmpy's positions and speeds to 1e-12
    (here exactly), force.f left to the FMU and said so; the old rule moved the mass otherwise."""
    path, t, f = force
    out = tmp_path / "run.csv"
    done = CliRunner().invoke(cli, ["simulate", str(sliding[version]), "--input-file", str(path), "--record",
                                    "mass.s,mass.v", "-o", str(out), "--json"])
    assert done.exit_code == 0, done.output
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["driven"] == ["extForce"] and summary["left"] == ["force.f"]
    ours = pd.read_csv(out)
    assert list(ours.columns) == ["time", "extForce", "mass.s", "mass.v"]  # force.f was not driven: no column
    theirs = _fmpy(sliding[version], t, f)
    np.testing.assert_allclose(ours["time"], theirs["time"], rtol=0, atol=1e-12)
    for name in ("mass.s", "mass.v"):
        np.testing.assert_allclose(ours[name], theirs[name], rtol=0, atol=1e-12, err_msg=name)
    assert np.std(ours["mass.v"]) == pytest.approx(np.std(theirs["mass.v"]), abs=1e-12)
    # the old rule: force.f set to 0 after extForce at every step cancels the force, the mass only rings down
    old = _old_rule(sliding[version], f)
    assert np.abs(old[:, 1] - theirs["mass.v"]).max() > 1.0
    assert old[:, 1].std() < 0.5 * theirs["mass.v"].std()
    # replaying the record drives what the first run drove, extForce only: the same motion
    again = CliRunner().invoke(cli, ["simulate", str(sliding[version]), "--input-file", str(out), "--record",
                                     "mass.s,mass.v", "-o", str(tmp_path / "again.csv")])
    assert again.exit_code == 0 and "drove extForce; left force.f to the FMU (start 0)" in again.stdout
    np.testing.assert_array_equal(pd.read_csv(tmp_path / "again.csv").to_numpy(), ours.to_numpy())


@pytest.mark.parametrize("version", [2, 3])
def test_model_exchange_leaves_the_other_input_too(sliding, force, version):
    """The same rule as Model Exchange, integrated by FMPy's Euler in both: FMPy's answer exactly, the input held
    over each step in both (FMPy given the steps as repeated times)."""
    _, t, f = force
    ours = cosim.simulate(sliding[version], {"extForce": f}, duration=DURATION, dt=DT, kind="me", solver="euler",
                          outputs=["mass.s", "mass.v"])
    assert ours.meta["left_inputs"] == {"force.f": 0.0} and ours.inputs == ("extForce",)
    theirs = _fmpy(sliding[version], np.repeat(t, 2)[1:], np.repeat(f, 2)[:-1], fmi_type="ModelExchange",
                   solver="Euler")
    rows = [np.nonzero(np.abs(theirs["time"] - ti) <= 1e-9)[0][-1] for ti in ours.time]  # after each time's events
    for name in ("mass.s", "mass.v"):
        np.testing.assert_allclose(ours[name], theirs[name][rows], rtol=0, atol=1e-12, err_msg=name)
    assert np.ptp(ours["mass.s"]) > 0.5  # the force moved it


def test_closed_loop_drives_only_the_controllers_input(sliding):
    """A PID on extForce holds the position at 0.5 m: the loop leaves force.f to the FMU. An open FmuPlant that
    drives force.f too (the old rule) cancels the PID's force, which a note says."""
    from controllers.pid import PID

    pid = PID(kp=400.0, ki=400.0, kd=40.0, tf=0.05, dt=DT, inputs="extForce", outputs="position", u_min=-100.0,
              u_max=100.0)
    res = closed_loop(pid, sliding[3], reference=0.5, duration=5.0, model=None)
    assert res.status == "completed" and res.fmu["position"][-1] == pytest.approx(0.5, abs=1e-3)
    assert "force.f" not in res.fmu.names and res.fmu.meta["left_inputs"] == {"force.f": 0.0}
    with cosim.FmuPlant(sliding[3], dt=DT) as plant:
        old = closed_loop(pid, plant, reference=0.5, duration=5.0, model=None)
    assert abs(old.fmu["position"][-1]) < 0.05  # the force cancelled: the mass rings down to rest
    assert any("drives force.f, which nobody in the loop drives" in note for note in old.notes)
    # validation runs through closed_loop: the same rule, on Model Exchange too
    from cosim.loop.validation import validate

    verdict = validate(sliding[2], pid, "step:amp=0.5,duration=5", ["steady_state_error<=0.002"], model=None,
                       kind="me")
    assert verdict.passed, verdict.reasons
    assert verdict.results[0].fmu.meta["left_inputs"] == {"force.f": 0.0}


def test_fmu_info_says_which_inputs_a_run_drives(sliding, force):
    path = force[0]
    runner = CliRunner()
    plain = runner.invoke(cli, ["fmu", "info", str(sliding[2])])
    assert plain.exit_code == 0 and "a run drives only the inputs it is given" in plain.stdout
    info = json.loads(runner.invoke(cli, ["fmu", "info", str(sliding[2]), "--input-file", str(path), "--json"]).stdout)
    assert info["driven"] == ["extForce"] and info["left"] == ["force.f"]
    text = runner.invoke(cli, ["fmu", "info", str(sliding[3]), "--input", "force.f=3"]).stdout
    assert "a run with these options drives force.f; leaves extForce to the FMU (start value set once)" in text
    bad = runner.invoke(cli, ["fmu", "info", str(sliding[3]), "--input", "extforce=3"])
    assert bad.exit_code == 2 and "has no input named 'extforce'" in bad.stderr and bad.stderr.count("\n") == 1
