"""A plant of several FMUs (issue 40): systems read from OSP and SSP files and from Python, checked against their
FMUs, and run by the master whose order of accuracy is stated (cosim.plant.system_plant).

The FMUs are the quarter truck of the Open Simulation Platform (../shared/fmus/quarter-truck: two FMUs of another
tool, MIT licence), read where they lie; files a test writes go to its temporary folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim.errors import FmuNotFoundError, InvalidSettingError, UnknownVariableError
from cosim.plant.system_plant import SystemPlant
from cosim.plant.system_structure import Component, Connection, System, read_system
from cosim.plant.system_wiring import wire

TRUCK = Path(__file__).resolve().parents[2] / "shared" / "fmus" / "quarter-truck"
pytestmark = pytest.mark.skipif(not (TRUCK / "Chassis.fmu").exists(), reason="../shared/fmus/quarter-truck missing")

SETTINGS = {"mass": 400.0, "solverType": "Euler", "timeStep": 1e-5}


def truck(**connection_options) -> System:
    """The quarter truck as the OSP file wires it, written in Python."""
    return System(
        components={"chassis": Component(TRUCK / "Chassis.fmu", SETTINGS),
                    "wheel": Component(TRUCK / "Wheel.fmu", {**SETTINGS, "mass": 40.0})},
        connections=[Connection("chassis.velocity", "wheel.in_vel", **connection_options),
                     ("wheel.out_spring_damper_f", "chassis.force")])


def final_positions(system, dt: float, duration: float = 1.0, wheel: str = "wheel", **master) -> np.ndarray:
    with SystemPlant(system, dt=dt, outputs=["chassis.position", f"{wheel}.position"], **master) as plant:
        return plant.run(np.zeros((int(round(duration / dt)), 0)))[-1]


def test_the_osp_file_reads_as_the_system_it_wires():
    s = read_system(TRUCK / "OspSystemStructure.xml")
    assert sorted(s.components) == ["chassis", "wheel"]
    assert s.components["wheel"].parameters == {**SETTINGS, "mass": 40.0}
    assert [(c.start, c.end) for c in s.connections] == [("chassis.velocity", "wheel.in_vel"),
                                                          ("wheel.out_spring_damper_f", "chassis.force")]
    assert s.dt == pytest.approx(1e-4)
    w = wire(s)
    assert w.inputs == ()  # both inputs are connected
    assert "wheel.out_tire_f" in w.outputs and "chassis.velocity" in w.outputs
    # the FMUs declare no output dependencies: a possible loop, not a refused one
    assert w.loops == () and len(w.possible_loops) == 1


def test_the_osp_file_and_its_python_description_run_alike():
    from_file = final_positions(read_system(TRUCK / "OspSystemStructure.xml"), 2e-3)
    assert np.array_equal(from_file, final_positions(truck(), 2e-3))
    with SystemPlant(truck(), dt=2e-3) as plant:  # the bindings reach the FMUs
        assert plant.get(["wheel.mass", "chassis.mass", "wheel.solverType"]) == [40.0, 400.0, "Euler"]


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_the_quarter_truck_converges_as_the_step_shrinks(algorithm):
    """Against a run at a step 16 times finer: the error falls with the step, at first order for Jacobi without
    extrapolation, and linear extrapolation lowers it tenfold at least. These FMUs declare their positions, speeds
    and forces discrete, which the default master holds: ``hold_discrete=False`` extrapolates them. (The truck's
    tyre leaves and meets the ground, a kink that caps what extrapolation can win: the orders the master states
    are measured on the smooth split servo, tests/test_split_servo_system.py and benchmarks/bench_coupling.py.)"""
    reference = final_positions(truck(), 1.25e-4, algorithm="jacobi", extrapolation=2, hold_discrete=False)
    errors = {order: [np.max(np.abs(final_positions(truck(), dt, algorithm=algorithm, extrapolation=order,
                                                    hold_discrete=False) - reference))
                      for dt in (4e-3, 2e-3, 1e-3)] for order in (0, 1)}
    for order in (0, 1):
        assert errors[order][0] > errors[order][1] > errors[order][2], (order, errors)
    assert all(e1 < e0 / 10 for e0, e1 in zip(errors[0], errors[1], strict=True)) if algorithm == "jacobi" else True
    if algorithm == "jacobi":
        measured = np.log2(np.array(errors[0][:-1]) / np.array(errors[0][1:]))
        assert np.all((measured > 0.8) & (measured < 1.3)), (errors, measured)


def test_a_bare_ssd_with_units_a_parameter_set_and_a_nested_system(tmp_path):
    """An SSD (not zipped) beside an .ssv: the wheel inside a nested system reached through its connectors, its
    mass from the parameter set, and a connection whose units convert (m/s -> km/h: factor 3.6)."""
    (tmp_path / "wheel.ssv").write_text("""<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="w">
  <ssv:Parameters><ssv:Parameter name="mass"><ssv:Real value="40"/></ssv:Parameter>
  <ssv:Parameter name="solverType"><ssv:String value="Euler"/></ssv:Parameter>
  <ssv:Parameter name="timeStep"><ssv:Real value="1e-5"/></ssv:Parameter></ssv:Parameters>
