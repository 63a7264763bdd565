"""Response figures against closed-form answers."""

import math

import numpy as np
import pytest

from cosim.loop.response import jsonable_metrics, response_metrics

T = np.linspace(0.0, 20.0, 200_001)


def test_first_order_lag_known_figures():
    tau = 0.5
    y = 1.0 - np.exp(-T / tau)
    m = response_metrics(T, y, np.ones_like(T), t_event=0.0)
    assert m["rise_time"] == pytest.approx(tau * math.log(9.0), abs=2e-4)       # 10 % -> 90 %
    assert m["settling_time"] == pytest.approx(tau * math.log(50.0), abs=2e-4)  # into the 2 % band
    assert m["overshoot_pct"] == 0.0
    assert m["iae"] == pytest.approx(tau, rel=1e-3)
    assert m["steady_state_error"] < 1e-12


def test_second_order_overshoot_and_offset():
    zeta, wn = 0.3, 4.0
    wd = wn * math.sqrt(1 - zeta ** 2)
    y = 1 - np.exp(-zeta * wn * T) * (np.cos(wd * T) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * T))
    m = response_metrics(T, 0.98 * y, np.ones_like(T), t_event=0.0)  # a 2 % offset at the end
    expected = 100 * (0.98 * (1 + math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))) - 1)
    assert m["overshoot_pct"] == pytest.approx(expected, rel=1e-4)
    assert m["steady_state_error"] == pytest.approx(0.02, rel=1e-6)


def test_step_at_event_time_and_band_choices():
    r = np.where(T >= 1.0, 2.0, 0.5)
    y = np.where(T >= 1.0, 2.0 - 1.5 * np.exp(-(T - 1.0)), 0.5)
    m = response_metrics(T, y, r)  # event found from the reference
    assert m["step"] == pytest.approx(1.5)
    assert m["settling_time"] == pytest.approx(math.log(50.0), abs=2e-4)
    m_abs = response_metrics(T, y, r, band_abs=1.5 * 0.1)
    assert m_abs["settling_time"] == pytest.approx(math.log(10.0), abs=2e-4)
    m_peak = response_metrics(T, y, r, band_peak=0.1)
    assert m_peak["settling_time"] == pytest.approx(math.log(10.0), abs=2e-4)


def test_ramp_still_moving_has_no_settling_or_overshoot():
    m = response_metrics(T, 0.9 * T, T, t_event=0.0)
    assert math.isnan(m["settling_time"]) and math.isnan(m["overshoot_pct"])
    assert m["steady_state_error"] == pytest.approx(0.1 * np.mean(T[-20_000:]), rel=1e-6)


def test_never_settles_is_nan_and_json_has_none():
    y = np.sin(T)
    m = response_metrics(T, y, np.ones_like(T), t_event=0.0)
    assert math.isnan(m["settling_time"])
    assert jsonable_metrics(m)["settling_time"] is None
