"""A controller as an FMU in a system (issue 40 item 5): the PID exported by ``cosim export ctrl.json -o pid.fmu``,
wired beside the split servo's two FMUs, closes the loop cosim's own closed loop closes with the Python PID: the
same outputs within 1e-9 of their range (they agree to the bit on this machine)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from controllers.pid import PID
from controllers.pid.fmu import export_fmu
from cosim.loop.closed_loop import closed_loop
from cosim.plant.build import build_ssp
from cosim.plant.system_plant import SystemPlant
from cosim.plant.system_structure import System, read_system

DT = 1 / 2257
# gains `cosim design pid` gives on a model identified from the split servo (the README tour's path on it)
GAINS = {"kp": 856508.8067025508, "ki": 7072677.226075028, "kd": 64521.41888030824, "b": 0.15}


def pid(**changes) -> PID:
    settings = {**GAINS, "dt": DT, "inputs": "motor.Tm", "outputs": ["motor.omega_m", "load.theta_L"],
                "velocity": "motor.omega_m", "u_min": -5000.0, "u_max": 5000.0, **changes}
    return PID(**settings)


def reference(t: np.ndarray) -> np.ndarray:
    return 0.01 * (t >= 0.05)


@pytest.mark.parametrize("changes", [{}, {"anti_windup": "clamping", "du_max": 200.0},
                                     {"velocity": None, "outputs": ["load.theta_L"], "kd": 10.0, "n": 8.0}])
def test_the_exported_pid_in_a_system_closes_the_python_loop(tmp_path, changes):
    controller = pid(**changes)
    fmu = export_fmu(controller, tmp_path / "pid.fmu")
    plant = read_system(build_ssp())
    wires = [(c.start, c.end) for c in plant.connections]
    wires += [("pid.motor.Tm", "motor.Tm"), ("load.theta_L", "pid.load.theta_L")]
    if controller.velocity:
        wires.append(("motor.omega_m", "pid.motor.omega_m"))
    system = System({**plant.components, "pid": fmu}, wires)
    n = int(round(1.0 / DT))
    t = DT * np.arange(n + 1)
    names = ["motor.theta_m", "motor.omega_m", "load.theta_L", "load.omega_L", "pid.motor.Tm"]
    with SystemPlant(system, dt=DT, outputs=names) as loop:
        assert loop.inputs == ("load.TL", "pid.setpoint") and loop.engine == "c"
        loop.set_inputs([0.0, reference(t[:1])[0]])
        fmu_loop = np.vstack([loop.read_outputs(), loop.run(np.c_[np.zeros(n), reference(t[:-1])])])
    python_loop = closed_loop(controller, build_ssp(), duration=1.0, reference=reference, model=None).fmu
    ours = np.c_[[python_loop[x] for x in names[:4]]].T
    assert ours.shape == fmu_loop[:, :4].shape
    scale = np.ptp(ours, axis=0)
    assert np.all(np.max(np.abs(fmu_loop[:, :4] - ours), axis=0) <= 1e-9 * scale)
    # the command: the Python loop's row k is the PID's output at t_k for the set-point r(t_k); the system's row k is
    # read after the step to t_k, for the set-point step() held over that step, r(t_k-1) (as any FMU's output with
    # direct feedthrough is: FmuPlant.step's too). They are the same sample where the set-point did not change.
    command = python_loop["motor.Tm"]
    same = np.r_[True, reference(t[1:]) == reference(t[:-1])][:-1]
    assert np.count_nonzero(~same) == 1
    assert np.max(np.abs(fmu_loop[:-1, 4] - command[:-1])[same]) <= 1e-9 * np.ptp(command)
    assert np.ptp(ours[:, 2]) > 0.009  # the load moved to the set-point: the loop did something
    if changes:
        return
    # the same three FMUs wired by an SSP file of their own (as another tool would get them): the same run
    from cosim.plant.system_structure import split_name

    elements = "".join(f'<ssd:Component name="{n}" source="{c.source}"/>'
                       for n, c in {**plant.components, "pid": system.components["pid"]}.items())
    comps = {"motor": None, "load": None, "pid": None}
    lines = "".join('<ssd:Connection startElement="{}" startConnector="{}" endElement="{}" endConnector="{}"/>'.format(
        *split_name(a, comps), *split_name(b, comps)) for a, b in wires)
    (tmp_path / "SystemStructure.ssd").write_text(
        '<?xml version="1.0" encoding="UTF-8"?><ssd:SystemStructureDescription '
        'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" version="1.0" name="loop">'
        f'<ssd:System name="loop"><ssd:Elements>{elements}</ssd:Elements><ssd:Connections>{lines}'
        '</ssd:Connections></ssd:System></ssd:SystemStructureDescription>')
    with SystemPlant(tmp_path / "SystemStructure.ssd", dt=DT, outputs=names) as loop:
        loop.set_inputs([0.0, reference(t[:1])[0]])
        from_file = np.vstack([loop.read_outputs(), loop.run(np.c_[np.zeros(n), reference(t[:-1])])])
    assert np.array_equal(from_file, fmu_loop)


def test_the_exported_pid_passes_fmpys_validation_and_the_cli_exports_it(tmp_path, monkeypatch):
    from click.testing import CliRunner
    from fmpy.validation import validate_fmu

    from cosim.cli import main

    monkeypatch.chdir(tmp_path)
    pid().save(tmp_path / "pid.json")
    result = CliRunner().invoke(main, ["export", "pid.json", "-o", "pid.fmu", "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["written"] == ["pid.fmu"]
    assert validate_fmu(str(tmp_path / "pid.fmu")) == []
    split_servo_mpc().save(tmp_path / "mpc.json")
    result = CliRunner().invoke(main, ["export", "mpc.json", "-o", "mpc.fmu"], catch_exceptions=False)
    assert result.exit_code == 0 and "the mpc as an FMI 2.0 co-simulation FMU" in result.stdout, result.stderr
    assert validate_fmu(str(tmp_path / "mpc.fmu")) == []
    # a controller file exported to what only a model can be: one line, exit 2, nothing written
    result = CliRunner().invoke(main, ["export", "pid.json", "-o", "pid.mat"], catch_exceptions=False)
    assert result.exit_code == 2 and "a controller exports as an FMU" in result.stderr
    assert not (tmp_path / "pid.mat").exists()


@pytest.mark.parametrize("mass_version", ["2.0", "3.0"])
def test_a_model_exchange_component_beside_the_pid_fmu_closes_the_python_loop(tmp_path, mass_version):
    """Mixed interfaces and FMI versions in one system: the test's sliding mass as a Model Exchange FMU
    (integrated by FMPy's CVode inside the plant room) under the exported PID (FMI 2.0 co-simulation): the loop of
    cosim's closed loop with the Python PID on the same FMU."""
    from pathlib import Path

    from cosim import FmuPlant
    from cosim.plant.build import build_fmu
    from cosim.plant.system_structure import Component

    mass = build_fmu("sliding_mass", source=Path(__file__).parent / "fmus" / "sliding_mass",
                     fmi_version=mass_version)
    controller = PID(kp=40.0, ki=20.0, kd=4.0, dt=0.01, inputs="extForce", outputs="mass.s", u_min=-50.0,
                     u_max=50.0)
    fmu = export_fmu(controller, tmp_path / "pid.fmu")
    system = System({"mass": Component(mass, kind="me"), "pid": fmu},
                    [("mass.mass.s", "pid.mass.s"), ("pid.extForce", "mass.extForce")])
    n = 300
    t = 0.01 * np.arange(n + 1)
    with SystemPlant(system, dt=0.01, inputs=["pid.setpoint"], outputs=["mass.mass.s", "mass.mass.v"]) as loop:
        assert loop.engine == "python" and "Model Exchange" in loop.engine_note
        loop.set_inputs([reference(t[:1])[0]])
        fmu_loop = np.vstack([loop.read_outputs(), loop.run(reference(t[:-1])[:, None])])
    with FmuPlant(mass, dt=0.01, kind="me", inputs=["extForce"], outputs=["mass.s", "mass.v"]) as plant:
        python_loop = closed_loop(controller, plant, duration=3.0, reference=reference, model=None).fmu
    ours = np.c_[python_loop["mass.s"], python_loop["mass.v"]]
    assert np.max(np.abs(fmu_loop - ours)) <= 1e-9 * np.ptp(ours)
    assert python_loop["mass.s"][-1] > 0.007  # the loop took the mass most of the way to its set-point


def split_servo_mpc(**options):
    """An MPC of the load angle on the servo's own linear model, named as the split servo names its signals."""
    import control

    from controllers.mpc import MPC
    from cosim.export.statespace import control_label
    from cosim.study.paper import two_mass_matrices

    a, b = two_mass_matrices()
    states = [control_label(s) for s in ("motor.theta_m", "motor.omega_m", "load.theta_L", "load.omega_L")]
    plant = control.ss(a, b[:, :1], np.eye(4), np.zeros((4, 1)), states=states, inputs=[control_label("motor.Tm")],
                       outputs=states)
    return MPC(plant, dt=DT, horizon=20, inputs=["motor.Tm"], outputs=["motor.theta_m", "load.theta_L"],
               tracked=["load.theta_L"], u_min=-5000.0, u_max=5000.0, **options)


@pytest.mark.parametrize("friction", [0.0, 100.0])
def test_the_exported_mpc_in_a_system_closes_the_python_loop(tmp_path, friction):
    """The MPC's FMU (its step's generated C and DAQP) beside the split servo: the loop of cosim's closed loop with
    the Python MPC within 1e-6 of the range (with and without the motor's friction the model lacks)."""
    from fmpy.validation import validate_fmu

    from controllers.mpc.fmu import export_fmu as export_mpc

    controller = split_servo_mpc()
    fmu = export_mpc(controller, tmp_path / "mpc.fmu")
    assert validate_fmu(str(fmu)) == []
    plant = read_system(build_ssp())
    wires = [(c.start, c.end) for c in plant.connections]
    wires += [("mpc.motor.Tm", "motor.Tm"), ("motor.theta_m", "mpc.motor.theta_m"),
              ("load.theta_L", "mpc.load.theta_L")]
    system = System({**plant.components, "mpc": fmu}, wires)
    n = int(round(0.6 / DT))
    t = DT * np.arange(n + 1)
    names = ["motor.theta_m", "motor.omega_m", "load.theta_L", "load.omega_L"]
    with SystemPlant(system, dt=DT, outputs=names, parameters={"motor.Fc": friction}) as loop:
        assert loop.inputs == ("load.TL", "mpc.r_load.theta_L")
        loop.set_inputs([0.0, reference(t[:1])[0]])
        fmu_loop = np.vstack([loop.read_outputs(), loop.run(np.c_[np.zeros(n), reference(t[:-1])])])
    python_loop = closed_loop(controller, build_ssp(), duration=0.6, reference=reference, model=None,
                              parameters={"motor.Fc": friction}).fmu
    ours = np.c_[[python_loop[x] for x in names]].T
    assert np.all(np.max(np.abs(fmu_loop - ours), axis=0) <= 1e-6 * np.ptp(ours, axis=0))
    assert np.ptp(ours[:, 2]) > 0.009
