"""The bundled servo split as tools split it (fmus/two_mass_servo_split): a motor FMU and a shaft-and-load FMU,
wired by an SSP 1.0 system file and packed by ``build_ssp``.

Real FMUs built from C, no mocks: fmpy's validation of each FMU and of the ``.ssd`` (its XSD), the motor and the
load alone against the one-FMU servo's rows bit for bit, the coupled pair against the one-FMU servo as the
communication step shrinks (a Gauss-Seidel loop written here, and one with FMI 2 input interpolation), against an
independent Gauss-Seidel of the same split linear equations, FMU state save/restore, direct feedthrough of Tc,
and FMI 2 input derivatives against an independent solution.

FmuPlant drives the plain loops; the FMI calls FmuPlant does not make (FMU state, input derivatives) go through
FMPy's slave classes (:func:`slave`).
"""

from __future__ import annotations

import contextlib
import ctypes
import shutil
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.ssp.ssd import read_ssd
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp
from scipy.linalg import expm

import cosim.plant.build
from cosim import FmuPlant
from cosim.errors import FmuNotFoundError
from cosim.plant.build import build_fmu, build_ssp, fmu_source_dir

VERSIONS = ("2.0", "3.0")
COMPONENTS = ("motor", "shaft_load")
SYSTEM = "two_mass_servo_split"
SRC = fmu_source_dir(SYSTEM)

# every effect the split concerns switched on: friction and cogging on the motor, backlash and gravity in the load
MOTOR_EFFECTS = {"Fc": 30.0, "Bm_asym": 20.0, "Tcog": 15.0}
LOAD_EFFECTS = {"backlash": 2e-4, "mgl": 200.0}
STEPS = (1 / 500, 1 / 1000, 1 / 2000, 1 / 4000)


def torque(t: np.ndarray) -> np.ndarray:
    """The test's Tm: a 500 N m step at 50 ms on a 300 N m, 3 Hz sine."""
    return np.where(t >= 0.05, 500.0, 0.0) + 300.0 * np.sin(2 * np.pi * 3.0 * t)


@pytest.fixture(scope="module")
def fmus() -> dict[tuple[str, str], Path]:
    """Each component FMU per FMI version, built from its folder (cached on disk after the first build)."""
    return {(c, v): build_fmu(c, fmi_version=v, source=SRC / c) for c in COMPONENTS for v in VERSIONS}


@pytest.fixture(scope="module")
def servo() -> dict[str, Path]:
    """The one-FMU servo, the reference."""
    return {v: build_fmu("two_mass_servo", fmi_version=v) for v in VERSIONS}


@contextlib.contextmanager
def slave(path: Path, parameters: dict | None = None):
    """An initialised FMPy co-simulation slave of `path` and its value references by name; freed on exit."""
    md = fmpy.read_model_description(str(path))
    unzipped = fmpy.extract(str(path))
    v2 = md.fmiVersion == "2.0"
    fmu = (FMU2Slave if v2 else FMU3Slave)(guid=md.guid, unzipDirectory=unzipped,
                                            modelIdentifier=md.coSimulation.modelIdentifier, instanceName="test")
    vrs = {v.name: v.valueReference for v in md.modelVariables}
    instantiated = False
    try:
        fmu.instantiate()
        instantiated = True
        if v2:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        else:
            fmu.enterInitializationMode(startTime=0.0)
        for name, value in (parameters or {}).items():
            if isinstance(value, int):
                (fmu.setInteger if v2 else fmu.setInt32)([vrs[name]], [value])
            else:
                (fmu.setReal if v2 else fmu.setFloat64)([vrs[name]], [value])
        fmu.exitInitializationMode()
        yield fmu, vrs
    finally:
        if instantiated:
            with contextlib.suppress(Exception):
                fmu.terminate()
            fmu.freeInstance()
        shutil.rmtree(unzipped, ignore_errors=True)


def get(fmu, vrs, names):
    return (fmu.getReal if isinstance(fmu, FMU2Slave) else fmu.getFloat64)([vrs[n] for n in names])


def put(fmu, vrs, values: dict):
    (fmu.setReal if isinstance(fmu, FMU2Slave) else fmu.setFloat64)([vrs[n] for n in values], list(values.values()))


