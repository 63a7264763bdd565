"""Output-error refinement kept stable (``refine_output_error(stability_limit=...)``)."""

from __future__ import annotations

import numpy as np

from cosim.identify._stability import StabilityPenalty
from cosim.identify.model import IdentifiedModel
from cosim.identify.output_error import _Problem, refine_output_error


def _unstable_record(dt: float = 0.01, n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Two seconds of x' = 0.5 x + u under a square wave, exact (zero-order hold), small noise."""
    a, b = 0.5, 1.0
    u = np.sign(np.sin(2 * np.pi * 1.0 * dt * np.arange(n)))[:, None]
    ad, bd = np.exp(a * dt), (np.exp(a * dt) - 1.0) / a * b
    x = np.zeros((n + 1, 1))
    for k in range(n):
        x[k + 1] = ad * x[k] + bd * u[k]
    return x + 1e-4 * np.random.default_rng(0).standard_normal(x.shape), u


def test_a_stability_limit_keeps_the_fit_inside_it():
    """The data of an unstable plant pull the pole to +0.5 1/s; with ``stability_limit=0.05`` the refinement ends
    at the boundary instead (between 0 and the limit), and costs more than the unconstrained fit."""
    x, u = _unstable_record()
    start = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 1.0]]), dt=0.01)
    free = refine_output_error(start, [(x, u)], dt=0.01)
    kept = refine_output_error(start, [(x, u)], dt=0.01, stability_limit=0.05)
    assert abs(free.coef[0, 0] - 0.5) < 0.02
    assert -0.01 < kept.coef[0, 0] <= 0.05
    assert kept.cost > free.cost


def test_the_penalty_rows_derivative_matches_differences():
    """The penalty's Jacobian (eigenvalue sensitivities) against central differences, on a two-state model with
    a growing oscillation (a complex pair: both rows move)."""
    coef = np.array([[0.0, 1.0, 0.0], [-4.0, 0.3, 1.0]])
    model = IdentifiedModel(states=("q", "v"), inputs=("u",), terms=("q", "v", "u"), coef=coef, dt=0.01)
    x = np.column_stack([np.sin(np.arange(51) * 0.1), np.cos(np.arange(51) * 0.1)])
    problem = _Problem(model, [(x, np.zeros((50, 1)))], 0.01, coef != 0.0, True, None, None)
    penalty = StabilityPenalty(problem, limit=0.1, data_cost=1.0, n_res=100)
    theta = problem.theta0
    value, jac = penalty.rows(theta)
    assert np.count_nonzero(value) == 2  # the pair 0.15 +- 2j
    h = 1e-6
    for p in range(problem.n_coef):
        up, down = theta.copy(), theta.copy()
        up[p] += h
        down[p] -= h
        np.testing.assert_allclose(jac[:, p], (penalty.rows(up)[0] - penalty.rows(down)[0]) / (2 * h),
                                   rtol=1e-5, atol=1e-6 * np.abs(jac).max())



def test_a_start_whose_free_run_overflows_still_gives_finite_penalty_rows():
    """The data's cost at a stage's start scales the penalty; a start whose free run's squares overflow (record 89
    of the generalisation benchmark, pruning from a diverging start) gives an infinite cost, and the rows were
    NaN (0 x inf), which the solver refuses. Such a start is scaled as a diverging run."""
    x, u = _unstable_record()
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[0.3, 1.0]]), dt=0.01)
    problem = _Problem(model, [(x, u)], 0.01, model.coef != 0.0, True, None, None)
    value, jac = StabilityPenalty(problem, limit=0.05, data_cost=np.inf, n_res=200).rows(problem.theta0)
    assert np.all(np.isfinite(value)) and np.all(np.isfinite(jac)) and value[0] > 0
