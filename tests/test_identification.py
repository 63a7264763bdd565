"""SINDYc identification against known answers: the bundled two-mass servo FMU and small models."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from cosim import build_fmu, simulate
from cosim.data.trajectory import Trajectory
from cosim.errors import DataError, InvalidSettingError, UnknownVariableError
from cosim.identify.model import IdentifiedModel
from cosim.identify.sindyc import DIFFERENTIATION_METHODS, IdentificationWarning, SINDYc
from cosim.study.cases import study_case
from cosim.study.paper import STUDY_DT, STUDY_TABLE1, STUDY_X0

STATES = ["theta_m", "omega_m", "theta_L", "omega_L"]
KINEMATICS = {"theta_m": "omega_m", "theta_L": "omega_L"}
EXCITATIONS = {"square": "square:amp=500,freq=1", "sine": "sine:amp=500,freq=5"}


def true_matrices() -> tuple[np.ndarray, np.ndarray]:
    """A and B of the FMU's linear two-mass model from its default parameters (fmus/two_mass_servo/README.md)."""
    jm, jl, kl, bm, bl = 250.0, 1000.0, 2.5e6, 50.0, 500.0
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-kl / jm, -(bm + bl) / jm, kl / jm, bl / jm],
                  [0.0, 0.0, 0.0, 1.0],
                  [kl / jl, bl / jl, -kl / jl, -bl / jl]])
    b = np.array([[0.0], [1.0 / jm], [0.0], [0.0]])
    return a, b


@pytest.fixture(scope="module")
def clean() -> dict[str, Trajectory]:
    """The study's FMU records: 5 s at 2257 Hz from the study's initial state, both excitations."""
    steps = round(5.0 / STUDY_DT)
    return {name: simulate(build_fmu(), {"Tm": spec}, duration=steps * STUDY_DT, dt=STUDY_DT, start=STUDY_X0)
            for name, spec in EXCITATIONS.items()}


def _linear_plant() -> IdentifiedModel:
    return IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("x", "v", "u"),
                           coef=np.array([[0.0, 1.0, 0.0], [-4.0, -0.4, 2.0]]))


def _smooth_record(n: int = 400, dt: float = 0.02) -> Trajectory:
    t = np.arange(n) * dt
    u = (np.sin(1.3 * t) + 0.5 * np.sin(3.1 * t))[:, None]
    return _linear_plant().simulate([1.0, 0.0], u, dt=dt).to_trajectory()


# ------------------------------------------------------------------------------------------ clean FMU data
@pytest.mark.parametrize("excitation", list(EXCITATIONS))
@pytest.mark.parametrize("settings", [{}, {"differentiation": "zoh"}], ids=["integral-auto", "zoh-auto"])
def test_noise_free_coefficients_match_the_fmu(clean, excitation, settings):
    """0 % noise: every coefficient of A and B within 0.5 % of the FMU's (measured: ~3e-8 relative), kinematic
    rows exactly [0 1 0 0], zeros where the plant has none, no constant."""
    est = SINDYc(**settings).fit(clean[excitation], inputs=["Tm"])
    a_true, b_true = true_matrices()
    a, b, c = est.model_.linear_matrices()
    nonzero = a_true != 0
    np.testing.assert_allclose(a[nonzero], a_true[nonzero], rtol=5e-3)
    np.testing.assert_allclose(b[1], b_true[1], rtol=5e-3)
    assert np.all(a[~nonzero] == 0.0) and np.all(b[[0, 2, 3]] == 0.0) and np.all(c == 0.0)
    np.testing.assert_allclose(a[[0, 2]], a_true[[0, 2]], atol=1e-6)
    # far tighter than required: the method is exact up to O(dt^4) / the FMU's own RK4 error
    np.testing.assert_allclose(a[nonzero], a_true[nonzero], rtol=1e-6)
    assert est.model_.meta["stable"] is True
    assert est.score(clean[excitation]) > 0.999999


def test_constant_input_warns_and_is_left_out():
    """A record that drives TL at a constant 0 (an input nobody drives is not recorded: driven here on purpose)."""
    steps = round(1.0 / STUDY_DT)
    data = simulate(build_fmu(), {"Tm": EXCITATIONS["square"], "TL": 0.0}, duration=steps * STUDY_DT, dt=STUDY_DT,
                    start=STUDY_X0)
    with pytest.warns(IdentificationWarning, match="'TL' is constant"):
        est = SINDYc(kinematics=KINEMATICS).fit(data)
    assert est.inputs_ == ("Tm",)
    assert est.model_.meta["data"]["dropped_inputs"] == ["TL"]