def relative_errors(split: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """max |split - reference| over time, per column, over the reference's range."""
    return np.abs(split - reference).max(axis=0) / np.ptp(reference, axis=0)


def order(errors: list[np.ndarray]) -> np.ndarray:
    """Least-squares slope of -log2(error) against the number of halvings of the step, per column."""
    logs = -np.log2(np.array(errors))
    x = np.arange(len(errors)) - (len(errors) - 1) / 2
    return (x @ (logs - logs.mean(axis=0))) / (x @ x)


# ---------------------------------------------------------------------------------------------------- the files
def test_the_fmi_wrappers_are_one_file_the_two_fmus_share():
    """The two folders have no wrappers of their own: the builder takes the system folder's, packs it with each
    FMU, and a change of it rebuilds both (it is in their cache keys)."""
    from cosim.plant.build import _wrapper

    for version, wrapper in ((2, "fmi2.c"), (3, "fmi3.c")):
        assert (SRC / wrapper).is_file()
        for component in ("motor", "shaft_load"):
            assert not (SRC / component / wrapper).exists() and _wrapper(SRC / component, version) == SRC / wrapper


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("component", COMPONENTS)
def test_each_fmu_builds_and_passes_fmpy_validation(fmus, component, version):
    path = fmus[component, version]
    assert path.name == f"{component}.fmu"
    assert validate_fmu(str(path)) == []
    md = fmpy.read_model_description(str(path))
    cs = md.coSimulation
    assert (md.fmiVersion, cs.modelIdentifier) == (version, component)
    assert cs.canGetAndSetFMUstate and cs.canHandleVariableCommunicationStepSize
    assert not cs.canSerializeFMUstate
    assert (cs.maxOutputDerivativeOrder or 0) == 0
    if version == "2.0":
        assert cs.canInterpolateInputs
    assert md.defaultExperiment.startTime == "0" and md.defaultExperiment.stopTime == "1"
    assert float(md.defaultExperiment.stepSize) == 1e-3
    # units on every Real (the integers ncog and nsub have none in FMI)
    assert [v.name for v in md.modelVariables if v.type in ("Real", "Float64") and not v.unit] == []
    outputs = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs}
    states = sorted(d.variable.derivative.name for d in md.derivatives)
    if component == "motor":
        assert outputs == {"theta_m": [], "omega_m": []} and states == ["omega_m", "theta_m"]
    else:  # Tc answers theta_m and omega_m at once: a master must step the motor first
        assert outputs == {"Tc": ["omega_L", "omega_m", "theta_L", "theta_m"], "theta_L": [], "omega_L": []}
        assert states == ["omega_L", "theta_L"]


@pytest.mark.parametrize("version", VERSIONS)
def test_parameters_are_the_one_fmu_servos(fmus, servo, version):
    """Same names, defaults, units and causality as the bundled servo; together the two FMUs have all of them."""

    def parameters(path):
        md = fmpy.read_model_description(str(path))
        return {v.name: (v.start, v.unit, v.type, v.variability) for v in md.modelVariables
                if v.causality == "parameter"}

    motor, load, whole = (parameters(p) for p in (fmus["motor", version], fmus["shaft_load", version],
                                                   servo[version]))
    assert set(motor) | set(load) == set(whole) and set(motor) & set(load) == {"nsub"}
    for name, declared in {**motor, **load}.items():
        assert declared == whole[name], name


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("component", COMPONENTS)
def test_start_values_in_the_xml_are_the_c_defaults(fmus, component, version):
    path = fmus[component, version]
    md = fmpy.read_model_description(str(path))
    declared = {v.name: float(v.start) for v in md.modelVariables if v.start is not None}
    with FmuPlant(path, dt=1e-3) as plant:
        assert dict(zip(declared, map(float, plant.get(list(declared))), strict=True)) == declared


