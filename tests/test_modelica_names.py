"""Names as FMUs write them (``mass.s``, ``x[2]``, ``A[1,2]``, ``der(x)``, ``'my var'``) work wherever a signal
name is accepted: identification, diagnosis, comparison, export (StateSpace, .mat, FMU) and controllers.

The record comes from an independent simulator (scipy's ``solve_ivp``) of a mass on a spring and damper with
Coulomb friction, driven by a multisine force, written as a CSV whose columns are Modelica's names.
"""

from __future__ import annotations

import ast
import json

import numpy as np
import pandas as pd
import pytest
import scipy.io
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from cosim.cli import main as cli
from cosim.data import load_data
from cosim.data._names import (
    control_label,
    expression_names,
    is_name,
    label_name,
    parse_expression,
    real_name,
    safe_name,
    with_safe_names,
)
from cosim.errors import InvalidSettingError
from cosim.identify.model import IdentifiedModel
from cosim.identify.terms import Term

STATES = ("mass.s", "mass.v")
INPUT = "extForce"
#: The simulated mass: d s/dt = v, d v/dt = (-K s - C v - FC sign(v) + F) / M (sign smoothed at 1 mm/s).
K, C, FC, M = 4.0, 0.8, 0.5, 1.0
DT, DURATION = 0.01, 20.0


def run(*args: str) -> dict:
    """`cosim ARGS --json`, its JSON output."""
    result = CliRunner().invoke(cli, [*args, "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("modelica_names")


@pytest.fixture(scope="module")
def record(folder):
    """The mass's record as a CSV with columns t, mass.s, mass.v, extForce (0.01 % noise on the states)."""
    rng = np.random.default_rng(0)
    freqs = np.array([0.1, 0.23, 0.41, 0.7, 1.1, 1.7])
    phases = rng.uniform(0.0, 2.0 * np.pi, len(freqs))

    def force(t):
        return 2.0 * np.sum(np.sin(2.0 * np.pi * freqs * t + phases))

    def rhs(t, x):
        return [x[1], (-K * x[0] - C * x[1] - FC * np.tanh(x[1] / 1e-3) + force(t)) / M]

    t = np.arange(0.0, DURATION, DT)
    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=0.005, rtol=1e-8, atol=1e-10)
    noise = 1e-4 * rng.standard_normal((2, len(t)))
    frame = pd.DataFrame({"t": t, "mass.s": sol.y[0] + noise[0], "mass.v": sol.y[1] + noise[1],
                          INPUT: [force(v) for v in t]})
    path = folder / "data.csv"
    frame.to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def identified(record, folder):
    """``cosim identify data.csv --state mass.s,mass.v --input extForce -o model.json``: its JSON and file."""
    path = folder / "model.json"
    payload = run("identify", str(record), "--state", ",".join(STATES), "--input", INPUT, "-o", str(path))
    return payload, path


# ------------------------------------------------------------------------------------------- the mapping
@pytest.mark.parametrize("name", ["x[2]", "A[1,2]", "der(x)", "der(mass.s)", "'quoted name'", "mass.s",
                                  "a.b[1].'c d'", "der(x, 2)", "'it\\'s'", "$PRE.x", "\u03c9.m", "lambda", "_m_x"])
def test_a_name_maps_to_an_identifier_and_back(name):
    safe = safe_name(name)
    assert safe.isidentifier() and safe != name
    assert real_name(safe) == name
    assert is_name(name)
    assert expression_names(f"2*{name} + u") == (name, "u")
    tree = parse_expression(f"sin({name})*u")
    assert {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} == {"sin", name, "u"}


def test_plain_names_numbers_and_mat_indices_stay_as_they_are():
    assert safe_name("omega_m") == "omega_m" and real_name("omega_m") == "omega_m"
    assert with_safe_names("1.5e-3*x + .5 - data[:,2] + data[0]") == "1.5e-3*x + .5 - data[:,2] + data[0]"
    assert not is_name("data[:,2]") and not is_name("x[0]") and not is_name("2*x")


def test_python_control_labels_read_back():
    assert control_label("mass.s") == "mass:s" and label_name("mass:s") == "mass.s"
    assert control_label("mass.s", keep_dots=True) == "mass.s"
    with pytest.raises(InvalidSettingError, match="holds ':'"):
        control_label("a:b")


def test_a_term_over_fmu_names_parses_evaluates_and_writes_code():
    term = Term("sign(mass.v)*extForce")
    assert term.text == "sign(mass.v)*extForce" and str(term) == "sign(mass.v)*extForce"
    assert set(term.variables) == {"mass.v", "extForce"}
    values = {"mass.v": np.array([-2.0, 3.0]), "extForce": np.array([5.0, 7.0])}
    assert term.evaluate(values).tolist() == [-5.0, 7.0]
    assert term.to_c({"mass.v": "x[1]", "extForce": "u[0]"}) == "(cosim_sign(x[1]) * u[0])"
    assert np.asarray(Term("mass.v*extForce").derivative(values, "mass.v")).tolist() == [5.0, 7.0]
    odd = Term("der(x)**2 + A[1,2]/'my var' - tanh(der(mass.s)/0.01)")
    assert set(odd.variables) == {"der(x)", "A[1,2]", "'my var'", "der(mass.s)"}
    with pytest.raises(InvalidSettingError, match="not a valid expression"):
        Term("mass.v +* 2")


def test_a_model_over_fmu_names_simulates_and_prints_them():
    model = IdentifiedModel(states=("x[1]", "der(x[1])"), inputs=("'ext force'",),
                            terms=("der(x[1])", "x[1]", "'ext force'", "sign(der(x[1]))"),
                            coef=np.array([[1.0, 0.0, 0.0, 0.0], [0.0, -4.0, 1.0, -0.5]]), dt=DT)
    assert model.equations() == ["x[1]' = 1 der(x[1])", "der(x[1])' = -4 x[1] + 1 'ext force' - 0.5 sign(der(x[1]))"]
    result = model.simulate([0.0, 0.0], np.ones(100))
    assert result.status == "ok" and result.states[-1, 0] > 0.05
    assert IdentifiedModel.from_json(model.to_json()).terms == model.terms


# ------------------------------------------------------------------------------------------- data columns
def test_column_expressions_read_fmu_names_and_still_mat_indices(record, tmp_path):
    data = load_data(record, columns=["mass.s", "f=2*extForce", "der(mass.s)=mass.v*1"])
    assert data.names == ("mass.s", "f", "der(mass.s)")
    np.testing.assert_allclose(data["der(mass.s)"], pd.read_csv(record)["mass.v"])
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"t": np.arange(50) * DT, "data": np.random.default_rng(1).normal(size=(50, 3))})
    assert load_data(path, columns=["pos=data[:,2]"]).names == ("pos",)
    with pytest.raises(InvalidSettingError, match=r"'data\[0\]' is not allowed"):
        load_data(path, columns=["pos=data[0]"])