def test_kinematics_fix_rows_exactly(clean):
    est = SINDYc(kinematics=KINEMATICS, include_constant=False).fit(clean["sine"], inputs=["Tm"])
    coef = dict(zip(est.terms_, est.coef_[0], strict=True))
    assert coef == {"theta_m": 0.0, "omega_m": 1.0, "theta_L": 0.0, "omega_L": 0.0, "Tm": 0.0}
    assert est.model_.meta["kinematics"] == KINEMATICS


def test_several_records_at_once(clean):
    est = SINDYc().fit([clean["square"], clean["sine"]], inputs=["Tm"])
    a_true, _ = true_matrices()
    np.testing.assert_allclose(est.model_.linear_matrices()[0], a_true, rtol=1e-6, atol=1e-6)
    assert est.model_.meta["data"]["records"] == 2


def test_positions_only_derive_velocities(clean):
    """Only the angles are measured; the speeds are derived by a smoothing differentiator."""
    positions = clean["square"].select(["Tm", "theta_m", "theta_L"])
    est = SINDYc(velocities={"omega_m": "theta_m", "omega_L": "theta_L"}).fit(positions, states=STATES)
    a_true, b_true = true_matrices()
    a, b, _ = est.model_.linear_matrices()
    nonzero = a_true != 0
    np.testing.assert_allclose(a[nonzero], a_true[nonzero], rtol=2e-3)
    np.testing.assert_allclose(b[1], b_true[1], rtol=2e-3)
    assert est.model_.meta["kinematics"] == KINEMATICS
    assert est.score(clean["square"]) > 0.999


# ------------------------------------------------------------------------------------------ library
def test_polynomial_library_finds_state_input_cross_term():
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "x*u", "u"), coef=np.array([[-1.0, 0.5, 1.0]]))
    t = np.arange(3000) * 0.01
    u = (np.sin(0.7 * t) + 0.5 * np.sign(np.sin(2.3 * t)))[:, None]
    data = model.simulate([0.5], u, dt=0.01).to_trajectory()
    est = SINDYc(library="polynomial", degree=2).fit(data)
    assert est.terms_ == ("1", "x", "u", "x**2", "x*u", "u**2")
    got = dict(zip(est.terms_, est.coef_[0], strict=True))
    assert got["x"] == pytest.approx(-1.0, rel=1e-5)
    assert got["x*u"] == pytest.approx(0.5, rel=1e-5)
    assert got["u"] == pytest.approx(1.0, rel=1e-5)
    assert got["1"] == got["x**2"] == got["u**2"] == 0.0


def test_user_terms_are_added_and_exported_as_expressions():
    model = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u", "tanh(v/0.1)"),
                            coef=np.array([[1.0, 0.0, 0.0, 0.0], [-0.5, -2.0, 1.0, -0.3]]))
    t = np.arange(4000) * 0.005
    u = np.sign(np.sin(0.9 * t))[:, None]
    data = model.simulate([0.0, 0.0], u, dt=0.005).to_trajectory()
    est = SINDYc(terms=["tanh(v/0.1)"], include_constant=False).fit(data)
    assert "tanh(v/0.1)" in est.terms_
    row = dict(zip(est.terms_, est.coef_[1], strict=True))
    assert row["tanh(v/0.1)"] == pytest.approx(-0.3, rel=1e-4)
    assert row["v"] == pytest.approx(-0.5, rel=1e-4)
    loaded = IdentifiedModel.from_json(est.model_.to_json())
    np.testing.assert_array_equal(loaded.coef, est.coef_)


def test_constant_found_by_the_regression_is_kept():
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("1", "x", "u"), coef=np.array([[0.3, -1.0, 1.0]]))
    u = np.sign(np.sin(np.arange(2000) * 0.01))[:, None]
    est = SINDYc().fit(model.simulate([0.0], u, dt=0.01).to_trajectory())
    assert dict(zip(est.terms_, est.coef_[0], strict=True))["1"] == pytest.approx(0.3, rel=1e-5)
    assert est.model_.linear_matrices()[2][0] == pytest.approx(0.3, rel=1e-5)


