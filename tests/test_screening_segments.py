"""Output-error fits over several records (`segments`): each record from its own initial state, nothing crossing
a boundary; `initial_state_fit`; and the block-wise sensitivity recursion against the step-by-step one.

The plant is a mass-spring-damper ``x' = v, v' = -K x - C v + G u``, simulated here with SciPy (exact
zero-order hold), not with cosim.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from cosim.diagnose import _sensitivity
from cosim.diagnose._sensitivity import Propagator, propagate_stepwise
from cosim.diagnose.screening import (
    OutputErrorScreen,
    free_run_residual,
    initial_state_fit,
    output_error_fit,
)
from cosim.errors import InvalidSettingError
from cosim.identify.model import IdentifiedModel

K, C, G, DT = 40.0, 1.5, 2.0, 1e-3
A = np.array([[0.0, 1.0], [-K, -C]])
B = np.array([[0.0], [G]])


def plant_record(x0, n, seed, noise=0.01):
    """ZOH simulation of the plant from x0 driven by a random multisine, plus white noise on both states."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) for f in (0.7, 1.9, 4.3, 9.1))
    phi = expm(np.block([[A, B], [np.zeros((1, 3))]]) * DT)
    ad, bd = phi[:2, :2], phi[:2, 2:]
    x = np.empty((n, 2))
    x[0] = x0
    for k in range(n - 1):
        x[k + 1] = ad @ x[k] + bd[:, 0] * u[k]
    measured = x + noise * np.std(x, axis=0) * rng.standard_normal(x.shape)
    return {"x": measured[:, 0], "v": measured[:, 1], "u": u}, x


def model(k=K, c=C, g=G):
    return IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u"),
                           coef=np.array([[1.0, 0.0, 0.0], [-c, -k, g]]))


def joined(*records):
    columns = {name: np.concatenate([r[name] for r in records]) for name in records[0]}
    starts = np.cumsum([0] + [len(r["x"]) for r in records])[:-1]
    return columns, [int(s) for s in starts]


X0S = ([0.3, 0.0], [-0.2, 1.5])


@pytest.fixture(scope="module")
def two_records():
    (a, _), (b, _) = plant_record(X0S[0], 3000, 1), plant_record(X0S[1], 2500, 2)
    return joined(a, b)


def test_two_records_fitted_jointly_recover_the_plant(two_records):
    columns, segments = two_records
    fitted, se, _ = output_error_fit(model(k=30.0, c=3.0, g=1.5), columns, DT, segments=segments)
    row = fitted.coef[1]
    assert row == pytest.approx([-C, -K, G], rel=0.02)
    assert np.all(se[1] > 0)
    x0 = fitted.meta["x0"]
    assert len(x0) == 2  # one initial state per record
    for got, true in zip(x0, X0S, strict=True):
        assert got == pytest.approx(true, abs=0.02)
    # each record ran from its own start: the residual is noise (about one noise level per state) everywhere
    screen = OutputErrorScreen(fitted, columns, DT, segments=segments)
    r = screen.residual.reshape(-1, 2)
    assert np.sqrt(np.mean(r ** 2)) < 1.5
    assert screen.x0.shape == (2, 2) and screen.base.shape[1] == 3 + 2 * 2


def test_one_record_cut_in_two_fits_like_the_whole_record():
    columns, _ = plant_record(X0S[0], 6000, 3)
    whole, _, _ = output_error_fit(model(k=35.0), columns, DT)
    cut, _, _ = output_error_fit(model(k=35.0), columns, DT, segments=[0, 3100])
    np.testing.assert_allclose(cut.coef, whole.coef, rtol=5e-3)
    assert len(whole.meta["x0"]) == 1 and len(cut.meta["x0"]) == 2
    # the second record's start is where the whole record's run is at that sample
    run = model().simulate(whole.meta["x0"][0], columns["u"][:-1, None], dt=DT).states
    assert cut.meta["x0"][1] == pytest.approx(run[3100], abs=0.02)


def test_segments_none_is_one_record(two_records):
    columns, _ = two_records
    start = model(k=35.0)
    none = OutputErrorScreen(start, columns, DT)
    one = OutputErrorScreen(start, columns, DT, segments=[0])
    assert np.array_equal(none.residual, one.residual) and np.array_equal(none.base, one.base)
    assert none.x0.shape == (2,)
    fit_none, se_none, _ = output_error_fit(start, columns, DT, iterations=3)
    fit_one, se_one, _ = output_error_fit(start, columns, DT, iterations=3, segments=[0])
    assert np.array_equal(fit_none.coef, fit_one.coef) and np.array_equal(se_none, se_one)
    assert fit_none.meta["x0"] == fit_one.meta["x0"]


