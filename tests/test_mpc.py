"""MPC: LQR equivalence, bounds, offset-free tracking, observer, codegen = Python path, files, fallbacks, errors,
and a closed loop against the bundled FMU."""

from __future__ import annotations

import control
import numpy as np
import pytest

from controllers import load_controller
from controllers.mpc import MPC
from cosim import FmuPlant, build_fmu
from cosim.errors import ControllerError, InvalidSettingError, UnknownVariableError
from cosim.study.paper import STUDY_DT, two_mass_matrices

DT = STUDY_DT
NAMES = ["theta_m", "omega_m", "theta_L", "omega_L"]
POSITIONS = ["theta_m", "theta_L"]


def two_mass(inputs: int = 1) -> control.StateSpace:
    """The true linear two-mass model (continuous), all four states as outputs."""
    A, B = two_mass_matrices()
    return control.ss(A, B[:, :inputs], np.eye(4), 0, states=NAMES, inputs=["Tm", "TL"][:inputs], outputs=NAMES)


def discrete_plant() -> tuple[np.ndarray, np.ndarray]:
    """ZOH-discretised two-mass plant with both inputs (Tm, TL): the 'true' plant of the numpy loops."""
    A, B = two_mass_matrices()
    d = control.c2d(control.ss(A, B, np.eye(4), 0), DT, method="zoh")
    return d.A, d.B


def run_loop(mpc: MPC, steps: int, *, x0=None, tl: float = 0.0, tm_offset: float = 0.0, setpoint: float = 0.01):
    """Closed loop of `mpc` and the discrete two-mass plant; returns states (steps+1, 4) and inputs (steps, m)."""
    A, B = discrete_plant()
    x = np.zeros(4) if x0 is None else np.array(x0, dtype=float)
    mpc.setpoint = setpoint
    idx = [NAMES.index(n) for n in mpc.outputs]
    xs, us = [x.copy()], []
    for k in range(steps):
        u = mpc(k * DT, x[idx])
        x = A @ x + B @ np.array([u[0] + tm_offset, tl])
        xs.append(x.copy())
        us.append(u)
    return np.array(xs), np.array(us)


# ------------------------------------------------------------------ unconstrained: the LQR law
@pytest.mark.parametrize("horizon", [1, 5, 20])
def test_first_move_equals_lqr_for_any_horizon(horizon):
    Q, R = np.diag([1e6, 10.0, 1e6, 10.0]), np.array([[1e-6]])
    mpc = MPC(two_mass(), dt=DT, horizon=horizon, tracked=["theta_L"], q=0.0, q_rate=0.0, q_states=Q, r=R,
              r_delta=0.0, disturbance=None, observer={"gain": np.eye(4)})
    K, _, _ = control.dlqr(mpc.model.A, mpc.model.B, Q, R)
    rng = np.random.default_rng(horizon)
    for setpoint in (0.0, 0.02):
        mpc.reset()
        mpc.setpoint = setpoint
        xs = np.array([setpoint, 0.0, setpoint, 0.0])  # rigid-body rest at the setpoint, us = 0
        x = rng.normal(scale=[1e-3, 0.05, 1e-3, 0.05])
        u = mpc(0.0, x)
        expected = -K @ (x - xs)
        np.testing.assert_allclose(u, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())
        np.testing.assert_allclose(mpc.target[0], xs, atol=1e-12)
    rho = np.max(np.abs(np.linalg.eigvals(mpc.model.A - mpc.model.B @ K)))
    assert mpc.info["closed_loop_spectral_radius"] == pytest.approx(rho, rel=1e-9)


