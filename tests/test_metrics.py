"""Accuracy measures against hand-computed answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.data.trajectory import Trajectory
from cosim.errors import DataError, InvalidSettingError
from cosim.identify.metrics import METRICS, k_step_ahead_error, max_deviation_pct, nrmse_fit_pct, r2
from cosim.identify.model import IdentifiedModel


def test_r2_hand_computed():
    # y = 1, 2, 3: mean 2, SS_tot = 2; f = 1, 2, 4: SS_res = 1 -> R^2 = 0.5
    assert r2([1.0, 2.0, 3.0], [1.0, 2.0, 4.0]) == pytest.approx(0.5)
    # y = 0, 2, 4, 6 (SS_tot = 20), errors 1, -1, 0, 2 (SS_res = 6) -> 0.7
    assert r2([0.0, 2.0, 4.0, 6.0], [1.0, 1.0, 4.0, 8.0]) == pytest.approx(0.7)


def test_r2_per_column_and_perfect():
    y = np.array([[1.0, 0.0], [2.0, 1.0], [3.0, 0.0]])
    f = np.array([[1.0, 0.0], [2.0, 1.0], [3.0, 1.0]])
    # column 2: y = 0, 1, 0, mean 1/3, SS_tot = 2/3, SS_res = 1 -> 1 - 1.5
    np.testing.assert_allclose(r2(y, f), [1.0, -0.5])
    assert isinstance(r2(y[:, 0], f[:, 0]), float)


def test_r2_constant_measured_signal():
    assert r2([2.0, 2.0, 2.0], [2.0, 2.0, 2.0]) == 1.0
    assert r2([2.0, 2.0, 2.0], [2.0, 2.1, 2.0]) == -math.inf


def test_nrmse_fit_hand_computed():
    # ||y - f|| = 1, ||y - mean|| = sqrt(2) -> 100*(1 - 1/sqrt(2))
    assert nrmse_fit_pct([1.0, 2.0, 3.0], [1.0, 2.0, 4.0]) == pytest.approx(100 * (1 - 1 / math.sqrt(2)))
    assert nrmse_fit_pct([1.0, 2.0, 3.0], [1.0, 2.0, 3.0]) == 100.0


def test_nrmse_relates_to_r2():
    rng = np.random.default_rng(0)
    y = rng.standard_normal((200, 3)).cumsum(axis=0)
    f = y + 0.3 * rng.standard_normal(y.shape)
    np.testing.assert_allclose(nrmse_fit_pct(y, f), 100 * (1 - np.sqrt(1 - r2(y, f))))


def test_max_deviation_is_percent_of_peak_to_peak():
    # peak-to-peak of the measured signal: 4 - 0 = 4; worst error 0.2 -> 5 %
    assert max_deviation_pct([0.0, 4.0, 2.0], [0.0, 4.0, 2.2]) == pytest.approx(5.0)
    # an offset does not change the amplitude: 10..14, worst error 0.4 -> 10 %
    assert max_deviation_pct([10.0, 14.0, 12.0], [10.4, 14.0, 12.0]) == pytest.approx(10.0)
    np.testing.assert_allclose(max_deviation_pct(np.array([[0.0, 1.0], [2.0, 3.0]]),
                                                 np.array([[0.1, 1.0], [2.0, 2.0]])), [5.0, 50.0])


def test_max_deviation_constant_signal():
    assert max_deviation_pct([1.0, 1.0], [1.0, 1.0]) == 0.0
    assert max_deviation_pct([1.0, 1.0], [1.0, 1.5]) == math.inf


@pytest.mark.parametrize("func", [r2, nrmse_fit_pct, max_deviation_pct])
def test_bad_arrays_are_data_errors(func):
    with pytest.raises(DataError, match="shape"):
        func([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(DataError, match="NaN"):
        func([1.0, 2.0, 3.0], [1.0, np.nan, 3.0])
    with pytest.raises(DataError, match="numeric"):
        func(["a", "b"], [1.0, 2.0])


def test_metrics_registry():
    assert set(METRICS) >= {"r2", "nrmse", "max_deviation"}
    assert METRICS["max_deviation"][1] is False


def _decay_trajectory(rate: float, n: int, dt: float) -> Trajectory:
    t = dt * np.arange(n)
    return Trajectory.from_arrays(t, {"x": np.exp(-rate * t)}, roles={"x": "state"})


def test_k_step_ahead_error_known_answer_linear():
    # data x = exp(-t); model x' = -2 x predicts x[j+k] as exp(-2 k dt) x[j] instead of exp(-k dt) x[j]
    dt, n, k = 0.01, 500, 7
    data = _decay_trajectory(1.0, n, dt)
    model = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-2.0]]))
    x = data["x"]
    expected = abs(math.exp(-k * dt) - math.exp(-2 * k * dt)) * math.sqrt(np.mean(x[:n - k] ** 2))
    assert k_step_ahead_error(model, data, k)["x"] == pytest.approx(expected, rel=1e-9)


def test_k_step_ahead_error_exact_model_nonlinear():
    # a nonlinear model stepped by RK4 reproduces its own RK4 simulation exactly
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x**3", "u"), coef=np.array([[-1.0, 0.5]]))
    u = np.sign(np.sin(np.arange(400) * 0.05))[:, None]
    data = model.simulate([1.0], u, dt=0.01).to_trajectory()
    err = k_step_ahead_error(model, data, 25)
    assert err["x"] < 1e-12


def test_k_step_ahead_error_bad_k():
    data = _decay_trajectory(1.0, 50, 0.1)
    model = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-1.0]]))
    for k in (0, 50, 2.5, True):
        with pytest.raises(InvalidSettingError, match="k must be"):
            k_step_ahead_error(model, data, k)
    with pytest.raises(InvalidSettingError, match="fit"):
        k_step_ahead_error(object(), data, 1)