</ssv:ParameterSet>""")
    (tmp_path / "SystemStructure.ssd").write_text(f"""<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
  xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="truck">
 <ssd:System name="truck">
  <ssd:Elements>
   <ssd:Component name="chassis" source="{TRUCK / 'Chassis.fmu'}">
    <ssd:Connectors>
     <ssd:Connector name="velocity" kind="output"><ssc:Real unit="m/s"/></ssd:Connector>
     <ssd:Connector name="force" kind="input"><ssc:Real/></ssd:Connector>
    </ssd:Connectors>
    <ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>
     <ssv:ParameterSet version="1.0" name="c"><ssv:Parameters>
      <ssv:Parameter name="mass"><ssv:Real value="400"/></ssv:Parameter>
      <ssv:Parameter name="solverType"><ssv:String value="Euler"/></ssv:Parameter>
      <ssv:Parameter name="timeStep"><ssv:Real value="1e-5"/></ssv:Parameter>
     </ssv:Parameters></ssv:ParameterSet>
    </ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>
   </ssd:Component>
   <ssd:System name="axle">
    <ssd:Connectors>
     <ssd:Connector name="v" kind="input"><ssc:Real unit="km/h"/></ssd:Connector>
     <ssd:Connector name="f" kind="output"><ssc:Real/></ssd:Connector>
    </ssd:Connectors>
    <ssd:Elements>
     <ssd:Component name="wheel" source="{TRUCK / 'Wheel.fmu'}">
      <ssd:Connectors>
       <ssd:Connector name="in_vel" kind="input"><ssc:Real unit="km/h"/></ssd:Connector>
       <ssd:Connector name="out_spring_damper_f" kind="output"><ssc:Real/></ssd:Connector>
      </ssd:Connectors>
      <ssd:ParameterBindings><ssd:ParameterBinding source="wheel.ssv"/></ssd:ParameterBindings>
     </ssd:Component>
    </ssd:Elements>
    <ssd:Connections>
     <ssd:Connection startConnector="v" endElement="wheel" endConnector="in_vel"/>
     <ssd:Connection startElement="wheel" startConnector="out_spring_damper_f" endConnector="f"/>
    </ssd:Connections>
   </ssd:System>
  </ssd:Elements>
  <ssd:Connections>
   <ssd:Connection startElement="chassis" startConnector="velocity" endElement="axle" endConnector="v"/>
   <ssd:Connection startElement="axle" startConnector="f" endElement="chassis" endConnector="force"/>
  </ssd:Connections>
 </ssd:System>
 <ssd:Units>
  <ssc:Unit name="m/s"><ssc:BaseUnit m="1" s="-1"/></ssc:Unit>
  <ssc:Unit name="km/h"><ssc:BaseUnit m="1" s="-1" factor="0.2777777777777778"/></ssc:Unit>
 </ssd:Units>