def test_rate_penalty_first_move_equals_augmented_lqr():
    """With r_delta the terminal Riccati cost is that of the model augmented with the previous input."""
    Q, R, S = np.diag([1e6, 10.0, 1e6, 10.0]), np.array([[1e-6]]), np.array([[5e-6]])
    mpc = MPC(two_mass(), dt=DT, horizon=7, q=0.0, q_rate=0.0, q_states=Q, r=R, r_delta=S, disturbance=None,
              observer={"gain": np.eye(4)}, u0=120.0)
    A, B = mpc.model.A, mpc.model.B
    Az = np.block([[A, np.zeros((4, 1))], [np.zeros((1, 5))]])
    Bz = np.vstack([B, [[1.0]]])
    Kz, _, _ = control.dlqr(Az, Bz, np.diag([*np.diag(Q), S[0, 0]]), R + S, np.vstack([np.zeros((4, 1)), -S]))
    x = np.array([2e-3, -0.1, 1e-3, 0.05])
    u = mpc(0.0, x)
    np.testing.assert_allclose(u, -Kz @ np.concatenate([x, [120.0]]), rtol=1e-6)


# ------------------------------------------------------------------ bounds and rate bounds
def test_input_and_rate_bounds_hold_and_are_active():
    u_min, u_max, du = -300.0, 500.0, 40.0
    mpc = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=u_min, u_max=u_max, du_max=du)
    free = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"])
    free.setpoint = 0.01
    assert free(0.0, [0.0, 0.0])[0] > u_max  # unconstrained first move: far outside
    xs, us = run_loop(mpc, 3000)
    u = us[:, 0]
    assert np.all(u >= u_min) and np.all(u <= u_max)
    steps = np.abs(np.diff(np.concatenate([[0.0], u])))
    assert np.all(steps <= du + 1e-9)
    assert u[0] == pytest.approx(du, abs=1e-9)  # the rate bound is active on the first move
    assert np.any(np.isclose(u, u_max, atol=1e-7)) and np.any(np.isclose(u, u_min, atol=1e-7))
    assert abs(xs[-1, 2] - 0.01) < 1e-4  # and it still gets there


