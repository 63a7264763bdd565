"""Exports of identified models: python-control StateSpace, MATLAB .mat, generated FMI 2.0 FMU, JSON.

Known answers: the two-mass plant's true A, B (fmus/two_mass_servo/README.md) as a model; every export is
checked against IdentifiedModel.simulate, the reference for how a model steps (exact ZOH / RK4).
"""

from __future__ import annotations

import zipfile

import control
import numpy as np
import pytest
import scipy.io
from fmpy.validation import validate_fmu

import cosim.identify.terms
from cosim import simulate
from cosim.errors import BuildError, FmiCallError, InvalidSettingError, UnknownVariableError
from cosim.export import (
    CONSTANT_INPUT,
    OperatingPoint,
    export,
    export_fmu,
    export_mat,
    operating_point,
    to_statespace,
)
from cosim.identify.model import IdentifiedModel

JM, JL, KL, BM, BL = 250.0, 1000.0, 2.5e6, 50.0, 500.0
STATES = ("theta_m", "omega_m", "theta_L", "omega_L")
INPUTS = ("Tm", "TL")
A = np.array([[0.0, 1.0, 0.0, 0.0],
              [-KL / JM, -(BM + BL) / JM, KL / JM, BL / JM],
              [0.0, 0.0, 0.0, 1.0],
              [KL / JL, BL / JL, -KL / JL, -BL / JL]])
B = np.array([[0.0, 0.0], [1.0 / JM, 0.0], [0.0, 0.0], [0.0, 1.0 / JL]])
OFFSET = 100.0  # N m of torque offset on the motor side: the constant term
C_OFFSET = np.array([0.0, OFFSET / JM, 0.0, 0.0])
X0 = np.array([-2.0, 0.0, 2.0, 1.0])
DT, N = 1e-3, 1000


def named(names, values) -> dict:
    return dict(zip(names, values, strict=True))


def rel_err(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.abs(got - want)) / np.max(np.abs(want)))


@pytest.fixture(scope="module")
def linear() -> IdentifiedModel:
    return IdentifiedModel(states=STATES, inputs=INPUTS, terms=STATES + INPUTS, coef=np.hstack([A, B]), dt=DT)


@pytest.fixture(scope="module")
def with_constant() -> IdentifiedModel:
    return IdentifiedModel(states=STATES, inputs=INPUTS, terms=("1",) + STATES + INPUTS,
                           coef=np.hstack([C_OFFSET[:, None], A, B]), dt=DT)


@pytest.fixture(scope="module")
def nonlinear() -> IdentifiedModel:
    """Coulomb-like friction on the motor (smooth sign) and a gravity unbalance on the load."""
    extra = np.array([[0.0, 0.0], [-20.0 / JM, 0.0], [0.0, 0.0], [0.0, -300.0 / JL]])
    return IdentifiedModel(states=STATES, inputs=INPUTS, terms=STATES + INPUTS + ("tanh(omega_m/0.01)",
                                                                                  "sin(theta_L)"),
                           coef=np.hstack([A, B, extra]), dt=DT)