# ------------------------------------------------------------------------------------------- identify, diagnose
def test_identify_keeps_the_names(identified):
    payload, path = identified
    assert payload["states"] == list(STATES) and payload["inputs"] == [INPUT]
    assert payload["equations"][0] == "mass.s' = 1 mass.v"
    assert payload["equations"][1].startswith("mass.v' = ") and "extForce" in payload["equations"][1]
    assert payload["kinematics"][0] | {"gain": None, "r2": None} == {"position": "mass.s", "velocity": "mass.v",
                                                                    "found": "name", "gain": None, "r2": None}
    assert min(payload["fit"]["fit_pct"].values()) > 90.0
    compared = run("compare", str(path), str(path.with_name("data.csv")))
    assert set(compared["fit_pct"]) == set(STATES)


def test_user_terms_over_fmu_names_find_the_friction(record):
    from cosim import SINDYc

    data = load_data(record, columns=[*STATES, INPUT], roles={**dict.fromkeys(STATES, "state"), INPUT: "input"})
    model = SINDYc(terms=["sign(mass.v)", "mass.v*extForce"], refine=None).fit(
        data, states=list(STATES), inputs=[INPUT]).model_
    assert "sign(mass.v)" in model.terms
    friction = model.coef[1, model.terms.index("sign(mass.v)")]
    assert friction == pytest.approx(-FC / M, rel=0.15)


