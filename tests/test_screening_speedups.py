"""The screening's exact Jacobian, its `measured` states, and its batched score test.

* ``IdentifiedModel.state_jacobian`` (forward mode over the terms) against the complex-step derivative of a
  model with a sharp Coulomb friction ``tanh(v/1e-4)``, where the old finite difference (a step of
  ``1e-6 max|x|``, here as wide as the smoothing velocity) misses the slope;
* a mass with Coulomb friction whose position is measured with noise and whose velocity is derived from it
  (Savitzky-Golay): with ``measured=["x"]`` only the position counts;
* ``OutputErrorScreen.test_specs`` gives the numbers of ``test`` on ``candidate_sensitivities``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import savgol_filter

from cosim.diagnose.screening import (
    OutputErrorScreen,
    free_run_cost,
    free_run_residual,
    initial_state_fit,
    output_error_fit,
)
from cosim.errors import InvalidSettingError
from cosim.identify.model import IdentifiedModel
from cosim.identify.terms import Term

EPS, FC, B, K, DT = 1e-4, 0.3, 0.5, 20.0, 1e-3


def friction_model(fc=FC, b=B, eps=EPS, k=K):
    return IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", f"tanh(v/{eps})", "u"),
                           coef=np.array([[1.0, 0.0, 0.0, 0.0], [-b, -k, -fc, 1.0]]))


def drive(n, gain=1.0):
    t = np.arange(n) * DT
    return gain * (0.8 * np.sin(2 * np.pi * 0.5 * t) + 0.3 * np.sin(2 * np.pi * 3.1 * t))


def complex_step_jacobian(x, u, eps=EPS):
    """d f / d x of the friction model by the complex step (exact to rounding)."""
    def f(z):
        return np.stack([z[:, 1], -B * z[:, 1] - K * z[:, 0] - FC * np.tanh(z[:, 1] / eps) + u], axis=1)
    out = np.empty((len(x), 2, 2))
    for j in range(2):
        z = x.astype(complex)
        z[:, j] += 1e-30j
        out[:, :, j] = f(z).imag / 1e-30
    return out


def test_exact_jacobian_matches_the_complex_step_where_the_finite_difference_misses():
    m = friction_model()
    u = drive(20001, gain=300.0)  # speeds up to ~100: a step of 1e-6 max|v| is ~1e-4, the smoothing velocity
    x = m.simulate([0.0, 0.0], u[:-1, None], dt=DT).states[:-1]
    want = complex_step_jacobian(x, u[:-1])
    got = m.state_jacobian(x, u[:-1, None])
    scale = np.abs(want).max()  # the friction's slope at zero speed, FC / EPS
    assert np.abs(got - want).max() <= 1e-12 * scale
    h = 1e-6 * np.abs(x).max(axis=0)
    fd = np.stack([(m.predict(x + np.eye(2)[j] * h[j], u[:-1, None]) - m.predict(x - np.eye(2)[j] * h[j],
                                                                                  u[:-1, None])) / (2 * h[j])
                   for j in range(2)], axis=2)
    assert np.abs(fd - want).max() > 0.05 * scale  # what the screening used before


def test_model_jacobian_is_exact_and_the_screen_takes_the_slope_across_each_sample():
    m = friction_model()
    u = drive(3001, gain=300.0)
    sim = m.simulate([0.0, 0.0], u[:-1, None], dt=DT).states
    exact = complex_step_jacobian(sim[:-1], u[:-1])
    assert np.abs(m.state_jacobian(sim[:-1], u[:-1]) - exact).max() <= 1e-12 * FC / EPS
    screen = OutputErrorScreen(m, {"x": sim[:, 0], "v": sim[:, 1], "u": u}, DT)
    a0 = np.array([[0.0, 1.0], [-K, -B]])
    assert screen.nonlinear
    # away from the friction's sharp turn the slope across a sample is the exact slope...
    move = np.abs(np.diff(sim[:, 1]))
    calm = np.minimum(np.abs(sim[:-1, 1]) - move, np.abs(sim[1:, 1])) > 30 * EPS
    assert calm.sum() > 1000
    np.testing.assert_allclose(screen.delta_j[calm] + a0, exact[calm], rtol=1e-6, atol=1e-6 * FC / EPS)
    # ...and where the speed moves far across a sample, the friction's slope across it is at most its jump over
    # the span (2 FC over the move), far below the turn's pointwise FC/EPS: the held-over-a-sample sensitivity
    # step stays stable
    steep = move > 10 * EPS
    assert steep.sum() > 100
    assert np.all(np.abs(screen.delta_j[steep][:, 1, 1]) <= 2 * FC / move[steep] * (1 + 1e-9))
    assert np.abs(screen.delta_j[steep][:, 1, 1]).max() < 0.2 * FC / EPS


@pytest.mark.parametrize("text, name, value, slope", [
    ("x**2*sin(y)", "y", {"x": 3.0, "y": 0.0}, 9.0),
    ("x**2*sin(y)", "x", {"x": 3.0, "y": 0.5}, 6 * np.sin(0.5)),
    ("abs(x)/(1+y)", "y", {"x": -2.0, "y": 1.0}, -0.5),
    ("sign(x)", "x", {"x": 1.0}, 0.0),
    ("exp(-x)*atan(x)", "x", {"x": 0.3}, -np.exp(-0.3) * np.arctan(0.3) + np.exp(-0.3) / 1.09),
    ("sqrt(x)+log(x)-tan(x)+cos(x)", "x", {"x": 0.7},
     0.5 / np.sqrt(0.7) + 1 / 0.7 - 1 / np.cos(0.7) ** 2 - np.sin(0.7)),
    ("x**y", "y", {"x": 2.0, "y": 3.0}, 8.0 * np.log(2.0)),
    ("u", "x", {"x": 1.0, "u": 2.0}, 0.0),
])
def test_term_derivative(text, name, value, slope):
    got = Term(text).derivative({k: np.array([v]) for k, v in value.items()}, name)
    assert np.asarray(got, dtype=float).ravel()[0] == pytest.approx(slope, rel=1e-12, abs=1e-15)


def test_linear_model_has_no_time_varying_jacobian():
    m = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u"),
                        coef=np.array([[1.0, 0.0, 0.0], [-B, -K, 1.0]]))
    u = drive(501)
    sim = m.simulate([0.1, 0.0], u[:-1, None], dt=DT).states
    screen = OutputErrorScreen(m, {"x": sim[:, 0], "v": sim[:, 1], "u": u}, DT)
    assert not screen.nonlinear and not np.any(screen.delta_j)


# ---------------------------------------------------------------------------------------------- measured
@pytest.fixture(scope="module")
def derived_velocity():
    """A mass with Coulomb friction (smooth enough to fit), position measured with noise, velocity derived."""
    truth = friction_model(fc=0.4, eps=0.01)
    n = 4001
    u = drive(n, gain=3.0)
    x = truth.simulate([0.0, 0.0], u[:-1, None], dt=DT).states
    rng = np.random.default_rng(3)
    pos = x[:, 0] + 0.002 * np.std(x[:, 0]) * rng.standard_normal(n)
    vel = savgol_filter(pos, 31, 3, deriv=1, delta=DT)
    return truth, {"x": pos, "v": vel, "u": u}


def test_measured_counts_only_the_measured_states(derived_velocity):
    truth, columns = derived_velocity
    start = friction_model(fc=0.25, b=0.8, eps=0.01)
    screen = OutputErrorScreen(start, columns, DT, measured=["x"])
    n = len(columns["x"])
    assert screen.measured == ("x",)
    assert screen.n_obs == n * 1
    r = screen.residual.reshape(n, 2)
    assert np.any(r[:, 0]) and not np.any(r[:, 1])
    base = screen.base.reshape(n, 2, -1)
    assert not np.any(base[:, 1]) and np.any(base[:, 0])
    # the velocity's initial state is still estimated (through the position): its column is not zero
    assert np.linalg.norm(base[:, 0, -1]) > 0
    assert screen.variance == pytest.approx(screen.rss0 / (n - screen.base.shape[1]))
    [score] = screen.test_specs([(("tanh(v/0.01)",), ("v",))])
    assert np.all(np.isfinite(score["coef"])) and score["drop"] > 0

    fitted, se, _ = output_error_fit(start, columns, DT, measured=["x"])
    row = fitted.coef[1]
    assert row[2] == pytest.approx(-0.4, rel=0.05)  # the friction level, from the position only
    assert row[0] == pytest.approx(-B, rel=0.1)
    assert se[1, 2] > 0
    # the cost is the position's only: the same as the cost with the velocity given any noise level
    x0 = np.asarray(fitted.meta["x0"][0])
    cost = float(fitted.meta["refinement"]["cost"])
    sigma = OutputErrorScreen(fitted, columns, DT, measured=["x"]).sigma
    assert free_run_cost(fitted, columns, DT, x0, sigma, measured=["x"]) == pytest.approx(cost, rel=1e-9)
    assert free_run_cost(fitted, columns, DT, x0, sigma * [1, 1e-6], measured=["x"]) == pytest.approx(cost,
                                                                                                       rel=1e-9)
    res = free_run_residual(fitted, columns, DT, x0, sigma, measured=["x"])
    assert not np.any(res[:, 1]) and float(np.sum(res ** 2)) == pytest.approx(cost, rel=1e-9)
    held = initial_state_fit(fitted, columns, DT, measured=["x"])
    assert not np.any(held.residual[:, 1]) and held.cost <= cost * (1 + 1e-6)


def test_all_states_measured_fit_is_pulled_by_the_derived_velocity(derived_velocity):
    """Without `measured`, the smoothed velocity's lag weighs in the cost (the reason for the keyword)."""
    _, columns = derived_velocity
    start = friction_model(fc=0.25, b=0.8, eps=0.01)
    only_x = OutputErrorScreen(start, columns, DT, measured=("x",))
    both = OutputErrorScreen(start, columns, DT)
    assert both.n_obs == 2 * only_x.n_obs
    assert both.residual.reshape(-1, 2)[:, 1].any()