</ssd:SystemStructureDescription>""")
    s = read_system(tmp_path / "SystemStructure.ssd")
    assert sorted(s.components) == ["axle.wheel", "chassis"]
    assert s.components["axle.wheel"].parameters == {"mass": 40.0, "solverType": "Euler", "timeStep": 1e-5}
    w = wire(s)
    link = next(lk for lk in w.links if lk.end == ("axle.wheel", "in_vel"))
    assert link.start == ("chassis", "velocity") and link.factor == pytest.approx(3.6, rel=1e-12)
    converted = final_positions(s, 2e-3, wheel="axle.wheel")
    by_hand = System(components={"chassis": Component(TRUCK / "Chassis.fmu", SETTINGS),
                                 "axle.wheel": Component(TRUCK / "Wheel.fmu", {**SETTINGS, "mass": 40.0})},
                     connections=[Connection("chassis.velocity", "axle.wheel.in_vel", factor=3.6),
                                  ("axle.wheel.out_spring_damper_f", "chassis.force")])
    with SystemPlant(by_hand, dt=2e-3, outputs=["chassis.position", "axle.wheel.position"]) as plant:
        expected = plant.run(np.zeros((500, 0)))[-1]
    assert np.allclose(converted, expected, rtol=1e-12, atol=0)
    assert not np.allclose(converted, final_positions(truck(), 2e-3), rtol=1e-3)  # the factor matters

    # the same units left undefined: refused in one line, naming both
    (tmp_path / "SystemStructure.ssd").write_text(
        (tmp_path / "SystemStructure.ssd").read_text().replace('name="km/h"', 'name="kmh"'))
    with pytest.raises(InvalidSettingError, match=r"units that differ with no conversion: chassis.velocity is in "
                                                  r"m/s, axle.wheel.in_vel in km/h \(km/h is not defined"):
        wire(read_system(tmp_path / "SystemStructure.ssd"))


def test_bad_systems_are_refused_in_one_line(tmp_path):
    with pytest.raises(InvalidSettingError, match="input wheel.in_vel is connected twice"):
        System({"chassis": TRUCK / "Chassis.fmu", "wheel": TRUCK / "Wheel.fmu"},
               [("chassis.velocity", "wheel.in_vel"), ("chassis.position", "wheel.in_vel")])
    with pytest.raises(InvalidSettingError, match="'axle.in_vel' names no component of the system"):
        System({"chassis": TRUCK / "Chassis.fmu", "wheel": TRUCK / "Wheel.fmu"}, [("chassis.velocity", "axle.in_vel")])
    with pytest.raises(UnknownVariableError, match="has no variable in_velocity"):
        wire(System({"chassis": TRUCK / "Chassis.fmu", "wheel": TRUCK / "Wheel.fmu"},
                    [("chassis.velocity", "wheel.in_velocity")]))
    with pytest.raises(InvalidSettingError, match="chassis.force is an input, not an output"):
        wire(System({"chassis": TRUCK / "Chassis.fmu", "wheel": TRUCK / "Wheel.fmu"},
                    [("chassis.force", "wheel.in_vel")]))
    osp = (TRUCK / "OspSystemStructure.xml").read_text().replace('source="Wheel.fmu"', 'source="Wheels.fmu"')
    (tmp_path / "OspSystemStructure.xml").write_text(osp.replace('source="Chassis.fmu"',
                                                                 f'source="{TRUCK / "Chassis.fmu"}"'))
    with pytest.raises(FmuNotFoundError, match="simulator wheel: its FMU Wheels.fmu is missing"):
        read_system(tmp_path / "OspSystemStructure.xml")
    with pytest.raises(InvalidSettingError, match="algorithm='newton'"):
        SystemPlant(truck(), dt=1e-3, algorithm="newton")
    with pytest.raises(InvalidSettingError, match="dt=None: give the communication step"):
        SystemPlant(truck())


def _cosim(*args: str, cwd: Path) -> tuple[int, str, str]:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True, text=True, timeout=120,
                          cwd=cwd)
    return proc.returncode, proc.stdout, proc.stderr


def test_the_cli_describes_and_simulates_a_system(tmp_path):
    """`cosim fmu info` and `cosim simulate` on the OSP file; with --json, stdout is the JSON alone although these
    FMUs print banners from C."""
    import json

    osp = str(TRUCK / "OspSystemStructure.xml")
    code, out, err = _cosim("fmu", "info", osp, "--json", cwd=tmp_path)
    assert code == 0, err
    info = json.loads(out)
    assert [c["name"] for c in info["components"]] == ["chassis", "wheel"]
    assert info["connections"][0] == {"from": "chassis.velocity", "to": "wheel.in_vel", "factor": 1.0, "offset": 0.0}
    assert info["loops"] == [] and info["possible_loops"] == [["chassis.velocity", "wheel.in_vel",
                                                               "wheel.out_spring_damper_f", "chassis.force"]]
    code, out, err = _cosim("simulate", osp, "--duration", "0.5", "--dt", "1e-3", "--set", "wheel.mass=50",
                            "--record", "chassis.position,wheel.position,wheel.mass", "-o", "run.csv", "--json",
                            cwd=tmp_path)
    assert code == 0, err
    summary = json.loads(out)
    assert "MODEL INFO" in err  # the FMUs' banners, moved off stdout
    assert summary["samples"] == 501 and summary["kind"] == "system"
    assert summary["final"]["wheel.mass"] == 50.0
    with SystemPlant(truck(), dt=1e-3, parameters={"wheel.mass": 50.0},
                     outputs=["chassis.position", "wheel.position"]) as plant:
        expected = plant.run(np.zeros((500, 0)))[-1]
    assert [summary["final"]["chassis.position"], summary["final"]["wheel.position"]] == expected.tolist()
    code, out, err = _cosim("simulate", osp, "--duration", "0.5", "--dt", "1e-3", "--set", "axle.mass=50",
                            "-o", "bad.csv", cwd=tmp_path)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "'axle.mass' names no component" in err
    assert not (tmp_path / "bad.csv").exists()


@pytest.mark.parametrize(("algorithm", "extrapolation", "multiples", "hold"),
                         [("jacobi", 0, None, False), ("jacobi", 2, None, False), ("gauss-seidel", 0, None, False),
                          ("gauss-seidel", 1, None, False), ("gauss-seidel", 1, {"wheel": 2}, False),
                          ("jacobi", 1, {"chassis": 3}, False), ("gauss-seidel", 1, None, True)])
def test_the_c_loop_gives_the_python_masters_bits(algorithm, extrapolation, multiples, hold):
    """The compiled master (the default where it can run) and the Python master: the same outputs to the bit.
    (Not after a reset: these FMUs' fmi2Reset leaves something behind, and their first step after it differs from
    one run of the same code to the next; tests/test_split_servo_system.py checks resets on FMUs that reset.)"""
    runs = []
    for engine in ("c", "python"):
        with SystemPlant(truck(), dt=1e-3, algorithm=algorithm, extrapolation=extrapolation, engine=engine,
                         step_multiples=multiples, hold_discrete=hold) as plant:
            assert plant.engine == engine
            first = plant.run(np.zeros((150, 0)))
            steps = np.array([plant.step([]) for _ in range(50)])
            runs.append((first, steps, plant.time))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2] == pytest.approx(0.2)
    with SystemPlant(truck(), dt=1e-3) as plant:
        assert plant.engine == "c" and plant.engine_note is None


def _libcosim_positions(execution, until: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """libcosim's run of a system: the time and the chassis and wheel positions every 20 of its steps (its time
    series observer stops an ECCO run after one step: read the last values as it goes instead)."""
    from libcosimpy.CosimObserver import CosimObserver

    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    index = {s.name.decode(): s.index for s in execution.slave_infos()}
    refs = {n: {v.name.decode(): v.reference for v in execution.slave_variables(i)}["position"]
            for n, i in index.items()}
    t, y = [], []
    while not t or t[-1] < until:
        assert execution.step(20)
        t.append(execution.status().current_time * 1e-9)
        y.append([observer.last_real_values(index[n], [refs[n]])[0] for n in ("chassis", "wheel")])
    return np.array(t), np.array(y)


@pytest.mark.parametrize("source", ["OspSystemStructure.xml", "SystemStructure.ssd"])
def test_the_quarter_truck_agrees_with_libcosims_run_of_the_same_file(source, tmp_path):
    """libcosim (the Open Simulation Platform's engine, where its wheel installs) runs the same file: its ECCO
    adaptive master on the OSP file, its fixed step on the SSD; cosim's default master at 1e-4 s is within 1e-3 of
    the positions' range of it over the whole second."""
    pytest.importorskip("libcosimpy")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.ERROR)
    if source == "OspSystemStructure.xml":
        path = TRUCK / source
        execution = CosimExecution.from_osp_config_file(str(path))
    else:
        path = tmp_path / source
        path.write_text(SSD_TRUCK)
        execution = CosimExecution.from_ssp_file(str(tmp_path), step_size=int(1e5))  # 1e-4 s in nanoseconds
    t, theirs = _libcosim_positions(execution)
    with SystemPlant(path, dt=1e-4, outputs=["chassis.position", "wheel.position"]) as plant:
        ours = np.vstack([plant.read_outputs(), plant.run(np.zeros((10_001, 0)))])
    grid = 1e-4 * np.arange(len(ours))
    at_theirs = np.c_[np.interp(t, grid, ours[:, 0]), np.interp(t, grid, ours[:, 1])]
    assert len(t) > 400 and t[-1] >= 1.0
    assert np.all(np.max(np.abs(at_theirs - theirs), axis=0) < 1e-3 * np.ptp(ours, axis=0))