def test_diagnose_names_coulomb_friction_on_the_dotted_velocity(record):
    payload = run("diagnose", str(record), "--state", ",".join(STATES), "--input", INPUT)
    effect = payload["effects"][0]
    assert effect["name"] == "coulomb_friction" and effect["attached_to"] == "mass.v"
    assert effect["rows"] == ["mass.v"] and effect["terms"][0].startswith("tanh(mass.v/")
    assert payload["after"]["nrmse_pct"] < payload["before"]["nrmse_pct"] / 3


# ------------------------------------------------------------------------------------------- export
def test_statespace_and_mat_keep_the_names(identified, tmp_path):
    import control

    from cosim.export import export_mat, to_statespace

    model = IdentifiedModel.load(identified[1])
    sys = to_statespace(model)
    assert sys.state_labels == list(STATES) and sys.input_labels == [INPUT]
    assert sys.output_labels == ["mass:s", "mass:v"]  # python-control refuses '.' in an input or output name
    assert [label_name(y) for y in sys.output_labels] == list(STATES)
    assert control.c2d(sys, DT).output_labels == sys.output_labels
    saved = scipy.io.loadmat(export_mat(model, tmp_path / "model.mat"))
    assert [str(c[0][0]) for c in saved["StateName"]] == list(STATES)
    assert [str(c[0][0]) for c in saved["OutputName"]] == list(STATES)
    assert [str(c[0][0]) for c in saved["InputName"]] == [INPUT]


def test_the_exported_fmu_keeps_the_names_and_steps_like_the_model(tmp_path):
    import fmpy

    from cosim import simulate
    from cosim.export import export_fmu

    model = IdentifiedModel(states=("x[1]", "der(x[1])"), inputs=("'ext force'",),
                            terms=("der(x[1])", "x[1]", "'ext force'", "sign(der(x[1]))"),
                            coef=np.array([[1.0, 0.0, 0.0, 0.0], [0.0, -4.0, 1.0, -0.5]]), dt=DT)
    path = export_fmu(model, tmp_path / "odd names.fmu")
    description = fmpy.read_model_description(str(path), validate=True)
    names = [v.name for v in description.modelVariables]
    assert names == ["time", "'ext force'", "x[1]", "der(x[1])", "der(der(x[1]))", "nsub"]
    assert [d.variable.name for d in description.derivatives] == ["der(der(x[1]))"]
    force = np.sin(np.arange(300) * DT * 3.0) + 0.8
    traj = simulate(path, {"'ext force'": force}, duration=299 * DT, dt=DT)
    expected = model.simulate([0.0, 0.0], force[:299]).states
    np.testing.assert_allclose(np.c_[traj["x[1]"], traj["der(x[1])"]], expected, atol=1e-9)


def test_fmu_pid_and_validation_keep_the_names_end_to_end(identified, folder):
    import fmpy

    from controllers.base import load_controller
    from cosim import simulate

    _, model_path = identified
    fmu = folder / "mass.fmu"
    run("export", str(model_path), "-o", str(fmu))
    assert {"mass.s", "mass.v", "extForce", "der(mass.v)"} <= {v.name for v in
                                                             fmpy.read_model_description(str(fmu)).modelVariables}
    model = IdentifiedModel.load(model_path)
    force = pd.read_csv(model_path.with_name("data.csv"))[INPUT].to_numpy()[:500]
    traj = simulate(fmu, {INPUT: force}, duration=499 * DT, dt=DT, start={"mass.s": 0.01})
    expected = model.simulate([0.01, 0.0], force[:499]).states
    np.testing.assert_allclose(np.c_[traj["mass.s"], traj["mass.v"]], expected, atol=1e-9)
    pid_path = folder / "pid.json"
    design = run("design", "pid", str(model_path), "--tracked", "mass.s", "--u-max", "20", "-o", str(pid_path))
    assert design["inputs"] == [INPUT] and design["outputs"] == ["mass.s"] and design["tracked"] == ["mass.s"]
    pid = load_controller(pid_path)
    assert pid.design_model.outputs == STATES and pid.design_model.to_statespace().output_labels == ["mass:s",
                                                                                                     "mass:v"]
    verdict = run("validate", str(fmu), str(pid_path), "--scenario", "step:amp=0.1,duration=3",
                  "--spec", "settling_time<=2")
    assert verdict["passed"], verdict