# every registered differentiation method, with the options it needs and the accuracy it reaches on a
# smooth 2-state record sampled coarsely (dt = 0.02 s, 400 samples)
METHOD_CASES = {
    "integral": ({}, 1e-6),
    "zoh": ({}, 1e-9),
    "finite_difference": ({"order": 4}, 5e-3),
    "smoothed_finite_difference": ({}, 5e-3),
    "savitzky_golay": ({"left": 0.1, "right": 0.1, "order": 3}, 5e-3),
    "spline": ({"s": 1e-8}, 5e-3),
    "kalman": ({"alpha": 1e-8}, 5e-3),
    "kernel": ({"sigma": 0.04, "lmbd": 1e-6}, 5e-3),
    "trend_filtered": ({"order": 0, "alpha": 1e-4}, 0.4),   # a Lasso smoother: coarse
    "spectral": ({}, 0.4),                                   # assumes periodic data: edge errors
}


def test_every_method_has_a_case():
    assert set(METHOD_CASES) == set(DIFFERENTIATION_METHODS)


@pytest.mark.parametrize("method", list(METHOD_CASES))
def test_differentiation_methods_known_answer(method):
    options, tol = METHOD_CASES[method]
    est = SINDYc(differentiation=method, differentiation_options=options, threshold=0.05).fit(_smooth_record())
    truth = np.hstack([np.zeros((2, 1)), _linear_plant().coef])  # terms 1, x, v, u
    np.testing.assert_allclose(est.coef_, truth, atol=tol * 4.0)
    assert est.model_.meta["equation_error"]["method"] == method


# ------------------------------------------------------------------------------------------ bad input
def test_unknown_column_lists_available(clean):
    with pytest.raises(UnknownVariableError, match="no column 'speed'.*available: Tm, theta_m"):
        SINDYc().fit(clean["square"], states=["theta_m", "speed"], inputs=["Tm"])


def test_too_few_samples_says_how_many(clean):
    short = clean["sine"].slice(0.0, 30 * STUDY_DT)
    with pytest.raises(DataError, match=r"31 samples for 6 terms; at least 60 are needed"):
        SINDYc().fit(short, inputs=["Tm"])


def test_nan_in_data_names_column_and_time(clean):
    record = clean["sine"]
    values = record.values.copy()
    values[100, record.names.index("omega_L")] = np.nan
    bad = replace(record)
    object.__setattr__(bad, "values", values)  # a Trajectory refuses NaN; an array passed around may not
    with pytest.raises(DataError, match=r"'omega_L'.*nan at t=0\.0443"):
        SINDYc().fit(bad, inputs=["Tm"])


def test_nan_in_simulation_inputs(clean):
    est = SINDYc().fit(clean["sine"], inputs=["Tm"])
    u = np.ones((10, 1))
    u[3, 0] = np.inf
    with pytest.raises(DataError, match="input 'Tm' is inf at step 3"):
        est.simulate(list(STUDY_X0.values()), u)
    with pytest.raises(DataError, match="x0 holds nan for 'omega_m'"):
        est.simulate([0.0, np.nan, 0.0, 0.0], np.ones((10, 1)))


def test_records_with_different_steps(clean):
    record = clean["sine"]
    coarse = Trajectory(record.time[::2], record.values[::2], record.names, units=record.units, roles=record.roles)
    with pytest.raises(DataError, match="same step"):
        SINDYc().fit([record, coarse], inputs=["Tm"])


@pytest.mark.parametrize("kwargs, match", [
    ({"library": "fourier"}, "library must be one of"),
    ({"threshold": -1.0}, "threshold must be"),
    ({"threshold": "best"}, "threshold must be"),
    ({"differentiation": "magic"}, "unknown differentiation"),
    ({"differentiation_options": {"width": 3}}, "option 'window' only"),
    ({"refine": "yes"}, "refine must be"),
    ({"terms": ["import os"]}, "not a valid expression"),
    ({"degree": 0}, "degree must be"),
    ({"refine_options": {"speed": 1}}, "unknown refine_options"),
    ({"prefer_stable": "yes"}, "prefer_stable must be True, False or None"),
    ({"refine_options": {"stability_limit": -1.0}}, "stability_limit must be a positive number"),
])
def test_bad_settings(kwargs, match):
    with pytest.raises(InvalidSettingError, match=match):
        SINDYc(**kwargs)