SSD_TRUCK = f"""<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
  xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="truck">
 <ssd:System name="truck">
  <ssd:Elements>
   <ssd:Component name="chassis" source="{TRUCK / 'Chassis.fmu'}">
    <ssd:Connectors>
     <ssd:Connector name="velocity" kind="output"><ssc:Real/></ssd:Connector>
     <ssd:Connector name="force" kind="input"><ssc:Real/></ssd:Connector>
    </ssd:Connectors>
    <ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>
     <ssv:ParameterSet version="1.0" name="c"><ssv:Parameters>
      <ssv:Parameter name="mass"><ssv:Real value="400"/></ssv:Parameter>
      <ssv:Parameter name="solverType"><ssv:String value="Euler"/></ssv:Parameter>
      <ssv:Parameter name="timeStep"><ssv:Real value="1e-5"/></ssv:Parameter>
     </ssv:Parameters></ssv:ParameterSet>
    </ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>
   </ssd:Component>
   <ssd:Component name="wheel" source="{TRUCK / 'Wheel.fmu'}">
    <ssd:Connectors>
     <ssd:Connector name="in_vel" kind="input"><ssc:Real/></ssd:Connector>
     <ssd:Connector name="out_spring_damper_f" kind="output"><ssc:Real/></ssd:Connector>
    </ssd:Connectors>
    <ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>
     <ssv:ParameterSet version="1.0" name="w"><ssv:Parameters>
      <ssv:Parameter name="mass"><ssv:Real value="40"/></ssv:Parameter>
      <ssv:Parameter name="solverType"><ssv:String value="Euler"/></ssv:Parameter>
      <ssv:Parameter name="timeStep"><ssv:Real value="1e-5"/></ssv:Parameter>
     </ssv:Parameters></ssv:ParameterSet>
    </ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>
   </ssd:Component>
  </ssd:Elements>
  <ssd:Connections>
   <ssd:Connection startElement="chassis" startConnector="velocity" endElement="wheel" endConnector="in_vel"/>
   <ssd:Connection startElement="wheel" startConnector="out_spring_damper_f" endElement="chassis" endConnector="force"/>
  </ssd:Connections>
 </ssd:System>
</ssd:SystemStructureDescription>"""


