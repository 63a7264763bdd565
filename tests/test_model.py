"""IdentifiedModel and library terms: parsing, evaluation, simulation against known solutions, JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosim.errors import DataError, InvalidSettingError, UnknownVariableError
from cosim.identify.model import IdentifiedModel
from cosim.identify.terms import Term, compile_rhs, polynomial_terms

STATES = ("theta_m", "omega_m", "theta_L", "omega_L")
P = {"Jm": 250.0, "JL": 1000.0, "KL": 2.5e6, "Bm": 50.0, "BL": 500.0}


def two_mass(extra_terms=(), extra_coef=None) -> IdentifiedModel:
    jm, jl, kl, bm, bl = P["Jm"], P["JL"], P["KL"], P["Bm"], P["BL"]
    a = np.array([[0, 1, 0, 0], [-kl / jm, -(bm + bl) / jm, kl / jm, bl / jm], [0, 0, 0, 1],
                  [kl / jl, bl / jl, -kl / jl, -bl / jl]])
    b = np.array([[0, 0], [1 / jm, 0], [0, 0], [0, 1 / jl]])
    coef = np.hstack([a, b] + ([extra_coef] if extra_coef is not None else []))
    return IdentifiedModel(states=STATES, inputs=("Tm", "TL"), terms=STATES + ("Tm", "TL") + tuple(extra_terms),
                           coef=coef, dt=1 / 2257, units={"theta_m": "rad"}, meta={"note": "true plant"})


@pytest.mark.parametrize("text,values,expected", [
    ("1", {"x": np.array([1.0, 2.0])}, [1.0, 1.0]),
    ("x*u", {"x": np.array([2.0]), "u": np.array([3.0])}, [6.0]),
    ("x**2 - 2*u", {"x": np.array([3.0]), "u": np.array([1.0])}, [7.0]),
    ("tanh(x/0.5)", {"x": np.array([0.5])}, [np.tanh(1.0)]),
    ("sign(x)", {"x": np.array([-2.0, 0.0, 3.0])}, [-1.0, 0.0, 1.0]),
    ("-sin(x)", {"x": np.array([np.pi / 2])}, [-1.0]),
])
def test_terms_evaluate_to_known_values(text, values, expected):
    np.testing.assert_allclose(Term(text).evaluate(values), expected, rtol=1e-15)


@pytest.mark.parametrize("text", ["__import__('os')", "x.real()", "x[0]", "lambda: 1", "sin", "max(x, 1)",
                                  "x if x else 1", "", "x +"])
def test_terms_reject_anything_but_arithmetic(text):
    with pytest.raises(InvalidSettingError):
        Term(text)


def test_polynomial_terms_count():
    # constant + monomials of 3 variables up to degree 2: 1 + 3 + 6
    assert len(polynomial_terms(["a", "b", "c"], 2)) == 10
    assert polynomial_terms(["a"], 3, include_bias=False) == ["a", "a**2", "a**3"]


def test_compiled_rhs_equals_numpy_evaluation():
    terms = [Term(t) for t in ("1", "x", "u", "x*u", "tanh(x/0.1)", "x**3")]
    coef = np.array([[0.5, -1.0, 2.0, 0.0, 3.0, -0.25], [1.0, 0.0, 0.0, 4.0, 0.0, 0.0]])
    rhs = compile_rhs(("x", "y"), ("u",), terms, coef)
    x, y, u = 0.3, -1.2, 0.7
    theta = np.array([t.evaluate({"x": np.array([x]), "y": np.array([y]), "u": np.array([u])})[0] for t in terms])
    np.testing.assert_allclose(rhs([x, y], [u]), coef @ theta, rtol=1e-15)


def test_linear_structure_and_equations():
    model = two_mass()
    assert model.is_linear
    a, b, c = model.linear_matrices()
    assert a[1, 0] == pytest.approx(-1e4) and b[1, 0] == pytest.approx(1 / 250) and not c.any()
    assert model.equations()[0] == "theta_m' = 1 omega_m"


def test_nonlinear_model_refuses_linear_matrices():
    model = two_mass(["tanh(omega_m/0.001)"], np.array([[0.0], [-0.4], [0.0], [0.0]]))
    assert not model.is_linear
    with pytest.raises(InvalidSettingError, match="tanh"):
        model.linear_matrices()


def test_linear_simulation_matches_solve_ivp():
    model = two_mass()
    n, dt = 500, 1 / 2257
    u = np.column_stack([np.where(np.arange(n) < 250, 500.0, -500.0), np.zeros(n)])
    sim = model.simulate([-2.0, 0.0, 2.0, 1.0], u)
    a, b, _ = model.linear_matrices()
    x = np.array([-2.0, 0.0, 2.0, 1.0])
    for k in (0, 250):
        span = (k * dt, (k + 250) * dt)
        sol = solve_ivp(lambda t, s, k=k: a @ s + b @ u[k], span, x, method="DOP853", rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        np.testing.assert_allclose(sim.states[k + 250], x, rtol=1e-8, atol=1e-8 * np.abs(x).max())
    assert sim.ok and sim.time[-1] == pytest.approx(n * dt)


def test_rk4_simulation_of_a_nonlinear_model_converges_to_solve_ivp():
    model = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "sin(x)", "tanh(v/0.1)", "u"),
                            coef=[[1, 0, 0, 0, 0], [0, -1.0, -2.0, -0.5, 1.0]], dt=0.01)
    u = np.full((200, 1), 0.3)
    sim = model.simulate([1.0, 0.0], u, nsub=4)
    sol = solve_ivp(lambda t, s: model.rhs(s, [0.3]), (0, 2.0), [1.0, 0.0], method="DOP853", rtol=1e-12,
                    atol=1e-12)
    np.testing.assert_allclose(sim.states[-1], sol.y[:, -1], rtol=1e-9, atol=1e-10)


def test_unstable_model_stops_with_a_clear_status():
    model = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=[[50.0]], dt=0.01)
    sim = model.simulate([1.0], n_steps=1000)
    assert sim.status == "diverged" and "t=0.5" in sim.message
    assert np.isnan(sim.states[-1, 0]) and np.isfinite(sim.states[:50]).all()
    traj = sim.to_trajectory()
    assert len(traj) < 1001 and np.isfinite(traj["x"]).all()


def test_json_round_trip_and_bad_files(tmp_path):
    model = two_mass(["tanh(omega_m/0.001)"], np.array([[0.0], [-0.4], [0.0], [0.0]]))
    path = model.save(tmp_path / "model.json")
    again = IdentifiedModel.load(path)
    np.testing.assert_array_equal(again.coef, model.coef)
    assert again.terms == model.terms and again.meta == model.meta and again.dt == model.dt
    data = json.loads(path.read_text())
    assert data["version"] == 1 and data["format"] == "cosim-identified-model"
    data["version"] = 99
    with pytest.raises(DataError, match="newer"):
        IdentifiedModel.from_dict(data)
    with pytest.raises(DataError, match="not JSON"):
        IdentifiedModel.from_json("{")
    with pytest.raises(DataError, match="not a cosim model"):
        IdentifiedModel.from_dict({"format": "other"})


def test_construction_checks():
    with pytest.raises(UnknownVariableError, match="q"):
        IdentifiedModel(states=("x",), inputs=(), terms=("q",), coef=[[1.0]])
    with pytest.raises(InvalidSettingError, match="shape"):
        IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=[[1.0, 2.0]])
    with pytest.raises(InvalidSettingError, match="NaN"):
        IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=[[np.nan]])
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=[[-1.0, 1.0]], dt=0.1)
    with pytest.raises(InvalidSettingError, match="shape"):
        model.simulate([0.0], np.ones((10, 2)))
    with pytest.raises(DataError, match="NaN"):
        model.simulate([0.0], np.full((10, 1), np.nan))
