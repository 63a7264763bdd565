"""The PID tuner and its actuator (issue 38): a design that delivers its set-point step through the input limits,
its predicted overshoot the one the loop shows with them, on plants the tuner was not written for.

The plants are mass-spring systems (and a double integrator) written here as matrices; the check runs the tuned
PID itself, limits and anti-windup on, against their exact zero-order-hold discretisation computed here with
``scipy.linalg.expm`` (not the tuner's model code), and compares that loop's overshoot with the prediction.
"""

from __future__ import annotations

import math
import warnings

import control
import numpy as np
import pytest
from scipy.linalg import expm

from controllers.pid import PID, tune_pid
from cosim.errors import CosimDeprecationWarning


def mass_spring(f0: float, mass: float = 2.0, zeta: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """m x'' = F - k x - c x', natural frequency f0 [Hz]: A, B of the state (x, v)."""
    k = mass * (2 * math.pi * f0) ** 2
    c = 2 * zeta * math.sqrt(k * mass)
    return np.array([[0.0, 1.0], [-k / mass, -c / mass]]), np.array([[0.0], [1.0 / mass]])


def as_statespace(a: np.ndarray, b: np.ndarray) -> control.StateSpace:
    return control.ss(a, b, np.eye(2), 0, inputs=["F"], outputs=["x", "v"], states=["x", "v"])


def independent_step(pid: PID, a: np.ndarray, b: np.ndarray, step: float, duration: float) -> tuple[np.ndarray, ...]:
    """The PID called sample by sample against the exact ZOH discretisation of x' = A x + B u (``expm`` of the
    augmented matrix), from rest, set-point `step`: the position and the input at each sample."""
    h = pid.dt
    n = a.shape[0]
    big = expm(np.block([[a, b], [np.zeros((1, n + 1))]]) * h)
    ad, bd = big[:n, :n], big[:n, n]
    pid.reset()
    pid.setpoint = step
    x = np.zeros(n)
    xs, us = [], []
    for k in range(int(round(duration / h))):
        y = x if pid.velocity is not None else x[:1]  # the PID measures (x, v) or x, in the plant's order
        u = float(pid(k * h, y)[0])
        xs.append(x[0])
        us.append(u)
        x = ad @ x + bd * u
    return np.array(xs), np.array(us)


def overshoot_pct(x: np.ndarray, step: float) -> float:
    return max(0.0, float(np.max((x - step) * math.copysign(1.0, step)))) / abs(step) * 100.0


# f0 [Hz], force limit [N], sample time [s], velocity feedback: frequencies, limits and rates apart, with and
# without the measured velocity (the 1.6 Hz, 50 N, 5 kHz plant is run end to end in test_cli_limits.py)
PLANTS = [(1.6, 50.0, 1 / 2000, "v"), (1.6, 50.0, 1 / 2000, None), (0.7, 10.0, 1 / 1000, None),
          (4.0, 200.0, 1 / 2000, "v")]


@pytest.mark.parametrize(("f0", "limit", "dt", "velocity"), PLANTS)
def test_the_predicted_step_is_the_loop_with_its_limits(f0, limit, dt, velocity):
    a, b = mass_spring(f0)
    pid = tune_pid(as_statespace(a, b), dt=dt, tracked="x", velocity=velocity, u_max=limit)
    info = pid.info
    k = -a[1, 0] * 2.0  # spring stiffness [N/m]
    assert pid.u_min.tolist() == [-limit]  # --u-max alone mirrors, in Python as on the CLI
    # the default step: its steady force is half the limit (two digits, rounded down)
    assert info["design_step"] == pytest.approx(0.5 * limit / k, rel=0.1) and info["design_step"] <= 0.5 * limit / k
    assert info["delivers_step"] is True and info["warnings"] == []
    assert info["linear_step_max"] < info["design_step"]  # the step saturates the force: the limit matters
    x, u = independent_step(pid, a, b, info["design_step"], 12 * info["step_settling_time_s"])
    assert np.abs(u).max() == pytest.approx(limit)  # it did saturate
    assert overshoot_pct(x, info["design_step"]) == pytest.approx(info["step_overshoot_pct"], abs=0.5)
    assert info["step_overshoot_pct"] <= 10.0 + 1e-9
    assert abs(x[-1] - info["design_step"]) < 0.02 * info["design_step"]


def test_a_design_that_ignores_the_limit_overshoots_where_the_one_that_respects_it_does_not():
    """The issue's case (1.6 Hz, 50 N, velocity fed back): the design without the limit (a crossover at the
    sample rate's ceiling) overshoots the default step by tens of % once the limit is put on it."""
    a, b = mass_spring(1.6)
    plant = as_statespace(a, b)
    pid = tune_pid(plant, dt=1 / 2000, tracked="x", velocity="v", u_max=50.0)
    blind = tune_pid(plant, dt=1 / 2000, tracked="x", velocity="v")
    blind = PID(**{**blind._settings(), "u_min": -50.0, "u_max": 50.0})
    step = pid.info["design_step"]
    x_blind, _ = independent_step(blind, a, b, step, 1.0)
    x_pid, _ = independent_step(pid, a, b, step, 1.0)
    assert overshoot_pct(x_blind, step) > 30.0 and overshoot_pct(x_pid, step) <= 10.0


def test_an_integrating_plant_keeps_the_linear_design_and_says_which_steps_stay_linear():
    """A double integrator (a mass, no spring) holds any position without force: no step follows from the limit,
    the design is the one without it, and the note gives the largest step that keeps the force within it."""
    mass = control.ss([[0.0, 1.0], [0.0, 0.0]], [[0.0], [0.5]], np.eye(2), 0, inputs=["F"], outputs=["x", "v"])
    pid = tune_pid(mass, dt=1e-3, tracked="x", velocity="v", u_max=20.0)
    free = tune_pid(mass, dt=1e-3, tracked="x", velocity="v")
    assert (pid.kp, pid.ki, pid.kd) == pytest.approx((free.kp, free.ki, free.kd), rel=1e-12)
    assert pid.info["design_step"] is None and pid.info["delivers_step"] is None
    top = pid.info["linear_step_max"]
    assert top > 0 and f"steps up to {top:.3g} stay linear" in pid.info["notes"][0]
    a = np.array([[0.0, 1.0], [0.0, 0.0]])
    _, u = independent_step(pid, a, np.array([[0.0], [0.5]]), 0.999 * top, 2.0)
    assert np.abs(u).max() == pytest.approx(20.0, rel=0.02)  # the largest linear step just reaches the limit
    asked = tune_pid(mass, dt=1e-3, tracked="x", velocity="v", u_max=20.0, step=100 * top)
    assert asked.info["delivers_step"] is True and asked.info["step_overshoot_pct"] <= 10.0 + 1e-9
    assert asked.info["crossover_rad_s"] < pid.info["crossover_rad_s"]  # a big move takes a slower loop


def test_a_step_the_actuator_cannot_hold_is_a_warning_with_the_step_that_stays_linear():
    a, b = mass_spring(1.6)
    k = -a[1, 0] * 2.0
    pid = tune_pid(as_statespace(a, b), dt=1 / 2000, tracked="x", u_max=50.0, step=2 * 50.0 / k)
    (warning,) = pid.info["warnings"]
    assert "needs a steady input of 100, beyond the limits [-50, 50]" in warning and "stay linear" in warning
    assert pid.info["delivers_step"] is False


def test_the_search_predictor_is_the_pid_itself():
    """The vectorised law the search steps (many designs at once) equals the PID class called sample by sample,
    with back-calculation, clamping, a rate limit, a bias and asymmetric limits, with and without the velocity."""
    from controllers.base import DesignModel
    from controllers.pid._plant import _Plant
    from controllers.pid._saturation import _Actuator, _pid_step, _saturated_steps

    a, b = mass_spring(1.6)
    model = DesignModel.from_statespace(as_statespace(a, b), dt=1e-3)
    for velocity in (None, "v"):
        plant = _Plant(model, 0, 0, 0, 1e-3, None if velocity is None else 1)
        for anti_windup, du in (("back-calculation", math.inf), ("clamping", 3.0), (None, math.inf)):
            pid = PID(kp=4e3, ki=4e4, kd=60.0, tf=0.0 if velocity else 2e-3, dt=1e-3, b=0.6, inputs="F",
                      outputs=["x", "v"] if velocity else "x", velocity=velocity, u_min=-20.0, u_max=35.0,
                      du_max=du, u0=2.0, anti_windup=anti_windup)
            act = _Actuator(-20.0, 35.0, du, 2.0, anti_windup, None)
            for step in (0.2, -0.15):
                y, u = _saturated_steps(plant, np.array([[pid.kp, pid.ki, pid.kd, pid.tf]]), np.array([pid.b]),
                                        step, act, 600)
                y_pid, u_pid = _pid_step(pid, plant, step, 600)
                np.testing.assert_allclose(u[:, 0], u_pid, rtol=1e-9, atol=1e-9)
                np.testing.assert_allclose(y[:, 0], y_pid, rtol=1e-9, atol=1e-12)


def test_python_and_the_cli_share_their_limits_and_names():
    a, b = mass_spring(1.6)
    plant = as_statespace(a, b)
    assert tune_pid(plant, dt=1e-3, tracked="x", u_max=5000).u_min.tolist() == [-5000.0]
    assert tune_pid(plant, dt=1e-3, tracked="x", u_min=-math.inf, u_max=5000).u_min.tolist() == [-math.inf]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = tune_pid(plant, dt=1e-3, tracked="x", bandwidth=30.0)
    with pytest.warns(CosimDeprecationWarning, match=r"tune_pid\(output=...\) is deprecated .* use tracked="):
        old = tune_pid(plant, dt=1e-3, output="x", bandwidth=30.0)
    assert old.to_dict() == new.to_dict() and new.tracked == ("x",)
    from controllers.mpc import MPC

    mpc = MPC(plant, dt=1e-3, tracked=["x"], u_max=5000.0, codegen=False)
    assert mpc.u_min.tolist() == [-5000.0] and mpc.u_max.tolist() == [5000.0]