def _ssd(components: dict[str, str], connections: list[tuple[str, str, str, str]], units: str = "") -> str:
    """A minimal SystemStructure.ssd: components by source, connections (start element, connector, end element,
    connector); `units` the connectors' extra XML, by component."""
    elements = "".join(f'<ssd:Component name="{n}" source="{src}"/>' for n, src in components.items())
    wires = "".join(f'<ssd:Connection startElement="{a}" startConnector="{b}" endElement="{c}" endConnector="{d}"/>'
                    for a, b, c, d in connections)
    return ('<?xml version="1.0" encoding="UTF-8"?><ssd:SystemStructureDescription '
            'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" '
            'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="s">'
            f'<ssd:System name="s"><ssd:Elements>{units or elements}</ssd:Elements>'
            f'<ssd:Connections>{wires}</ssd:Connections></ssd:System></ssd:SystemStructureDescription>')


def _cosim_here(argv: list[str], cwd: Path) -> tuple[int, str, str]:
    """A command through the `cosim` entry point's click group in this process (a process each: 8 s more)."""
    import os

    from click.testing import CliRunner

    from cosim.cli import main

    here = Path.cwd()
    os.chdir(cwd)
    try:
        result = CliRunner().invoke(main, argv, catch_exceptions=False)
    finally:
        os.chdir(here)
    return result.exit_code, result.stdout, result.stderr