@pytest.mark.parametrize("measured", [[], ["speed"], "y"])
def test_bad_measured_says_what_is_wrong(derived_velocity, measured):
    _, columns = derived_velocity
    with pytest.raises(InvalidSettingError, match="measured must name"):
        OutputErrorScreen(friction_model(eps=0.01), columns, DT, measured=measured)


# ---------------------------------------------------------------------------------------------- batched test
def test_batched_scores_match_one_by_one(derived_velocity):
    _, columns = derived_velocity
    screen = OutputErrorScreen(friction_model(fc=0.2, eps=0.01), columns, DT)
    # (not the model's own tanh(v/0.01) in row v: lying in the base, its projection is rounding only)
    specs = [((f"tanh(v/{e})",), rows) for e in (0.003, 0.02, 0.05) for rows in (("v",), ("x",), ("x", "v"))]
    specs += [(("v**3", "x**3"), ("v",)), (("sign(v)",), ("v",)), ((), ("v",))] * 30  # more than one chunk
    batched = screen.test_specs(specs)
    one_by_one = [screen.test(s) for s in screen.candidate_sensitivities(specs)]
    assert len(batched) == len(one_by_one) == len(specs)
    for spec, got, want in zip(specs, batched, one_by_one, strict=True):
        if not spec[0]:  # a spec without columns scores nothing
            assert got["drop"] == 0.0 and got["p_value"] == 1.0 and got["coef"] is None
            continue
        assert got["delta_bic"] == pytest.approx(want["delta_bic"], rel=1e-7, abs=1e-6)
        assert got["p_value"] == pytest.approx(want["p_value"], rel=1e-6, abs=1e-12)
        if want["coef"] is not None and len(want["coef"]):
            np.testing.assert_allclose(got["coef"], want["coef"], rtol=1e-7)
            np.testing.assert_allclose(got["se"], want["se"], rtol=1e-7)


