"""Diagnosis on FMU data with one undeclared effect switched on (known answers), on data without one, and bad input.

Each FMU case: 2 s of a 1-40 Hz multisine torque from rest, 5 % measurement noise, a linear SINDYc model
identified first with the settings `cosim diagnose` uses by default (``BASE_SETTINGS``: every linear term,
kinematic rows found from the names and the data, no hand-given kinematics); the figures before/after are the
free run against the noise-free simulation.
"""

import warnings

import numpy as np
import pytest
from diagnose_fixtures import coulomb_mass

from cosim import build_fmu, simulate
from cosim.data.trajectory import Trajectory
from cosim.diagnose.diagnosis import BASE_SETTINGS, diagnose
from cosim.errors import DataError, UnknownVariableError
from cosim.identify.model import IdentifiedModel
from cosim.identify.sindyc import IdentificationWarning, SINDYc
from cosim.study.paper import STATES, STUDY_DT

DURATION = round(2.0 / STUDY_DT) * STUDY_DT
MULTISINE = "multisine:amp=1000,fmin=1,fmax=40"
#: A slew: the multisine on a 1000 N m bias, so that the angles turn through several radians (cogging and
#: gravity are periodic in an angle: from rest the angles move 0.04 rad and sin(12 theta) looks linear)
SLEW = MULTISINE + ",offset=1000"


_RUNS: dict = {}


def run(parameters, seed=0, excitation=MULTISINE, duration=2.0):
    """Diagnose FMU data with `parameters` switched on (once per worker: tests that ask for the same case share
    the report, which nothing mutates)."""
    key = (tuple(sorted(parameters.items())), seed, excitation, duration)
    if key not in _RUNS:
        _RUNS[key] = _run(parameters, seed, excitation, duration)
    return _RUNS[key]


def _run(parameters, seed, excitation, duration):
    """Diagnose FMU data with `parameters` switched on; the linear model is identified from a multisine from
    rest on the same plant (from the data themselves when they are that experiment)."""
    fmu = build_fmu()
    steps = round(duration / STUDY_DT)
    clean = simulate(fmu, {"Tm": excitation}, duration=steps * STUDY_DT, dt=STUDY_DT, parameters=parameters)
    data = clean.with_noise(0.05, seed=seed)
    identification = data if excitation == MULTISINE else simulate(
        fmu, {"Tm": MULTISINE}, duration=round(2.0 / STUDY_DT) * STUDY_DT, dt=STUDY_DT,
        parameters=parameters).with_noise(0.05, seed=seed + 1)
    with warnings.catch_warnings():  # an offset's drift makes the plain identification unstable: expected
        warnings.simplefilter("ignore", IdentificationWarning)
        model = SINDYc(**BASE_SETTINGS).fit(identification, states=list(STATES), inputs=["Tm"]).model_
    return diagnose(model, data, reference=clean)


@pytest.mark.slow
@pytest.mark.parametrize(("parameters", "effect", "attached", "key", "true", "tolerance", "excitation", "duration"), [
    ({"Fc": 100.0}, "coulomb_friction", "omega_m", "Fc", 100.0, 0.05, MULTISINE, 2.0),
    ({"Bm_asym": 300.0}, "viscous_asymmetry", "omega_m", "viscous_asymmetry", 300.0, 0.10, MULTISINE, 2.0),
    ({"Tmax": 700.0}, "saturation", "Tm", "level", 700.0, 0.10, MULTISINE, 2.0),
    # 3 s: the stiction shows only at the speed reversals (2 s: Fs 10.7 % low)
    ({"Fs": 150.0, "vs": 0.02}, "stribeck", "omega_m", "Fs", 150.0, 0.10, MULTISINE, 3.0),
    ({"delay": 0.002}, "delay", "Tm", "delay_s", 0.002, 0.10, MULTISINE, 2.0),
    ({"backlash": 5e-5}, "backlash", "theta_m-theta_L", "half_width", 5e-5, 0.10, MULTISINE, 2.0),
    ({"Toffset": 100.0}, "offset", "constant", "offset_omega_m", 100.0, 0.10, MULTISINE, 2.0),
    # the linear model identified on the multisine runs at 130 % NRMSE on the slew
    ({"Tcog": 150.0}, "cogging", "theta_m", "amplitude_omega_m", 150.0, 0.10, SLEW, 3.0),
    pytest.param({"mgl": 500.0}, "gravity", "theta_L", "amplitude_omega_L", 500.0, 0.10, SLEW, 3.0,
                 marks=pytest.mark.xfail(strict=True, reason="issue 13, default path: gravity on theta_m wins the "
                                         "round in-sample but fails the held-out check (17.8 -> 49.1 %: fitted on "
                                         "the half that swings 0-0.9 rad, the sine trades against the spring and "
                                         "the constant); nothing is named")),
])
def test_the_undeclared_effect_ranks_first_with_its_parameter(parameters, effect, attached, key, true, tolerance,
                                                              excitation, duration):
    report = run(parameters, excitation=excitation, duration=duration)
    assert report.effects, report.message
    first = report.effects[0]
    assert (first.name, first.attached_to) == (effect, attached), report.message
    assert first.parameters[key] == pytest.approx(true, rel=tolerance)
    assert 0.0 < first.uncertainty[key] < tolerance * abs(true)
    assert report.after["nrmse_pct"] * 3 <= report.before["nrmse_pct"]
    assert report.after["white"]
    data = report.to_dict()
    assert data["effects"][0]["name"] == effect and data["effects"][0]["parameters"][key] == first.parameters[key]
    assert {"nrmse_pct", "r2"} <= set(data["before"]) and {"nrmse_pct", "r2"} <= set(data["after"])