@pytest.fixture(scope="module")
def u() -> np.ndarray:
    """Random steps of Tm and TL, each held 50 samples."""
    rng = np.random.default_rng(1)
    return np.repeat(rng.uniform(-500.0, 500.0, (N // 50, 2)), 50, axis=0)


def forced(sys: control.StateSpace, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """States (n+1 rows) of a discrete system under the ZOH inputs u (n rows)."""
    t = sys.dt * np.arange(len(u) + 1)
    return control.forced_response(sys, t, np.vstack([u, u[-1:]]).T, X0=x0).outputs.T


# --------------------------------------------------------------------------------------------- StateSpace
def test_continuous_statespace_is_the_plant(linear):
    sys = to_statespace(linear, name="servo")
    np.testing.assert_array_equal(sys.A, A)
    np.testing.assert_array_equal(sys.B, B)
    np.testing.assert_array_equal(sys.C, np.eye(4))
    np.testing.assert_array_equal(sys.D, np.zeros((4, 2)))
    assert sys.dt == 0 and sys.name == "servo"
    assert sys.state_labels == list(STATES) and sys.output_labels == list(STATES)
    assert sys.input_labels == list(INPUTS)
    assert sys.operating_point.states == dict.fromkeys(STATES, 0.0)


def test_discrete_statespace_steps_like_the_model(linear, u):
    sysd = to_statespace(linear, dt=DT)
    assert sysd.dt == DT
    np.testing.assert_allclose(sysd.A, control.c2d(to_statespace(linear), DT, "zoh").A, rtol=0, atol=1e-13)
    ref = linear.simulate(X0, u, dt=DT)
    assert rel_err(forced(sysd, u, X0), ref.states) < 1e-9


def test_constant_as_input(with_constant, u):
    sys = to_statespace(with_constant, dt=DT)
    assert sys.input_labels == [*INPUTS, CONSTANT_INPUT]
    np.testing.assert_array_equal(to_statespace(with_constant).B[:, -1], C_OFFSET)
    ref = with_constant.simulate(X0, u, dt=DT)
    got = forced(sys, np.column_stack([u, np.ones(len(u))]), X0)  # 1 on the const input
    assert rel_err(got, ref.states) < 1e-9


def test_constant_ignored_only_on_request(with_constant):
    sys = to_statespace(with_constant, constant="ignore")
    assert sys.input_labels == list(INPUTS)
    np.testing.assert_array_equal(sys.A, A)
    np.testing.assert_array_equal(sys.B, B)
    with pytest.raises(InvalidSettingError, match="constant='drop' is not one of"):
        to_statespace(with_constant, constant="drop")


def test_zero_constant_adds_nothing(linear):
    model = IdentifiedModel(states=STATES, inputs=INPUTS, terms=("1",) + STATES + INPUTS,
                            coef=np.hstack([np.zeros((4, 1)), A, B]))
    for mode in ("input", "operating_point", "ignore"):
        assert to_statespace(model, constant=mode).input_labels == list(INPUTS)


def test_constant_at_the_operating_point(with_constant, u):
    """A is singular (rigid-body mode): the offset is balanced by the motor torque, Tm = -OFFSET."""
    op = operating_point(with_constant)
    assert op.inputs["Tm"] == pytest.approx(-OFFSET, rel=1e-12) and op.inputs["TL"] == 0.0
    assert np.linalg.norm(A @ op.x + B @ op.u + C_OFFSET) < 1e-12
    sys = to_statespace(with_constant, dt=DT, constant="operating_point")
    assert sys.input_labels == list(INPUTS)
    assert sys.operating_point.states == pytest.approx(op.states, abs=1e-15)
    # the deviation model about the equilibrium reproduces the model with its constant
    ref = with_constant.simulate(X0, u, dt=DT)
    got = forced(sys, u - op.u, X0 - op.x) + op.x
    assert rel_err(got, ref.states) < 1e-9
    # the load torque can balance it instead, when it is the one allowed to move
    assert operating_point(with_constant, free_inputs=["TL"]).inputs == pytest.approx({"Tm": 0.0, "TL": -OFFSET})
    with pytest.raises(InvalidSettingError, match="no equilibrium.*constant='input'"):
        operating_point(with_constant, free_inputs=[])


def test_operating_point_of_a_regular_model_needs_no_input():
    model = IdentifiedModel(states=("a", "b"), inputs=("u",), terms=("1", "a", "b", "u"),
                            coef=np.array([[1.0, -2.0, 1.0, 1.0], [0.5, 0.0, -3.0, 0.0]]))
    op = operating_point(model)
    a = np.array([[-2.0, 1.0], [0.0, -3.0]])
    np.testing.assert_allclose(op.x, np.linalg.solve(a, [-1.0, -0.5]), rtol=1e-14)
    assert op.inputs == {"u": 0.0}


# --------------------------------------------------------------------------------------------- nonlinear
def test_nonlinear_model_needs_an_operating_point(nonlinear):
    with pytest.raises(InvalidSettingError, match=r"tanh\(omega_m/0.01\), sin\(theta_L\).*operating_point="):
        to_statespace(nonlinear)


def test_linearisation_matches_finite_differences(nonlinear):
    x_op = np.array([0.1, 0.003, 0.2, -0.002])
    u_op = np.array([50.0, -20.0])
    sys = to_statespace(nonlinear, operating_point=(named(STATES, x_op), named(INPUTS, u_op)))
    z = np.concatenate([x_op, u_op])
    jac = np.zeros((4, 6))
    for k in range(6):
        h = 1e-6 * max(1.0, abs(z[k]))
        e = np.zeros(6)
        e[k] = h
        jac[:, k] = (nonlinear.rhs((z + e)[:4], (z + e)[4:]) - nonlinear.rhs((z - e)[:4], (z - e)[4:])) / (2 * h)
    analytic = np.hstack([sys.A, sys.B[:, :2]])
    np.testing.assert_allclose(analytic, jac, rtol=1e-6, atol=1e-9 * np.abs(jac).max())
    # the friction slope at omega_m = 0.003: -20/Jm * (1 - tanh(0.3)^2) / 0.01, added to the viscous part
    assert sys.A[1, 1] == pytest.approx(-(BM + BL) / JM - 20.0 / JM * (1 - np.tanh(0.3) ** 2) / 0.01, rel=1e-14)
    # not an equilibrium: rhs(x_op, u_op) is the const input's column; states are deviations from x_op
    assert sys.input_labels[-1] == CONSTANT_INPUT
    np.testing.assert_allclose(sys.B[:, -1], nonlinear.rhs(x_op, u_op), rtol=1e-15)
    assert sys.operating_point.x.tolist() == x_op.tolist()


def test_nonlinear_equilibrium(nonlinear):
    """Tm = 50, TL = -20 held: the load settles where 300 sin(theta_L) = 30, twisted by 50/KL."""
    sys = to_statespace(nonlinear, operating_point=(np.zeros(4), [50.0, -20.0]), constant="operating_point")
    op = sys.operating_point
    assert op.states["theta_L"] == pytest.approx(np.arcsin(0.1), rel=1e-12)
    assert op.states["theta_m"] - op.states["theta_L"] == pytest.approx(50.0 / KL, rel=1e-6)
    assert op.inputs == {"Tm": 50.0, "TL": -20.0}
    assert sys.input_labels == list(INPUTS)
    assert sys.A[3, 2] == pytest.approx(-KL / JL - 300.0 / JL * np.cos(np.arcsin(0.1)), rel=1e-12)


def test_operating_point_arguments_are_checked(nonlinear):
    with pytest.raises(UnknownVariableError, match="'speed' is not a state"):
        to_statespace(nonlinear, operating_point=({"speed": 1.0}, [0.0, 0.0]))
    with pytest.raises(InvalidSettingError, match="no value for the state omega_L"):
        to_statespace(nonlinear, operating_point=({"theta_m": 0, "omega_m": 0, "theta_L": 0}, [0.0, 0.0]))
    with pytest.raises(InvalidSettingError, match="expected 2 finite input values"):
        to_statespace(nonlinear, operating_point=(np.zeros(4), [0.0]))
    with pytest.raises(InvalidSettingError, match=r"\(x_op, u_op\)"):
        to_statespace(nonlinear, operating_point=np.zeros(6))
    assert isinstance(operating_point(nonlinear), OperatingPoint)


# --------------------------------------------------------------------------------------------- MATLAB
def test_mat_round_trip(with_constant, tmp_path):
    path = export_mat(with_constant, tmp_path / "servo.mat", dt=DT)
    data = scipy.io.loadmat(path)
    sys = to_statespace(with_constant, dt=DT)
    for key in ("A", "B", "C", "D"):
        np.testing.assert_array_equal(data[key], getattr(sys, key))
    assert data["dt"].item() == DT

    def names(key: str) -> list[str]:
        return [str(cell.item()) for cell in data[key].ravel()]

    assert names("StateName") == list(STATES) and names("OutputName") == list(STATES)
    assert names("InputName") == [*INPUTS, CONSTANT_INPUT]
    assert data["ConstantInput"].item() == CONSTANT_INPUT
    assert names("Equations")[1] == ("omega_m' = 0.4 - 10000 theta_m - 2.2 omega_m + 10000 theta_L + 2 omega_L "
                                     "+ 0.004 Tm")
    continuous = scipy.io.loadmat(export_mat(with_constant, tmp_path / "c.mat", constant="operating_point"))
    assert continuous["dt"].item() == 0.0
    np.testing.assert_array_equal(continuous["A"], A)
    assert continuous["u_op"].ravel()[0] == pytest.approx(-OFFSET)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mat", "servo.mat"]  # no temporary files left


# --------------------------------------------------------------------------------------------- FMU
@pytest.mark.parametrize("which", ["linear", "with_constant", "nonlinear"])
def test_fmu_reproduces_the_model(which, request, u, tmp_path):
    model = request.getfixturevalue(which)
    nsub = 1 if model.is_linear else 4
    path = export_fmu(model, tmp_path / f"{which}.fmu", dt=DT, nsub=nsub)
    assert validate_fmu(str(path)) == []
    names = zipfile.ZipFile(path).namelist()
    assert {"sources/model.c", "sources/model.h", "sources/fmi2.c", "modelDescription.xml"} <= set(names)
    traj = simulate(path, named(INPUTS, u.T), duration=N * DT, dt=DT, start=named(STATES, X0))
    assert traj.states == STATES
    got = np.column_stack([traj[s] for s in STATES])
    ref = model.simulate(X0, u, dt=DT, nsub=nsub)
    assert rel_err(got, ref.states) < 1e-6
    if not model.is_linear:  # nsub is a parameter of the nonlinear FMU
        traj = simulate(path, named(INPUTS, u.T), duration=N * DT, dt=DT, start=named(STATES, X0),
                        parameters={"nsub": 9})
        ref = model.simulate(X0, u, dt=DT, nsub=9)
        assert rel_err(np.column_stack([traj[s] for s in STATES]), ref.states) < 1e-6


def test_linear_fmu_steps_only_in_multiples_of_its_dt(linear, u, tmp_path):
    path = export_fmu(linear, tmp_path / "servo.fmu")  # dt from the model
    double = simulate(path, named(INPUTS, u[::2].T), duration=N * DT, dt=2 * DT, start=named(STATES, X0))
    ref = linear.simulate(X0, np.repeat(u[::2], 2, axis=0), dt=DT)
    assert rel_err(np.column_stack([double[s] for s in STATES]), ref.states[::2]) < 1e-6
    with pytest.raises(FmiCallError, match="not a whole multiple of dt = 0.001.*export the model again"):
        simulate(path, {"Tm": 1.0}, duration=0.015, dt=1.5e-3)


def test_fmu_divergence_is_an_error(tmp_path):
    model = IdentifiedModel(states=("x",), inputs=(), terms=("x**2",), coef=np.array([[1.0]]))
    path = export_fmu(model, tmp_path / "blowup.fmu", dt=0.01)
    assert model.simulate([1.0], n_steps=200, dt=0.01).status == "diverged"
    with pytest.raises(FmiCallError, match="state x diverged"):
        simulate(path, duration=2.0, dt=0.01, start={"x": 1.0})


def test_fmu_refuses_what_it_cannot_express(tmp_path, monkeypatch):
    clip = (lambda v: np.clip(v, -1, 1), lambda v: min(1.0, max(-1.0, v)), "cosim_clip")
    monkeypatch.setitem(cosim.identify.terms.FUNCTIONS, "clip", clip)
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "clip(u)"), coef=np.array([[-1.0, 1.0]]))
    with pytest.raises(InvalidSettingError, match=r"term 'clip\(u\)' uses clip, which the generated C cannot"):
        export_fmu(model, tmp_path / "clip.fmu", dt=0.01)
    reserved = IdentifiedModel(states=("time",), inputs=(), terms=("time",), coef=np.array([[-1.0]]))
    with pytest.raises(InvalidSettingError, match="state name 'time' is reserved"):
        export_fmu(reserved, tmp_path / "time.fmu", dt=0.01)
    assert not list(tmp_path.iterdir())


def test_fmu_settings_are_checked(linear, nonlinear, tmp_path, monkeypatch):
    no_dt = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-1.0]]))
    with pytest.raises(InvalidSettingError, match="pass dt="):
        export_fmu(no_dt, tmp_path / "a.fmu")
    with pytest.raises(InvalidSettingError, match="nsub must be a whole number >= 1"):
        export_fmu(nonlinear, tmp_path / "a.fmu", nsub=0)
    with pytest.raises(InvalidSettingError, match="not a valid FMU model identifier"):
        export_fmu(linear, tmp_path / "a.fmu", name="2 servo")
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(BuildError, match="no C compiler found"):
        export_fmu(linear, tmp_path / "a.fmu")
    assert not list(tmp_path.iterdir())


# --------------------------------------------------------------------------------------------- dispatch
def test_export_by_suffix(with_constant, tmp_path):
    assert IdentifiedModel.load(export(with_constant, tmp_path / "m.json")).to_json() == with_constant.to_json()
    assert scipy.io.loadmat(export(with_constant, tmp_path / "m.mat", constant="ignore"))["B"].shape == (4, 2)
    with pytest.raises(InvalidSettingError, match=r"unknown suffix '\.csv'; use one of \.mat, \.fmu, \.json"):
        export(with_constant, tmp_path / "m.csv")
    with pytest.raises(InvalidSettingError, match="takes no options"):
        export(with_constant, tmp_path / "m.json", dt=DT)


@pytest.mark.parametrize("call", [
    lambda m, p: to_statespace(m, dtt=0.1),
    lambda m, p: export_mat(m, p / "m.mat", dtt=0.1),
    lambda m, p: export_fmu(m, p / "m.fmu", dtt=0.1),
    lambda m, p: export(m, p / "m.mat", dtt=0.1),
    lambda m, p: operating_point(m, nearr=None),
])
def test_unknown_keywords_are_rejected(call, linear, tmp_path):
    with pytest.raises(TypeError, match="dtt|nearr"):
        call(linear, tmp_path)