def test_compiled_rk4_gives_the_interpreters_bits(monkeypatch):
    from cosim.identify import terms

    m = friction_model()
    u = drive(terms._JIT_MIN_STEPS + 500, gain=300.0)[:, None]
    compiled = m.simulate([0.1, 0.0], u[:-1], dt=DT).states  # long enough to be run compiled
    monkeypatch.setattr(terms, "_JIT_MIN_STEPS", 10 ** 9)
    interpreted = m.simulate([0.1, 0.0], u[:-1], dt=DT).states
    assert np.ptp(compiled[:, 1]) > 0.1
    np.testing.assert_array_equal(compiled, interpreted)
    from cosim.plant.build import fmu_cache_dir

    assert list((fmu_cache_dir() / "jit").glob("cosim_rk4_*.so"))  # it was compiled, and kept


def test_compiled_linear_run_gives_the_python_loops_bits(monkeypatch):
    from cosim.identify import terms

    stable = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("x", "v", "u"),
                             coef=np.array([[0.0, 1.0, 0.0], [-K, -B, 1.0]]))
    unstable = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[40.0]]))
    u = drive(terms._JIT_MIN_STEPS + 700, gain=30.0)[:, None]
    runs = []
    for limit in (terms._JIT_MIN_STEPS, 10 ** 9):  # compiled, then the Python loop
        monkeypatch.setattr("cosim.identify.model._JIT_MIN_STEPS", limit)
        runs.append((stable.simulate([0.1, 0.0], u[:-1], dt=DT),
                     unstable.simulate([1.0], n_steps=terms._JIT_MIN_STEPS, dt=DT)))
    (compiled, fast), (looped, slow) = runs
    assert compiled.ok and np.ptp(compiled.states[:, 0]) > 0.1
    np.testing.assert_array_equal(compiled.states, looped.states)
    assert fast.status == slow.status == "diverged" and fast.message == slow.message
    np.testing.assert_array_equal(fast.states, slow.states)


def test_compiled_sensitivities_give_the_interpreters_bits(monkeypatch):
    from cosim.identify import _sensitivity
    from cosim.identify._sensitivity import free_run_sensitivities

    m = friction_model()
    u = drive(_sensitivity._JIT_MIN_STEPS + 300, gain=300.0)[:, None]
    runs = [free_run_sensitivities(m, m.coef, m.coef != 0, np.array([0.1, 0.0]), u, DT, len(u))]  # compiled
    monkeypatch.setattr(_sensitivity, "_JIT_MIN_STEPS", 10 ** 9)  # the interpreter only
    runs.append(free_run_sensitivities(m, m.coef, m.coef != 0, np.array([0.1, 0.0]), u, DT, len(u)))
    (states_c, sens_c), (states_i, sens_i) = runs
    assert np.ptp(states_c[:, 1]) > 0.1 and np.ptp(sens_c) > 0
    np.testing.assert_array_equal(states_c, states_i)
    np.testing.assert_array_equal(sens_c, sens_i)
    from cosim.plant.build import fmu_cache_dir

    assert list((fmu_cache_dir() / "jit").glob("cosim_sens_*.so"))  # it was compiled, and kept