# ---------------------------------------------------------------------------------------------------- the SSP
@pytest.mark.parametrize("version", VERSIONS)
def test_the_ssp_packs_and_fmpy_reads_it(version, tmp_path):
    path = build_ssp(SYSTEM, fmi_version=version)
    assert path.name == f"{SYSTEM}.ssp" and path.parent.name.startswith(f"{SYSTEM}-fmi{version[0]}-")
    ssd = read_ssd(str(path))  # validates against the SSP 1.0 XSD
    assert ssd.version == "1.0" and ssd.name == SYSTEM
    components = {c.name: c for c in ssd.system.elements}
    assert {n: c.source for n, c in components.items()} == {"motor": "resources/motor.fmu",
                                                            "load": "resources/shaft_load.fmu"}
    wired = {(c.startElement, c.startConnector, c.endElement, c.endConnector) for c in ssd.system.connections}
    assert wired == {("motor", "theta_m", "load", "theta_m"), ("motor", "omega_m", "load", "omega_m"),
                     ("load", "Tc", "motor", "Tc")}
    ends = {(c.endElement, c.endConnector) for c in ssd.system.connections}
    free = sorted(f"{n}.{k.name}" for n, c in components.items() for k in c.connectors
                  if k.kind == "input" and (n, k.name) not in ends)
    assert free == ["load.TL", "motor.Tm"]  # the one-FMU servo's two inputs

    # every connector is a variable of its FMU (the one packed) with that causality and unit; every unit is listed
    with zipfile.ZipFile(path) as zf:
        assert sorted(zf.namelist()) == ["SystemStructure.ssd", "resources/motor.fmu", "resources/shaft_load.fmu"]
        zf.extractall(tmp_path)
    tree = ET.parse(tmp_path / "SystemStructure.ssd")
    ns = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
          "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon"}
    listed_units = {u.get("name") for u in tree.findall("ssd:Units/ssc:Unit", ns)}
    for node in tree.findall(".//ssd:Component", ns):
        md = fmpy.read_model_description(str(tmp_path / node.get("source")))
        assert md.fmiVersion == version
        variables = {v.name: v for v in md.modelVariables}
        connectors = node.findall("ssd:Connectors/ssd:Connector", ns)
        assert {c.get("name") for c in connectors} == {n for n, v in variables.items()
                                                        if v.causality in ("input", "output", "parameter")}
        for c in connectors:
            v = variables[c.get("name")]
            assert c.get("kind") == v.causality, c.get("name")
            real = c.find("ssc:Real", ns)
            if v.type in ("Real", "Float64"):
                assert real is not None and real.get("unit") == v.unit, c.get("name")
                assert v.unit in listed_units
            else:
                assert real is None and c.find("ssc:Integer", ns) is not None, c.get("name")


