"""The output-error refinement's exact sensitivities of nonlinear models (cosim.identify._sensitivity)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosim.identify._sensitivity import free_run_sensitivities
from cosim.identify.model import IdentifiedModel
from cosim.identify.output_error import _Problem, refine_output_error

#: A mass with a spring, Coulomb friction (smoothed), a sine of its position and a constant: every kind of
#: function the diagnosis's effects write.
TERMS = ("1", "x", "v", "u", "tanh(v/0.05)", "sin(3*x)", "abs(v)", "exp(-(v/0.2)**2)*tanh(v/0.01)")
COEF = np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                 [0.1, -4.0, -0.5, 2.0, -0.3, 0.2, -0.05, -0.1]])


def _records(model: IdentifiedModel, dt: float, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    runs = []
    for x0 in ([0.1, 0.0], [-0.2, 0.3]):
        u = rng.normal(size=(300, 1))
        states = model.simulate(x0, u, dt=dt).states
        runs.append((states + 1e-3 * rng.normal(size=states.shape), u))
    return runs


def test_sensitivities_equal_forward_differences_of_the_reference_run():
    model = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=TERMS, coef=COEF)
    support = COEF != 0.0
    support[0] = False  # the kinematic row stays
    problem = _Problem(model, _records(model, 0.01, 0), 0.01, support, True, None, None)
    theta = problem.theta0 * 1.05
    res, jac = problem.nonlinear_sensitivities(theta, 300)
    reference = problem.nonlinear_residuals(theta[None], 300)
    for r in range(2):
        np.testing.assert_allclose(res[r], reference[r][0], rtol=0, atol=1e-12)
    fd = np.zeros_like(np.vstack(jac))
    r0 = np.concatenate([ref[0] for ref in reference])
    for j in range(theta.size):
        step = 1e-6 * max(abs(theta[j]), 1e-3)
        moved = theta.copy()
        moved[j] += step
        fd[:, j] = (np.concatenate([ref[0] for ref in problem.nonlinear_residuals(moved[None], 300)]) - r0) / step
    exact = np.vstack(jac)
    assert np.max(np.abs(exact - fd)) < 1e-5 * np.max(np.abs(fd))
    # each record's initial state moves its own residuals only
    n_coef = problem.n_coef
    assert np.all(jac[0][:, n_coef + 2:] == 0.0) and np.all(jac[1][:, n_coef:n_coef + 2] == 0.0)


def test_a_diverging_run_gives_no_sensitivities():
    model = IdentifiedModel(states=("x",), inputs=(), terms=("x*x",), coef=np.array([[1.0]]))
    assert free_run_sensitivities(model, model.coef, model.coef != 0, np.array([10.0]), np.zeros((500, 0)),
                                  0.1, 500) is None


def test_refinement_with_exact_sensitivities_matches_forward_differences_on_a_pendulum():
    """A damped pendulum with Coulomb friction, simulated by solve_ivp (its own equations), refined from a
    start 30 % off: both Jacobians reach the same optimum, near the truth."""
    g_l, b, fc, gain, dt, n = 9.0, 0.4, 0.3, 2.0, 0.01, 800
    t = np.arange(n + 1) * dt
    u = np.sin(1.3 * t[:-1]) + 0.5 * np.sign(np.sin(0.4 * t[:-1]))

    def rhs(time, s):
        k = min(int(time / dt), n - 1)
        return [s[1], -g_l * np.sin(s[0]) - b * s[1] - fc * np.tanh(s[1] / 0.05) + gain * u[k]]

    states = np.empty((n + 1, 2))
    states[0] = [0.5, 0.0]
    for k in range(n):  # sample by sample: the input is held
        states[k + 1] = solve_ivp(rhs, (t[k], t[k + 1]), states[k], rtol=1e-10, atol=1e-12).y[:, -1]
    noisy = states + 1e-3 * np.random.default_rng(1).normal(size=states.shape)
    truth = np.array([[0.0, 1.0, 0.0, 0.0, 0.0], [-g_l, -b, -fc, 0.0, gain]])
    terms = ("sin(theta)", "omega", "tanh(omega/0.05)", "1", "u")
    coef = truth.copy()
    coef[1] *= 1.3
    coef[1, 3] = 0.01
    start = IdentifiedModel(states=("theta", "omega"), inputs=("u",), terms=terms, coef=coef)
    support = coef != 0.0
    support[0] = False
    exact = refine_output_error(start, [(noisy, u[:, None])], dt=dt, support=support)
    differences = refine_output_error(start, [(noisy, u[:, None])], dt=dt, support=support, exact_jacobian=False)
    assert exact.status == differences.status == "ok"
    assert exact.cost == pytest.approx(differences.cost, rel=1e-4)
    np.testing.assert_allclose(exact.coef[1, [0, 1, 2, 4]], truth[1, [0, 1, 2, 4]], rtol=0.03)