def test_unknown_keyword_is_rejected():
    with pytest.raises(TypeError):
        SINDYc(thresh=0.1)


def test_unstable_model_is_recorded_and_diverges():
    plant = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[0.8, 1.0]]))
    u = np.sign(np.sin(np.arange(300) * 0.05))[:, None]
    data = plant.simulate([0.1], u, dt=0.01).to_trajectory()
    with pytest.warns(IdentificationWarning, match="unstable"):
        est = SINDYc(allow_unstable=True).fit(data)  # a deliberately unstable plant
    meta = est.model_.meta
    assert meta["stable"] is False
    assert meta["eigenvalues"][0][0] == pytest.approx(0.8, rel=1e-5)
    sim = est.simulate([1.0], np.zeros((5000, 1)), dt=0.01)
    assert sim.status == "diverged" and "diverged at t=" in sim.message


def test_unfitted_estimator():
    with pytest.raises(InvalidSettingError, match="not fitted"):
        SINDYc().equations()


# ------------------------------------------------------------------------------------------ using a fit
def test_predict_simulate_score_and_json(clean):
    record = clean["square"]
    est = SINDYc().fit(record, inputs=["Tm"])
    a_true, b_true = true_matrices()
    x, u = record[STATES], record[["Tm"]]
    np.testing.assert_allclose(est.predict(record), x @ a_true.T + u @ b_true.T, rtol=1e-6, atol=1e-3)
    sim = est.simulate(x[0], u[:-1])
    assert sim.ok and sim.states.shape == x.shape
    assert est.score(record, metric="max_deviation") < 1e-4
    assert est.score(record, metric="nrmse") > 99.99
    with pytest.raises(InvalidSettingError, match="unknown metric"):
        est.score(record, metric="aic")
    meta = json.loads(est.model_.to_json())["meta"]
    assert meta["settings"]["threshold"] == "auto" and meta["threshold"]["method"].startswith("auto")
    assert meta["data"]["samples"] == [len(record)]
    assert est.threshold_ == pytest.approx(meta["threshold"]["value"])
    assert len(est.equations()) == 4


def test_to_statespace_delegates(clean):
    export = pytest.importorskip("cosim.export")
    est = SINDYc(include_constant=False).fit(clean["sine"], inputs=["Tm"])
    assert est.to_statespace() is not None
    assert export is not None


# ------------------------------------------------------------------------------------------ noisy data
def test_output_error_refinement_removes_the_noise_bias(clean):
    """At 20 % noise equation error alone is biased; the refined model follows the clean record closely."""
    noisy = clean["square"].with_noise(0.2, seed=3)
    common = {"include_constant": False, "threshold": 0.0, "kinematics": KINEMATICS}
    plain = SINDYc(**common).fit(noisy, inputs=["Tm"])
    refined = SINDYc(refine="output_error", **common).fit(noisy, inputs=["Tm"])
    x0 = refined.model_.meta["x0"][0]
    u = clean["square"][["Tm"]][:-1]
    truth = clean["square"][STATES]
    from cosim.identify.metrics import max_deviation_pct, r2

    dev = max_deviation_pct(truth, refined.simulate(x0, u).states)
    assert np.all(dev < 1.0), dev
    assert np.all(r2(truth, refined.simulate(x0, u).states) > 0.9999)
    plain_sim = plain.simulate(truth[0], u)
    plain_dev = max_deviation_pct(truth, np.nan_to_num(plain_sim.states, nan=1e9))
    assert np.max(plain_dev) > 10 * np.max(dev)
    assert refined.model_.meta["refinement"]["status"] == "ok"
    assert refined.model_.meta["refinement"]["cost"] < refined.model_.meta["refinement"]["cost_start"]