def test_bad_system_files_get_one_line_exit_2_and_nothing_written(tmp_path):
    import sys
    import zipfile

    sys.path.insert(0, str(Path(__file__).parent))
    from reference_fmus import reference_fmus

    feed = reference_fmus(2)["Feedthrough"]
    chassis, wheel = TRUCK / "Chassis.fmu", TRUCK / "Wheel.fmu"
    elsewhere = tmp_path / "Elsewhere.fmu"  # the wheel without its Linux binary
    with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(elsewhere, "w") as dst:
        for info in src.infolist():
            if not info.filename.startswith("binaries/linux"):
                dst.writestr(info, src.read(info.filename))
    truck_wires = [("chassis", "velocity", "wheel", "in_vel")]
    units = (f'<ssd:Component name="chassis" source="{chassis}"><ssd:Connectors><ssd:Connector name="velocity" '
             'kind="output"><ssc:Real unit="m/s"/></ssd:Connector></ssd:Connectors></ssd:Component>'
             f'<ssd:Component name="wheel" source="{wheel}"><ssd:Connectors><ssd:Connector name="in_vel" '
             'kind="input"><ssc:Real unit="km/h"/></ssd:Connector></ssd:Connectors></ssd:Component>')
    cases = {
        "its FMU Missing.fmu is missing": _ssd({"chassis": chassis, "wheel": "Missing.fmu"}, truck_wires),
        "a connector of the wrong type: a.Int32_output is Integer, b.Float64_continuous_input is Real":
            _ssd({"a": feed, "b": feed}, [("a", "Int32_output", "b", "Float64_continuous_input")]),
        "units that differ with no conversion: chassis.velocity is in m/s, wheel.in_vel in km/h":
            _ssd({}, truck_wires, units=units),
        "input wheel.in_vel is connected twice":
            _ssd({"chassis": chassis, "wheel": wheel}, [*truck_wires, ("chassis", "position", "wheel", "in_vel")]),
        "has no variable in_velocity": _ssd({"chassis": chassis, "wheel": wheel},
                                            [("chassis", "velocity", "wheel", "in_velocity")]),
        "Elsewhere.fmu has no binary for this platform (linux64; it has: win32, win64)":
            _ssd({"chassis": chassis, "wheel": elsewhere}, truck_wires),
    }
    for k, (expected, text) in enumerate(cases.items()):
        folder = tmp_path / f"case{k}"
        folder.mkdir()
        (folder / "SystemStructure.ssd").write_text(text)
        for argv in (["simulate", "SystemStructure.ssd", "--duration", "0.1", "--dt", "1e-3", "-o", "out.csv"],
                     ["fmu", "info", "SystemStructure.ssd", "--json"]):
            code, out, err = _cosim_here(argv, folder)
            assert code == 2 and len(err.strip().splitlines()) == 1 and expected in err, (expected, err)
            assert err.startswith("error: component ") or "wheel.in_vel" in err or "a.Int32" in err, err
            assert out == "" and sorted(p.name for p in folder.iterdir()) == ["SystemStructure.ssd"]