def test_nothing_crosses_a_record_boundary(two_records):
    columns, segments = two_records
    m = model()
    joint = free_run_residual(m, columns, DT, X0S, np.ones(2), segments=segments)
    for (a, b), x0 in zip([(0, segments[1]), (segments[1], len(columns["x"]))], X0S, strict=True):
        part = {k: v[a:b] for k, v in columns.items()}
        alone = free_run_residual(m, part, DT, x0, np.ones(2))
        np.testing.assert_array_equal(joint[a:b], alone)
    # sensitivities restart at each record: the second record's initial state moves only the second record
    screen = OutputErrorScreen(m, columns, DT, x0=X0S, segments=segments)
    sens = screen.base.reshape(-1, 2, screen.base.shape[1])
    assert np.all(sens[:segments[1], :, -2:] == 0.0)
    assert np.all(sens[segments[1]:, :, -4:-2] == 0.0)
    np.testing.assert_allclose(sens[segments[1], :, -2:] * screen.sigma[:, None], np.eye(2))


def test_initial_state_fit_recovers_a_known_initial_state():
    columns, _ = plant_record([0.25, -0.8], 4000, 4, noise=0.0)
    fit = initial_state_fit(model(), columns, DT, x0=[0.0, 0.0], sigma=np.array([1e-3, 1e-2]))
    assert fit.x0 == pytest.approx([0.25, -0.8], abs=1e-8)
    assert fit.cost < 1e-6 and fit.residual.shape == (4000, 2)
    noisy, _ = plant_record([0.25, -0.8], 4000, 4, noise=0.01)
    a, b = noisy, plant_record([-0.4, 0.9], 3000, 5, noise=0.01)[0]
    columns, segments = joined(a, b)
    fit = initial_state_fit(model(), columns, DT, segments=segments)
    np.testing.assert_allclose(fit.x0, [[0.25, -0.8], [-0.4, 0.9]], atol=0.02)
    assert fit.cost / fit.residual.size == pytest.approx(1.0, rel=0.3)  # noise only


def test_bad_segments_say_what_is_wrong(two_records):
    columns, _ = two_records
    with pytest.raises(InvalidSettingError, match="segments must be increasing start indices from 0"):
        OutputErrorScreen(model(), columns, DT, segments=[10, 200])
    with pytest.raises(InvalidSettingError, match="x0 must hold 2 values per record"):
        OutputErrorScreen(model(), columns, DT, x0=[0.0, 0.0], segments=[0, 3000])


@pytest.fixture(params=["c_loop", "block_scan"])
def recursion(request, monkeypatch):
    """Each implementation of the recursion: the compiled C loop (where a C compiler works, as here) and the
    NumPy block scan it falls back to."""
    if request.param == "c_loop":
        assert _sensitivity._c_propagate() is not None, "the C loop did not compile"
    else:
        monkeypatch.setattr(_sensitivity, "_c_propagate", lambda: None)
    return request.param


@pytest.mark.parametrize("varying", [False, True])
@pytest.mark.parametrize("steps", [1, 7, 500, 2001])
def test_block_recursion_matches_the_step_by_step_one(varying, steps, recursion):
    rng = np.random.default_rng(steps)
    n, m = 3, 5
    a0 = rng.standard_normal((n, n)) - 2 * np.eye(n)
    phi = expm(np.block([[a0, np.eye(n)], [np.zeros((n, 2 * n))]]) * 0.01)
    ad, gamma = phi[:n, :n], phi[:n, n:]
    dj = 0.5 * rng.standard_normal((steps, n, n)) if varying else None
    forcing, s0 = rng.standard_normal((steps, n, m)), rng.standard_normal((n, m))
    ref = propagate_stepwise(ad, gamma, dj, forcing, s0)
    prop = Propagator(ad, gamma, dj, steps)
    np.testing.assert_allclose(prop.integrate(forcing, s0), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    rows = rng.integers(0, n, m)
    sparse = np.zeros_like(forcing)
    sparse[:, rows, np.arange(m)] = forcing[:, 0, :]
    np.testing.assert_array_equal(prop.integrate_columns(rows, forcing[:, 0, :], s0), prop.integrate(sparse, s0))