def test_build_ssp_caches_packs_atomically_and_keys_on_the_ssd(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    path = build_ssp(cache_dir=cache)
    assert path.parent.parent == cache / "fmus" and len(path.parent.name.rsplit("-", 1)[1]) == 16
    assert [p.name for p in path.parent.iterdir()] == [f"{SYSTEM}.ssp"]  # no temporary file left
    components = sorted(p.name.split("-")[0] for p in (cache / "fmus").iterdir() if p != path.parent)
    assert components == ["motor", "shaft_load"]  # each built into the cache like any FMU
    mtime = path.stat().st_mtime_ns
    assert build_ssp(cache_dir=cache) == path and path.stat().st_mtime_ns == mtime  # cached
    assert build_ssp(cache_dir=cache, force=True) == path and path.stat().st_mtime_ns != mtime  # rebuilt
    assert build_ssp(fmi_version="3.0", cache_dir=cache).parent != path.parent

    changed = tmp_path / SYSTEM
    shutil.copytree(SRC, changed)
    with open(changed / "SystemStructure.ssd", "a") as fh:
        fh.write("<!-- a change -->\n")
    monkeypatch.setattr(cosim.plant.build, "fmu_source_dir", lambda name: changed)
    again = build_ssp(cache_dir=cache)
    assert again.parent != path.parent
    assert zipfile.ZipFile(again).read("resources/motor.fmu") == zipfile.ZipFile(path).read("resources/motor.fmu")


def test_a_system_and_a_single_fmu_are_told_apart():
    assert (fmu_source_dir(SYSTEM) / "SystemStructure.ssd").is_file()
    with pytest.raises(FmuNotFoundError, match="build_ssp"):
        build_fmu(SYSTEM)
    with pytest.raises(FmuNotFoundError, match="build_fmu"):
        build_ssp("two_mass_servo")


# ---------------------------------------------------------------------------------------------------- the physics
@pytest.mark.parametrize("version", VERSIONS)
def test_each_fmu_alone_is_its_row_of_the_one_fmu_servo_bit_for_bit(fmus, servo, version):
    """With KL = BL = 0 the one-FMU servo's shaft torque is exactly 0: its motor row is the motor FMU with Tc = 0,
    its load row the shaft_load FMU, to the last bit (same terms, same RK4, same delay history). (The load row is
    compared without the delay: the one-FMU servo splits its whole RK4 step where a delayed input takes effect.)"""
    dt, n = 1e-3, 400
    t = np.arange(n) * dt
    tm = torque(t) + 40.0 * np.sign(np.sin(2 * np.pi * 7 * t))
    tl = 150.0 * np.cos(2 * np.pi * 2 * t)
    motor_parameters = {**MOTOR_EFFECTS, "Fs": 10.0, "Tmax": 600.0, "Toffset": 5.0, "delay": 0.0123}
    load_parameters = {"mgl": 300.0, "KL": 0.0, "BL": 0.0}
    start = {"theta_m": 0.3, "omega_m": -0.2, "theta_L": 1.1, "omega_L": 0.4}

    def whole(delay):
        parameters = {**motor_parameters, **load_parameters, "delay": delay}
        with FmuPlant(servo[version], dt=dt, parameters=parameters, start=start) as plant:
            return plant.run(np.column_stack([tm, tl]))

    with FmuPlant(fmus["motor", version], dt=dt, parameters=motor_parameters, inputs=["Tm", "Tc"],
                  start={k: start[k] for k in ("theta_m", "omega_m")}) as motor:
        motor_alone = motor.run(np.column_stack([tm, np.zeros(n)]))
    with FmuPlant(fmus["shaft_load", version], dt=dt, parameters=load_parameters, inputs=["TL", "theta_m"],
                  outputs=["theta_L", "omega_L"], start={k: start[k] for k in ("theta_L", "omega_L")}) as load:
        load_alone = load.run(np.column_stack([tl, np.full(n, 123.0)]))  # no stiffness: theta_m does nothing
    with_delay, without = whole(motor_parameters["delay"]), whole(0.0)
    assert np.array_equal(motor_alone, with_delay[:, :2])
    assert np.array_equal(load_alone, without[:, 2:])
    assert np.ptp(motor_alone[:, 1]) > 0.1 and np.ptp(load_alone[:, 1]) > 0.1  # both sides moved
    assert not np.array_equal(with_delay[:, :2], without[:, :2])  # the delay mattered


def gauss_seidel(motor: FmuPlant, load: FmuPlant, tm: np.ndarray) -> np.ndarray:
    """The plain loop: the motor steps with the last Tc, then the load with the motor's new angle and speed; Tc is
    read after. Returns [theta_m, omega_m, theta_L, omega_L] after each step."""
    tc = load.read_outputs()[0]  # Tc at the start, from the inputs and states then (direct feedthrough)
    out = np.empty((len(tm), 4))
    for k, u in enumerate(tm.tolist()):
        theta_m, omega_m = motor.step([u, tc])
        tc, theta_l, omega_l = load.step([theta_m, omega_m, 0.0])
        out[k] = theta_m, omega_m, theta_l, omega_l
    return out


def split_and_whole(fmus, servo, version, dt, motor_parameters, load_parameters, duration=1.0):
    """The coupled pair under :func:`gauss_seidel` and the one-FMU servo, with the same Tm held over each step."""
    tm = torque(np.arange(round(duration / dt)) * dt)
    with FmuPlant(fmus["motor", version], dt=dt, parameters=motor_parameters, inputs=["Tm", "Tc"]) as motor, \
            FmuPlant(fmus["shaft_load", version], dt=dt, parameters=load_parameters,
                     inputs=["theta_m", "omega_m", "TL"], outputs=["Tc", "theta_L", "omega_L"]) as load, \
            FmuPlant(servo[version], dt=dt, parameters={**motor_parameters, **load_parameters}) as whole:
        split = gauss_seidel(motor, load, tm)
        reference = whole.run(np.column_stack([tm, np.zeros_like(tm)]))
    return split, reference


@pytest.mark.parametrize("version", VERSIONS)
def test_gauss_seidel_converges_to_the_one_fmu_servo_at_first_order(fmus, servo, version):
    """The plain loop's error halves with the step (first order), every effect on.

    Measured (FMI 2 and 3 alike), max error over 1 s / range, [theta_m, omega_m, theta_L, omega_L]:
    dt = 1/500: [0.685 1.334 0.687 1.246], 1/1000: [0.313 0.529 0.313 0.501], 1/2000: [0.154 0.256 0.154 0.258],
    1/4000: [0.076 0.149 0.076 0.125]; fitted order [1.05 1.05 1.05 1.09].
    The constant is large because the coupling is stiff: over a step the load sees the motor's angle of the step's
    end while the motor felt the shaft torque of its start, a momentum KL*h^2*omega/2 per step that adds up to
    KL*h*theta/2 (59 N m s at h = 1/4000 over 1 s: 12 % of the speed), an error of the scheme, not of the FMUs
    (test_the_split_fmus_are_the_split_equations). Interpolating the inputs removes it
    (test_interpolated_inputs_converge_at_second_order).
    """
    errors = []
    for dt in STEPS:
        split, reference = split_and_whole(fmus, servo, version, dt, MOTOR_EFFECTS, LOAD_EFFECTS)
        errors.append(relative_errors(split, reference))
    measured = order(errors)
    assert np.all((measured > 0.8) & (measured < 1.3)), (measured, errors)
    assert np.all(errors[-1] < 0.2), errors[-1]  # 0.08 (angles) to 0.15 (motor speed)


def test_the_split_fmus_are_the_split_equations(fmus):
    """The plain loop on the linear plant against an independent Gauss-Seidel of the same split equations, each
    side advanced exactly over a step (matrix exponential of its linear ODE with its inputs held): the loops agree
    to RK4's error (measured 1.4e-11 of the range), so what differs from the one-FMU servo is the coupling
    scheme's."""
    jm, jl, kl, bm, bl = 250.0, 1000.0, 2.5e6, 50.0, 500.0
    dt, n = 1e-3, 1000

    def exact_zoh(a, b):
        m = np.zeros((a.shape[0] + b.shape[1],) * 2)
        m[:a.shape[0], :a.shape[0]], m[:a.shape[0], a.shape[0]:] = a, b
        e = expm(m * dt)
        return e[:a.shape[0], :a.shape[0]], e[:a.shape[0], a.shape[0]:]

    # motor: x = [theta_m, omega_m], u = [Tm, Tc]; load: x = [theta_L, omega_L], u = [theta_m, omega_m]
    pm, qm = exact_zoh(np.array([[0, 1], [0, -bm / jm]]), np.array([[0, 0], [1 / jm, -1 / jm]]))
    pl, ql = exact_zoh(np.array([[0, 1], [-kl / jl, -bl / jl]]), np.array([[0, 0], [kl / jl, bl / jl]]))
    tm = torque(np.arange(n) * dt)
    xm, xl, tc, expected = np.zeros(2), np.zeros(2), 0.0, np.empty((n, 4))
    for k in range(n):
        xm = pm @ xm + qm @ [tm[k], tc]
        xl = pl @ xl + ql @ xm
        tc = kl * (xm[0] - xl[0]) + bl * (xm[1] - xl[1])
        expected[k] = *xm, *xl
    with FmuPlant(fmus["motor", "2.0"], dt=dt, inputs=["Tm", "Tc"]) as motor, \
            FmuPlant(fmus["shaft_load", "2.0"], dt=dt, inputs=["theta_m", "omega_m", "TL"],
                     outputs=["Tc", "theta_L", "omega_L"]) as load:
        split = gauss_seidel(motor, load, tm)
    assert np.all(relative_errors(split, expected) < 1e-9)


def interpolated_loop(motor, mv, load, lv, servo_fmu, sv, dt, tm):
    """Gauss-Seidel with FMI 2 input interpolation: the load sees the motor's angle and speed move linearly from the
    step's start to its end (fmi2SetRealInputDerivatives), the motor a Tc extrapolated from its last two values."""
    out, reference = np.empty((len(tm), 4)), np.empty((len(tm), 4))
    tc_last = tc = get(load, lv, ["Tc"])[0]
    theta_m, omega_m = get(motor, mv, ["theta_m", "omega_m"])
    for k, u in enumerate(tm.tolist()):
        t, h = k * dt, (k + 1) * dt - k * dt
        put(motor, mv, {"Tm": u, "Tc": tc})
        motor.setRealInputDerivatives([mv["Tc"]], [1], [(tc - tc_last) / dt])
        motor.doStep(t, h)
        theta_m1, omega_m1 = get(motor, mv, ["theta_m", "omega_m"])
        put(load, lv, {"theta_m": theta_m, "omega_m": omega_m, "TL": 0.0})
        load.setRealInputDerivatives([lv["theta_m"], lv["omega_m"]], [1, 1],
                                     [(theta_m1 - theta_m) / h, (omega_m1 - omega_m) / h])
        load.doStep(t, h)
        put(load, lv, {"theta_m": theta_m1, "omega_m": omega_m1})  # the inputs at the step's end: Tc then
        tc_last, (tc, theta_l, omega_l) = tc, get(load, lv, ["Tc", "theta_L", "omega_L"])
        theta_m, omega_m = theta_m1, omega_m1
        out[k] = theta_m, omega_m, theta_l, omega_l
        put(servo_fmu, sv, {"Tm": u, "TL": 0.0})
        servo_fmu.doStep(t, h)
        reference[k] = get(servo_fmu, sv, ["theta_m", "omega_m", "theta_L", "omega_L"])
    return out, reference


def test_interpolated_inputs_converge_at_second_order(fmus, servo):
    """canInterpolateInputs at work: the same coupling with linear input interpolation is second order and at
    dt = 1/4000 within 1e-3 of the speeds' range (measured 2.1e-4 motor, 5.8e-5 load; fitted order 1.8-1.9)."""
    errors = []
    for dt in STEPS:
        tm = torque(np.arange(round(1.0 / dt)) * dt)
        with slave(fmus["motor", "2.0"], MOTOR_EFFECTS) as (motor, mv), \
                slave(fmus["shaft_load", "2.0"], LOAD_EFFECTS) as (load, lv), \
                slave(servo["2.0"], {**MOTOR_EFFECTS, **LOAD_EFFECTS}) as (whole, sv):
            split, reference = interpolated_loop(motor, mv, load, lv, whole, sv, dt, tm)
        errors.append(relative_errors(split, reference))
    measured = order(errors)
    assert np.all(measured > 1.6), (measured, errors)
    assert np.all(errors[-1][[1, 3]] < 1e-3), errors[-1]


# ---------------------------------------------------------------------------------------------------- FMI features
def save_run_restore_run(fmu, vrs, inputs, outputs, v2):
    """Save the FMU state, run 100 steps, restore it, run the same 100 steps again; both runs' outputs."""
    dt = 1e-3
    t0 = get(fmu, vrs, ["time"])[0]
    state = fmu.getFMUstate() if v2 else fmu.getFMUState()
    runs = []
    for _ in range(2):
        y = []
        for k in range(100):
            put(fmu, vrs, {name: value[k] for name, value in inputs.items()})
            if v2 and "Tm" in inputs:  # an input derivative is part of the state of a step
                fmu.setRealInputDerivatives([vrs["Tm"]], [1], [1000.0 * np.cos(k)])
            fmu.doStep(t0 + k * dt, dt)
            y.append(get(fmu, vrs, outputs))
        runs.append(np.array(y))
        if v2:
            fmu.setFMUstate(state)
        else:
            fmu.setFMUState(state)
        assert get(fmu, vrs, ["time"])[0] == t0
    if v2:
        fmu.freeFMUstate(state)
    else:
        fmu.freeFMUState(state)
    return runs


@pytest.mark.parametrize("version", VERSIONS)
def test_fmu_state_round_trips_with_the_delay_history(fmus, version):
    v2 = version == "2.0"
    k = np.arange(150)
    tm = 400.0 * np.sin(0.37 * k) + 200.0 * (k % 7 == 0)
    # a delay of 12.3 steps keeps ~13 inputs in the history's ring of 64: 150 steps wrap it twice, so a saved
    # state that shared the ring's memory would be overwritten
    with slave(fmus["motor", version], {**MOTOR_EFFECTS, "delay": 0.0123}) as (motor, mv):
        for i in range(50):
            put(motor, mv, {"Tm": tm[i], "Tc": 50.0 * np.cos(i)})
            motor.doStep(i * 1e-3, 1e-3)
        first, second = save_run_restore_run(motor, mv, {"Tm": tm[50:], "Tc": 80.0 * np.sin(k[50:])},
                                             ["theta_m", "omega_m"], v2)
    assert np.array_equal(first, second) and np.ptp(first[:, 1]) > 1e-3
    with slave(fmus["shaft_load", version], LOAD_EFFECTS) as (load, lv):
        put(load, lv, {"theta_m": 1e-3})
        load.doStep(0.0, 1e-3)
        first, second = save_run_restore_run(load, lv, {"theta_m": 1e-3 * np.sin(0.1 * k), "omega_m": np.cos(k),
                                                        "TL": np.full(150, 30.0)}, ["Tc", "theta_L", "omega_L"], v2)
    assert np.array_equal(first, second) and np.ptp(first[:, 0]) > 100.0


@pytest.mark.parametrize("version", VERSIONS)
def test_a_state_of_the_other_fmu_is_refused(fmus, version):
    v2 = version == "2.0"
    with slave(fmus["motor", version]) as (motor, _), slave(fmus["shaft_load", version]) as (load, _):
        state = motor.getFMUstate() if v2 else motor.getFMUState()
        with pytest.raises(FMICallException):
            load.setFMUstate(state) if v2 else load.setFMUState(state)
        motor.freeFMUstate(state) if v2 else motor.freeFMUState(state)


@pytest.mark.parametrize("version", VERSIONS)
def test_tc_answers_new_inputs_before_a_step(fmus, version):
    kl, bl, b = 2.5e6, 500.0, 5e-5
    with FmuPlant(fmus["shaft_load", version], dt=1e-3, parameters={"backlash": b}, start={"theta_L": 1e-4},
                  inputs=["theta_m", "omega_m", "TL"], outputs=["Tc", "theta_L", "omega_L"]) as load:
        assert load.read_outputs()[0] == pytest.approx(kl * (-1e-4 + b), rel=1e-12)  # after initialisation
        load.set_inputs([3e-4, 0.02, 0.0])  # before the first step
        assert load.read_outputs()[0] == pytest.approx(kl * (2e-4 - b) + bl * 0.02, rel=1e-12)
        _, theta_l, omega_l = load.step([3e-4, 0.02, 0.0])
        load.set_inputs([-2e-4, -0.05, 0.0])  # between steps
        tc = load.read_outputs()[0]
        assert tc == pytest.approx(kl * (-2e-4 - theta_l + b) + bl * (-0.05 - omega_l), rel=1e-12)


def test_input_derivatives_drive_the_step_and_the_delay_history(fmus):
    """FMI 2 input interpolation against an independent solution: Tm given as a ramp (its value at each
    communication point and its slope), delayed by 2.5 steps, on the motor with viscous friction only and a
    linearly varying Tc: Jm*w' = r*(t - delay) - Bm*w - (c0 + c1*t). A slope holds for one step only."""
    jm, bm, delay, r, c0, c1, dt, n = 250.0, 50.0, 0.0025, 4e4, 20.0, 3e3, 1e-3, 12

    def rhs(t, x):
        return [x[1], (r * max(t - delay, 0.0) - bm * x[1] - (c0 + c1 * t)) / jm]

    exact = solve_ivp(rhs, (0, n * dt), [0.0, 0.0], t_eval=np.arange(1, n + 1) * dt, rtol=1e-12, atol=1e-15,
                      method="DOP853", first_step=1e-5, max_step=delay / 4).y.T
    with slave(fmus["motor", "2.0"], {"delay": delay}) as (motor, mv):
        y = []
        for k in range(n):
            put(motor, mv, {"Tm": r * k * dt, "Tc": c0 + c1 * k * dt})
            motor.setRealInputDerivatives([mv["Tm"], mv["Tc"]], [1, 1], [r, c1])
            motor.doStep(k * dt, dt)
            y.append(get(motor, mv, ["theta_m", "omega_m"]))
        # the slopes were not set again: the inputs are held over this step
        put(motor, mv, {"Tm": r * n * dt, "Tc": 0.0})
        motor.doStep(n * dt, dt)
        held = get(motor, mv, ["omega_m"])[0]
        # an order beyond 1 is ignored with a warning (fmi2Warning = 1), the value references are checked
        vr, order, value = (ctypes.c_uint32 * 1)(mv["Tm"]), (ctypes.c_int * 1)(2), (ctypes.c_double * 1)(1.0)
        assert motor.fmi2SetRealInputDerivatives(motor.component, vr, 1, order, value) == 1
        with pytest.raises(FMICallException):
            motor.setRealInputDerivatives([mv["theta_m"]], [1], [1.0])
    assert np.abs(np.array(y) - exact).max(axis=0) / np.abs(exact).max(axis=0) == pytest.approx([0, 0], abs=1e-10)
    # over the held step Tc = 0 is held (its slope was not set again), while the delayed Tm still ramps: what acts
    # now was given 2.5 steps ago, with its slope, and the history keeps it
    last = solve_ivp(lambda t, x: [x[1], (r * (t - delay) - bm * x[1]) / jm], (n * dt, (n + 1) * dt), y[-1],
                     rtol=1e-12, atol=1e-15, method="DOP853").y[1, -1]
    assert held == pytest.approx(last, rel=1e-9)
