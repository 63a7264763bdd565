"""Residual analysis: the correlation tests against known processes, and the residuals of models on FMU data."""

import math

import numpy as np
import pytest
from matplotlib.figure import Figure

from cosim import build_fmu, simulate
from cosim.data.trajectory import Trajectory
from cosim.diagnose.residuals import correlation_tests, residuals
from cosim.errors import DataError, UnknownVariableError
from cosim.figures import COLOURS
from cosim.identify.model import IdentifiedModel
from cosim.study.paper import STATES, STUDY_DT, two_mass_matrices

N = 20_000


def test_white_noise_is_white_and_an_ar1_process_is_not():
    rng = np.random.default_rng(7)
    white = correlation_tests(rng.standard_normal(N))
    assert white.white and white.ljung_box_p > 0.01
    assert white.bound == pytest.approx(2.5758 / math.sqrt(N), rel=1e-4)
    assert white.fraction_outside <= 0.08
    e = np.zeros(N)
    noise = rng.standard_normal(N)
    for k in range(1, N):
        e[k] = 0.5 * e[k - 1] + noise[k]
    ar = correlation_tests(e)
    assert not ar.white and ar.ljung_box_p < 1e-12
    np.testing.assert_allclose(ar.autocorrelation[:3], [0.5, 0.25, 0.125], atol=0.03)  # phi^lag


def test_cross_correlation_finds_the_lag_at_which_the_input_leads():
    rng = np.random.default_rng(3)
    u = rng.standard_normal(N)
    e = 0.3 * np.roll(u, 3) + rng.standard_normal(N)  # the residual repeats the input 3 samples later
    tests = correlation_tests(e, u[:, None], input_names=["u"])
    ccf = tests.cross_correlation["u"]
    assert tests.cross_lags[np.argmax(np.abs(ccf))] == 3
    assert ccf[np.argmax(np.abs(ccf))] == pytest.approx(0.3 / math.sqrt(1.09), abs=0.02)
    assert not tests.independent
    clean = correlation_tests(rng.standard_normal(N), u[:, None], input_names=["u"])
    assert clean.independent


def test_cross_bound_widens_for_a_coloured_input():
    rng = np.random.default_rng(5)
    slow = np.repeat(rng.standard_normal(N // 50), 50)  # a held, strongly correlated input
    e = np.repeat(rng.standard_normal(N // 50), 50)     # a residual coloured the same way, but independent
    tests = correlation_tests(e, slow[:, None], input_names=["u"], max_lag=25)
    assert tests.cross_bound["u"] > 4 * tests.bound       # sqrt(P) grows with the shared colour
    assert tests.independent


@pytest.fixture(scope="module")
def true_model():
    a, b = two_mass_matrices()
    return IdentifiedModel(states=STATES, inputs=("Tm",), terms=(*STATES, "Tm"), coef=np.hstack([a, b[:, :1]]))


@pytest.fixture(scope="module")
def fmu_runs():
    fmu = build_fmu()
    kw = {"duration": round(2.0 / STUDY_DT) * STUDY_DT, "dt": STUDY_DT}
    clean = simulate(fmu, {"Tm": "multisine:amp=1000,fmin=1,fmax=40"}, **kw)
    friction = simulate(fmu, {"Tm": "multisine:amp=1000,fmin=1,fmax=40"}, parameters={"Fc": 100.0}, **kw)
    return clean, friction


def test_true_model_on_noisy_fmu_data_leaves_a_white_free_run_residual(true_model, fmu_runs):
    clean, _ = fmu_runs
    noisy = clean.with_noise(0.05, seed=2)
    res = residuals(true_model, noisy)
    assert res.free_run_status == "ok" and res.white and res.independent
    # the free-run residual is the measurement noise: its RMS is the noise level
    noise_std = {name: 0.05 * np.std(clean[name]) for name in STATES}
    for name in STATES:
        assert res.rms()["free_run"][name] == pytest.approx(noise_std[name], rel=0.05)
    # the one-step error of the same, true model is n[k+1] - A n[k]: a moving average, never white
    assert not residuals(true_model, noisy, tested="one_step").white


def test_friction_the_model_lacks_shows_in_every_residual(true_model, fmu_runs):
    clean, friction = fmu_runs
    without = residuals(true_model, clean)
    with_friction = residuals(true_model, friction)
    for kind in ("equation", "one_step", "free_run"):
        assert with_friction.rms()[kind]["omega_m"] > 100 * without.rms()[kind]["omega_m"], kind
    assert not with_friction.white
    # the equation error of omega_m is the friction torque over Jm, with the sign of the motor speed
    eq = with_friction.equation[:, 1]
    moving = np.abs(friction["omega_m"][:-1]) > 0.05
    np.testing.assert_allclose(eq[moving], -100.0 / 250.0 * np.sign(friction["omega_m"][:-1][moving]), atol=0.05)


def test_residual_plot_and_summary(true_model, fmu_runs, tmp_path):
    res = residuals(true_model, fmu_runs[1])
    fig = res.plot(tmp_path / "resid.png", colour=COLOURS["before"])
    assert isinstance(fig, Figure) and (tmp_path / "resid.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "resid.png").stat().st_size > 20_000
    assert fig.axes[0].get_ylabel() == "theta_m\nresidual [rad]"
    assert fig.axes[3].get_ylabel() == "omega_m\nresidual [rad/s]"
    assert fig.axes[-3].get_xlabel() == "time [s]"
    free_run = fig.axes[0].get_lines()[-1]
    assert free_run.get_label() == "free run" and free_run.get_color() == COLOURS["before"]
    assert res.plot().axes[0].get_lines()[-1].get_color() == COLOURS["model"]  # no path: nothing written, a Figure
    summary = res.summary()
    assert summary["white"] is False and set(summary["rms"]) == {"equation", "one_step", "free_run"}


def test_bad_input_is_refused(true_model):
    t = np.arange(30) * 0.01
    short = Trajectory.from_arrays(t, {**{s: np.zeros(30) for s in STATES}, "Tm": np.zeros(30)})
    with pytest.raises(DataError, match="at least"):
        residuals(true_model, short)
    t = np.cumsum(np.r_[0.0, np.full(99, 0.01)] * np.r_[1.0, np.ones(49), 2.0, np.ones(49)])
    uneven = Trajectory.from_arrays(t, {**{s: np.zeros(100) for s in STATES}, "Tm": np.zeros(100)})
    with pytest.raises(DataError, match="not uniform"):
        residuals(true_model, uneven)
    no_input = Trajectory.from_arrays(np.arange(100) * 0.01, {s: np.zeros(100) for s in STATES})
    with pytest.raises(UnknownVariableError, match="'Tm'"):
        residuals(true_model, no_input)
    with pytest.raises(DataError, match="tested"):
        residuals(true_model, no_input, tested="two_step")