def test_output_error_refinement_of_a_nonlinear_model():
    """A polynomial (state-input cross term) model is refined with RK4 simulations and their exact sensitivities."""
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "x*u", "u"), coef=np.array([[-1.0, 0.5, 1.0]]))
    t = np.arange(600) * 0.02
    u = (np.sin(0.7 * t) + 0.5 * np.sign(np.sin(2.3 * t)))[:, None]
    clean_run = model.simulate([0.5], u, dt=0.02).to_trajectory()
    noisy = clean_run.with_noise(0.3, seed=1)
    common = {"library": "polynomial", "degree": 2, "threshold": 0.0, "include_constant": False}
    plain = SINDYc(**common).fit(noisy)
    refined = SINDYc(refine="output_error", **common).fit(noisy)
    meta = refined.model_.meta["refinement"]
    assert meta["status"] == "ok" and meta["cost"] < meta["cost_start"]
    from cosim.identify.metrics import max_deviation_pct

    steps = clean_run[["u"]][:-1]
    dev_refined = max_deviation_pct(clean_run["x"], refined.simulate(refined.model_.meta["x0"][0], steps).states[:, 0])
    dev_plain = max_deviation_pct(clean_run["x"], plain.simulate([noisy["x"][0]], steps).states[:, 0])
    assert dev_refined < dev_plain


def test_known_initial_state_is_kept_fixed(clean):
    noisy = clean["sine"].with_noise(0.1, seed=1)
    est = SINDYc(include_constant=False, threshold=0.0, kinematics=KINEMATICS, refine="output_error").fit(
        noisy, inputs=["Tm"], x0=STUDY_X0)
    assert est.model_.meta["x0"] == [list(STUDY_X0.values())]
    with pytest.raises(UnknownVariableError, match="x0 lacks omega_L"):
        SINDYc().fit(noisy, inputs=["Tm"], x0={"theta_m": 0.0, "omega_m": 0.0, "theta_L": 0.0})


def test_auto_threshold_with_refinement_prunes_on_output_error(clean):
    noisy = clean["square"].with_noise(0.1, seed=2)
    est = SINDYc(include_constant=False, kinematics=KINEMATICS, refine="output_error").fit(noisy, inputs=["Tm"])
    meta = est.model_.meta["threshold"]
    assert meta["method"].startswith("auto with refinement")
    assert est.threshold_ == pytest.approx(math.sqrt(math.log(meta["residuals"])))
    # the plant's one zero among the refined terms goes; the motor torque's effect on the motor stays
    removed = [(r["state"], r["term"]) for r in meta["removed"]]
    assert ("omega_L", "Tm") in removed and ("omega_m", "Tm") not in removed
    row = dict(zip(est.terms_, est.coef_[1], strict=True))
    assert row["Tm"] == pytest.approx(0.004, rel=0.3)
    assert est.model_.meta["stable"] is True
    from cosim.identify.metrics import max_deviation_pct

    sim = est.simulate(est.model_.meta["x0"][0], clean["square"][["Tm"]][:-1])
    assert np.all(max_deviation_pct(clean["square"][STATES], sim.states) < 0.5)


# ------------------------------------------------------------------------------------------ the study
def test_study_case_result_fields():
    result = study_case("sine", 0.0, 0, duration=1.0)
    assert result["samples"] == 2258 and result["states"] == STATES
    for key in ("r2", "max_dev_pct", "nrmse"):
        assert set(result[key]) == set(STATES)
    assert min(result["r2"].values()) > 0.99999
    assert result["study_max_dev_pct"] == STUDY_TABLE1[0.0]
    assert np.array(result["coef"]).shape == (4, 5)


@pytest.mark.slow
@pytest.mark.parametrize("noise", [0.0, 0.05, 0.10, 0.20, 0.30, 0.50])
def test_beats_the_study_table(noise):
    """Free run vs clean record (the study's protocol), mean over 2 seeds, worse of the two excitations:
    maximum deviation below Table 1 for every state, R^2 >= 0.99 up to 30 % noise. 5 s records here (the
    report uses 10 s and more seeds)."""
    worst = {s: 0.0 for s in STATES}
    r2_min = 1.0
    for excitation in EXCITATIONS:
        seeds = (1, 2) if noise > 0 else (1,)  # without noise the seed changes nothing
        runs = [study_case(excitation, noise, seed, duration=5.0) for seed in seeds]
        for s in STATES:
            worst[s] = max(worst[s], float(np.mean([r["max_dev_pct"][s] for r in runs])))
        r2_min = min(r2_min, min(min(r["r2"].values()) for r in runs))
        assert all(r["status"] == "ok" for r in runs)
    for s in STATES:
        assert worst[s] < STUDY_TABLE1[noise][s], (s, worst[s], STUDY_TABLE1[noise][s])
    if noise <= 0.30:
        assert r2_min >= 0.99