@pytest.mark.slow
def test_cogging_period_is_found():  # the run of the cogging case above, shared (run() keeps it)
    report = run({"Tcog": 150.0}, excitation=SLEW, duration=3.0)
    cogging = [e for e in report.effects if e.name == "cogging"]
    assert cogging, report.message
    assert cogging[0].parameters["periods"] == 12.0  # the FMU's ncog


@pytest.mark.slow
def test_two_effects_at_once_are_both_found():
    report = run({"Fc": 100.0, "delay": 0.002})
    found = {e.name: e for e in report.effects}
    assert {"coulomb_friction", "delay"} <= set(found), report.message
    assert found["coulomb_friction"].parameters["Fc"] == pytest.approx(100.0, rel=0.05)
    assert found["delay"].parameters["delay_s"] == pytest.approx(0.002, rel=0.10)
    assert report.after["nrmse_pct"] * 3 <= report.before["nrmse_pct"] and report.after["white"]
    names, model = report.steps[-1]
    assert names == tuple(e.name for e in report.effects) and model is report.model_after


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(20))
def test_no_effect_no_claim(seed):
    report = run({}, seed=seed)
    assert report.effects == (), report.message
    assert report.message.startswith("no effect found")


def test_report_files(tmp_path):
    data, linear = coulomb_mass()  # quick, and the evidence plot must show the step at zero speed
    report = diagnose(linear, data)
    assert [e.name for e in report.effects] == ["coulomb_friction"]
    # 1 % above the truth, not closer: the diagnosis decimates the record by 2 and holds the switch's smoothing
    # velocity at the speed step the decimated record shows at a reversal (2.0 mm/s, the sharpest switch a free
    # run of one step per sample resolves; issue 39), where the truth's is 1 mm/s
    assert report.effects[0].parameters["Fc"] == pytest.approx(1.0, rel=0.02)
    html = report.write_report(tmp_path / "diagnosis.html")
    text = html.read_text()
    assert "coulomb_friction" in text and text.count("data:image/png;base64") >= 3


def test_bad_input_is_refused():
    t = np.arange(100) * 0.01
    model = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u"), coef=np.array([[1.0, 0.0],
                                                                                               [-1.0, 1.0]]))
    short = Trajectory.from_arrays(t, {"x": np.zeros(100), "v": np.zeros(100), "u": np.sin(t)})
    with pytest.raises(DataError, match="at least 200"):
        diagnose(model, short)
    t = np.arange(400) * 0.01
    flat = Trajectory.from_arrays(t, {"x": np.zeros(400), "v": np.zeros(400), "u": np.ones(400)})
    with pytest.raises(DataError, match="constant"):
        diagnose(model, flat)
    moving = Trajectory.from_arrays(t, {"x": np.zeros(400), "v": np.zeros(400), "u": np.sin(t)})
    with pytest.raises(UnknownVariableError, match="no effect named 'frction'"):
        diagnose(model, moving, effects="frction")
    with pytest.raises(UnknownVariableError, match="'u'"):
        diagnose(model, Trajectory.from_arrays(t, {"x": np.zeros(400), "v": np.zeros(400)}))


@pytest.mark.slow
def test_cli_diagnose_bad_input_is_one_line(tmp_path):
    from click.testing import CliRunner

    from cosim.cli import main

    result = CliRunner().invoke(main, ["diagnose", str(tmp_path / "none.mat"), "--state", "qm", "--input", "u"])
    assert result.exit_code == 2 and result.stderr.startswith("error:") and "Traceback" not in result.output