def test_soft_state_bound_limits_the_speed():
    kw = dict(dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    free_x, _ = run_loop(MPC(two_mass(), **kw), 3000, setpoint=0.05)
    soft = MPC(two_mass(), state_bounds={"omega_L": (None, 0.05)}, **kw)
    soft_x, _ = run_loop(soft, 3000, setpoint=0.05)
    assert free_x[:, 3].max() > 0.2
    assert soft_x[:, 3].max() < 0.05 * 1.01
    assert abs(soft_x[-1, 2] - 0.05) < 1e-3  # slower, but it gets there
    assert soft.info["qp_variables"] == 21 and soft.info["qp_constraints"] == 20


# ------------------------------------------------------------------ offset-free tracking and the observer
@pytest.mark.parametrize("disturbance", [{"tm_offset": 300.0}, {"tl": -400.0}])
def test_offset_free_with_unmodelled_constant_disturbance(disturbance):
    kw = dict(dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    xs, _ = run_loop(MPC(two_mass(), **kw), int(3 / DT), **disturbance)
    assert abs(xs[-1, 2] - 0.01) < 1e-6 * 0.01
    xs_none, _ = run_loop(MPC(two_mass(), disturbance=None, **kw), int(3 / DT), **disturbance)
    assert abs(xs_none[-1, 2] - 0.01) > 1e-3 * 0.01  # without the disturbance model: an offset


def test_two_inputs_track_two_outputs_without_offset():
    """Both torques manipulated, both angles tracked, constant unmodelled torques on both sides."""
    mpc = MPC(two_mass(inputs=2), dt=DT, inputs=["Tm", "TL"], outputs=POSITIONS, tracked=POSITIONS,
              u_min=[-5000, -5000], u_max=[5000, 5000], du_max=[1000, 1000], q_rate=[3e3, 3e3])
    assert mpc.info["disturbances"] == ["input:Tm", "input:TL"]
    A, B = discrete_plant()
    x = np.zeros(4)
    mpc.setpoint = [0.01, 0.0102]  # a twist of 0.2 mrad held by the two torques
    for k in range(int(3 / DT)):
        u = mpc(k * DT, x[[0, 2]])
        assert np.all(np.abs(u) <= 5000)
        x = A @ x + B @ (u + np.array([150.0, -80.0]))
    np.testing.assert_allclose(x[[0, 2]], [0.01, 0.0102], rtol=1e-6)
    np.testing.assert_allclose(mpc.target[1], [-500.0 - 150.0, 500.0 + 80.0], rtol=1e-4)  # KL * twist


def test_unmanipulated_model_input_is_an_unmeasured_disturbance():
    mpc = MPC(two_mass(inputs=2), dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    assert mpc.inputs == ("Tm",)  # default: the first model input; TL is taken as 0 and estimated away
    xs, _ = run_loop(mpc, int(3 / DT), tl=-300.0)
    assert abs(xs[-1, 2] - 0.01) < 1e-8


def test_disturbance_model_labels_and_estimate():
    mpc = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"])
    assert mpc.info["disturbances"] == ["input:Tm", "output:theta_m"]
    run_loop(mpc, int(2 / DT), tm_offset=250.0)
    np.testing.assert_allclose(mpc.disturbance_estimate, [250.0, 0.0], atol=1e-3)


def test_observer_estimates_unmeasured_velocities():
    mpc = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    A, B = discrete_plant()
    x = np.array([0.004, 0.3, -0.002, -0.2])
    mpc.setpoint = 0.0
    errors = []
    for k in range(int(1.0 / DT)):
        u = mpc(k * DT, x[[0, 2]])
        errors.append(np.abs(mpc.estimate - x))
        x = A @ x + B @ np.array([u[0], 0.0])
    assert errors[0][1] > 0.1 and errors[0][3] > 0.1  # the velocities were unknown at first
    assert np.all(errors[-1] < 1e-5 * errors[0])
    assert mpc.info["observer_spectral_radius"] < 1
    np.testing.assert_allclose(mpc.disturbance_estimate, 0.0, atol=1e-3)


def test_constant_input_is_held_at_one():
    """An identified model with a constant term: the target accounts for it, no disturbance model needed."""
    sys = control.ss([[-1.0]], [[1.0, 0.5]], [[1.0]], [[0.0, 0.0]], states=["x"], inputs=["u", "const"],
                     outputs=["y"])
    mpc = MPC(sys, dt=0.01, q=1.0, q_rate=0.0, r=1e-3, disturbance=None)
    assert mpc.inputs == ("u",)
    model = mpc.model
    x = np.zeros(1)
    mpc.setpoint = 2.0
    for k in range(2000):
        u = mpc(k * 0.01, x)
        x = model.A @ x + model.B @ np.array([u[0], 1.0])
    assert x[0] == pytest.approx(2.0, abs=1e-9)
    assert mpc.target[1][0] == pytest.approx(1.5, abs=1e-9)


# ------------------------------------------------------------------ paths, files, reset
def test_codegen_and_python_paths_agree():
    kw = dict(dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-2000, u_max=2000, du_max=300.0,
              state_bounds={"omega_L": (-0.08, 0.08)})
    fast, slow = MPC(two_mass(), **kw), MPC(two_mass(), codegen=False, **kw)
    assert fast.info["solver_path"] == "c:daqp" and slow.info["solver_path"] == "python:daqp"
    A, B = discrete_plant()
    x = np.array([0.0, 0.1, 0.0, 0.0])
    fast.setpoint = slow.setpoint = 0.02
    worst = 0.0
    for k in range(800):
        u, v = fast(k * DT, x[[0, 2]]), slow(k * DT, x[[0, 2]])
        worst = max(worst, float(np.max(np.abs(u - v))))
        x = A @ x + B @ np.array([u[0] + 50.0, 0.0])
    assert worst <= 1e-9
    np.testing.assert_allclose(fast.estimate, slow.estimate, rtol=1e-12, atol=1e-15)


def test_json_round_trip_gives_identical_inputs(tmp_path):
    mpc = MPC(two_mass(), dt=DT, horizon=12, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000,
              du_max=800.0, state_bounds={"omega_m": (-2.0, 2.0)}, x0={"theta_m": 1e-3}, u0=10.0,
              observer={"measurement_noise": [1e-6, 2e-6], "state_noise": {"omega_L": 1e-4}})
    path = mpc.save(tmp_path / "mpc.json")
    loaded = load_controller(path)
    assert isinstance(loaded, MPC) and loaded.horizon == 12 and loaded.tracked == ("theta_L",)
    assert loaded.to_dict() == mpc.to_dict()
    assert "library" not in path.read_text() and loaded.info["solver_path"] == "c:daqp"  # facts of this machine
    for c in (mpc, loaded):
        c.setpoint = 0.01
    rng = np.random.default_rng(1)
    for k in range(300):
        y = rng.normal(scale=1e-3, size=2)
        np.testing.assert_array_equal(mpc(k * DT, y), loaded(k * DT, y))


def test_reset_reproduces_the_same_inputs():
    mpc = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    _, first = run_loop(mpc, 400)
    mpc.reset()
    _, again = run_loop(mpc, 400)
    np.testing.assert_array_equal(first, again)


def test_compiled_library_is_cached_and_reused():
    kw = dict(dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000, horizon=9)
    a, b = MPC(two_mass(), **kw), MPC(two_mass(), **kw)
    assert a.info["library"] == b.info["library"]
    assert "/mpc/" in a.info["library"].replace("\\", "/")
    assert MPC(two_mass(), **{**kw, "horizon": 10}).info["library"] != a.info["library"]


def test_without_a_compiler_falls_back_to_python(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path / "cache"))
    with pytest.warns(RuntimeWarning, match="not compiled"):
        mpc = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    assert mpc.info["solver_path"] == "python:daqp" and "compiler" in mpc.info["codegen_unavailable"]
    mpc.setpoint = 0.01
    assert mpc(0.0, [0.0, 0.0])[0] == pytest.approx(5000.0)


# ------------------------------------------------------------------ infeasible problems and fallbacks
def infeasible_mpc(**kw) -> MPC:
    """Hard bound on the motor speed: feasible at rest; infeasible once the encoder says the motor jumped."""
    return MPC(two_mass(), dt=DT, horizon=10, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000,
               du_max=2000.0, state_bounds={"omega_m": (-0.2, 0.2)}, hard_state_bounds=True, **kw)


JUMP = [0.01, 0.0]  # theta_m 10 mrad away from one sample to the next: the observer sees the motor racing


@pytest.mark.parametrize("codegen", [True, False])
def test_infeasible_qp_applies_the_previous_plan(codegen):
    mpc = infeasible_mpc(codegen=codegen)
    mpc.setpoint = 2e-4  # a small step: the plan stays clear of the torque bound
    for k in range(20):
        u = mpc(k * DT, [0.0, 0.0])
    assert not mpc.events
    plan = mpc.plan
    assert 100 < plan[0, 0] < 5000 and plan[0, 0] != plan[1, 0]
    for j in range(3):
        u = mpc((20 + j) * DT, JUMP)
        assert abs(mpc.estimate[1]) > 0.2  # estimated motor speed beyond the hard bound: no feasible plan
        assert len(mpc.events) == j + 1 and mpc.events[j].kind == "infeasible"
        assert mpc.events[j].time == (20 + j) * DT
        assert f"move {j + 1} of the last good plan" in mpc.events[j].message
        np.testing.assert_array_equal(u, plan[j])  # within the bounds and the rate bound: applied as planned


def test_infeasible_for_too_long_raises_with_time_and_reason():
    mpc = infeasible_mpc(max_fallbacks=3)
    with pytest.raises(ControllerError, match=r"t=0.00177226 s: daqp found no optimal solution.* 4 consecutive"):
        for k in range(10):
            mpc(k * DT, [0.01 * k, 0.0])  # from k = 1 the encoder says the motor turns at 22 rad/s
    assert len(mpc.events) == 3


def test_infeasible_hold_and_raise():
    hold = infeasible_mpc(on_infeasible="hold", u0=100.0)
    hold.setpoint = 0.001
    assert hold(0.0, JUMP)[0] == 100.0 and "held the previous input" in hold.events[0].message
    now = infeasible_mpc(on_infeasible="raise")
    with pytest.raises(ControllerError, match="infeasible"):
        now(0.0, JUMP)


# ------------------------------------------------------------------ user mistakes: one-line errors
@pytest.mark.parametrize("kwargs, error, match", [
    (dict(horizon=0), InvalidSettingError, "horizon"),
    (dict(horizon=2.5), InvalidSettingError, "horizon"),
    (dict(u_min=5.0, u_max=5.0), InvalidSettingError, "u_min < u_max"),
    (dict(inputs=["Torque"]), UnknownVariableError, "Torque"),
    (dict(outputs=["theta_x"]), UnknownVariableError, "theta_x"),
    (dict(tracked=["speed"]), UnknownVariableError, "speed"),
    (dict(outputs=["theta_m"], tracked=["theta_L"]), InvalidSettingError, "not measured"),
    (dict(state_bounds={"omega": (-1, 1)}), UnknownVariableError, "omega"),
    (dict(state_bounds={"omega_m": (1, -1)}), InvalidSettingError, "lo < hi"),
    (dict(q={"theta_x": 1.0}), UnknownVariableError, "theta_x"),
    (dict(q=[1.0, 2.0]), InvalidSettingError, "shape"),
    (dict(r=-1.0), InvalidSettingError, "non-negative"),
    (dict(r=0.0, r_delta=0.0), InvalidSettingError, "positive"),
    (dict(observer={"noise": 1.0}), InvalidSettingError, "observer has no setting"),
    (dict(observer={"gain": np.eye(3)}), InvalidSettingError, "observer gain"),
    (dict(disturbance="both"), InvalidSettingError, "disturbance"),
    (dict(solver="nope"), InvalidSettingError, "solver"),
    (dict(on_infeasible="ignore"), InvalidSettingError, "on_infeasible"),
    (dict(u_max=10.0, u0=20.0), InvalidSettingError, "u0"),
    (dict(soft_weight=0.0), InvalidSettingError, "soft_weight"),
    (dict(dt=None), InvalidSettingError, "dt"),
    (dict(disturbance="output"), ControllerError, "detectable"),
    (dict(outputs=["omega_m", "omega_L"], tracked=["omega_L"]), ControllerError, "do not see"),
])
def test_bad_settings_are_one_line_errors(kwargs, error, match):
    kw = dict(dt=DT, outputs=POSITIONS, tracked=["theta_L"])
    with pytest.raises(error, match=match) as info:
        MPC(two_mass(), **{**kw, **kwargs})
    assert "\n" not in str(info.value)


def test_bad_model_and_measurements():
    with pytest.raises(InvalidSettingError, match="StateSpace"):
        MPC(np.eye(2), dt=DT)
    mpc = MPC(two_mass(), dt=DT, outputs=POSITIONS, tracked=["theta_L"])
    for y in ([0.0], [0.0, 0.0, 0.0], 1.0, ["a", "b"]):
        with pytest.raises(InvalidSettingError, match="2 measured output"):
            mpc(0.0, y)
    with pytest.raises(InvalidSettingError, match="setpoint"):
        mpc.setpoint = [1.0, 2.0]
    with pytest.raises(ControllerError, match="non-finite measurement"):
        mpc(0.0, [np.nan, 0.0])


# ------------------------------------------------------------------ against the bundled FMU
def test_fmu_step_settles_without_offset_under_coulomb_friction():
    sys = two_mass()
    mpc = MPC(sys, dt=DT, outputs=POSITIONS, tracked=["theta_L"], u_min=-5000, u_max=5000)
    ref = 0.01
    mpc.setpoint = ref
    steps = int(round(2.0 / DT))
    theta = np.empty(steps)
    with FmuPlant(build_fmu(), dt=DT, parameters={"Fc": 100.0}) as plant:
        y = plant.read_outputs()
        for k in range(steps):
            u = mpc(k * DT, y[[0, 2]])
            assert abs(u[0]) <= 5000
            y = plant.step([u[0], 0.0])
            theta[k] = y[2]
    t = np.arange(1, steps + 1) * DT
    outside = np.flatnonzero(np.abs(theta - ref) > 0.02 * ref)
    settling = t[outside[-1]] if outside.size else 0.0
    assert settling <= 0.5
    assert (theta.max() - ref) / ref < 0.05
    assert abs(theta[-1] - ref) < 1e-5
    assert not mpc.events
