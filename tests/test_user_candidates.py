"""Effects a user brings (issue 39, item 4): ``candidate("orifice: -a*sqrt(abs(h1))")`` and ``--candidate``.

The split into features and parameter factors, every bad input in one line (API and CLI: exit 2, no traceback,
no file written), the parameter right when the feature is refitted by hand, and the search on a two-tank record
of an independent simulator (:mod:`tank_records`, scipy).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from tank_records import A1, DT, a1, columns, linear_base, truth_model, two_tanks

from cosim.cli import main
from cosim.diagnose import Effect, candidate
from cosim.diagnose.diagnosis import diagnose
from cosim.diagnose.effects import Attachment, Roles
from cosim.diagnose.screening import output_error_fit
from cosim.errors import InvalidSettingError, UnknownVariableError

SIGNALS = ["h1", "h2", "u"]
ORIFICE = "orifice: -a*sqrt(abs(h1))"


@pytest.mark.parametrize(("spec", "features", "names", "factors"), [
    (ORIFICE, ("sqrt(abs(h1))",), ("a",), (-1.0,)),
    ("leak: -a*sqrt(abs(h1)) + b*h1", ("sqrt(abs(h1))", "h1"), ("a", "b"), (-1.0, 1.0)),
    ("x: 2*a*h1/3 - c*sqrt(abs(h2))/4", ("h1", "sqrt(abs(h2))"), ("a", "c"), (2 / 3, -0.25)),
    ("spring: k*(h1 - h2)", ("h1 - h2",), ("k",), (1.0,)),
    ("twice: a*h1 - 2*a*h2", ("h1 - 2.0*(h2)",), ("a",), (1.0,)),
    ("push: -(f*tanh(h1/0.01))", ("tanh(h1 / 0.01)",), ("f",), (-1.0,)),
])
def test_an_expression_splits_into_features_and_parameter_factors(spec, features, names, factors):
    effect = candidate(spec, signals=SIGNALS)
    assert isinstance(effect, Effect) and effect.nuisance is None
    assert (effect.features, effect.parameter_names) == (features, names)
    assert effect.factors == pytest.approx(factors)
    assert effect.terms(Attachment("h1", ("h1",), ("h1",)), None) == features
    if spec.startswith(("x:", "twice:")):  # a*h1: without the signals either name could be the parameter
        with pytest.raises(InvalidSettingError, match="could each be the parameter"):
            candidate(spec)
        assert candidate(spec, parameters=names).features == features
    else:  # without the signals: the parameters are the names that only ever multiply a summand
        assert candidate(spec).features == features


def test_a_callable_is_recorded_on_symbols_and_read_as_text():
    effect = candidate("orifice", lambda h1, a: -a * np.sqrt(np.abs(h1)))
    assert (effect.features, effect.parameter_names, effect.factors) == (("sqrt(abs(h1))",), ("a",), (-1.0,))
    both = candidate("two", lambda h1, h2, a, b: -a * np.sqrt(abs(h1)) + b * np.tanh(h2 / 0.1), signals=SIGNALS)
    assert both.features == ("sqrt(abs(h1))", "tanh(h2 / 0.1)")
    assert candidate("text", lambda: "-a*sqrt(abs(h1))").features == ("sqrt(abs(h1))",)


def test_parameters_are_the_coefficient_over_the_factor_and_through_the_input():
    effect = candidate(ORIFICE)
    model = truth_model(scale=1.0)
    roles = Roles.of(model)
    place = effect.attachments(roles)[0]
    assert (place.label, place.rows) == ("h1", ("h1", "h2"))
    one = effect.parameters({"h1": np.array([-0.6])}, None, roles, Attachment("h1", ("h1",), ("h1",)))
    assert one == pytest.approx({"a": 0.6, "a_input": 0.6 * A1})
    both = effect.parameters({"h1": np.array([-0.6]), "h2": np.array([0.75])}, None, roles, place)
    assert both["a"] == pytest.approx(0.6) and both["a_h2"] == pytest.approx(-0.75)


BAD = [
    ("orifice -a*sqrt(abs(h1))", InvalidSettingError, "write NAME: EXPRESSION"),
    ("orifice: -a*sqrt(abs(h1)", InvalidSettingError, "is not an expression"),
    ("orifice: -a*arcsin(h1)", InvalidSettingError, "arcsin() is not a term function"),
    ("orifice: -a*sqrt(abs(h3))", UnknownVariableError, "'h3' is not a signal; signals are h1, h2, u"),
    ("orifice: -sqrt(abs(h1))", InvalidSettingError, "no parameter"),
    ("orifice: a**2*h1", InvalidSettingError, "not linear in 'a'"),
    ("orifice: sqrt(a*h1)", InvalidSettingError, "not linear in 'a'"),
    ("orifice: a*b*h1", InvalidSettingError, "not linear"),
    ("orifice: a*h1 + h2", InvalidSettingError, "has no parameter"),
    ("orifice: a*h1 + b*h1", InvalidSettingError, "multiply the same feature"),
    ("coulomb_friction: -a*sqrt(abs(h1))", InvalidSettingError, "is a catalogue effect's name"),
    ("overflow: -a*sqrt(abs(h1))", InvalidSettingError, "is a catalogue effect's name"),
]


@pytest.mark.parametrize(("spec", "error", "words"), BAD)
def test_bad_input_is_refused_in_one_line(spec, error, words):
    with pytest.raises(error) as info:
        candidate(spec, signals=SIGNALS)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_a_bad_callable_is_refused_in_one_line():
    for func, words in [(lambda h1, a: a * np.arcsin(h1), "arcsin"), (lambda h1, a: a * max(h1, 0.0), "branch"),
                        (lambda h1, a: 3.0, "not an expression")]:
        with pytest.raises(InvalidSettingError, match=words):
            candidate("bad", func)


def test_an_unknown_signal_is_refused_when_the_model_lacks_it():
    with pytest.raises(UnknownVariableError, match="'h3' is not a signal of the model; signals are h1, h2, u"):
        diagnose(truth_model(), two_tanks(n=400), candidates=[candidate("orifice: -a*sqrt(abs(h3))")])


@pytest.mark.parametrize(("spec", "words"), [(s, w) for s, _, w in BAD[:5]])
def test_the_cli_refuses_a_bad_candidate_before_anything_runs(tmp_path, spec, words):
    out = tmp_path / "model.json"
    result = CliRunner().invoke(main, ["diagnose", str(tmp_path / "missing.csv"), "--state", "h1,h2", "--input", "u",
                                       "--candidate", spec, "-o", str(out)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: candidate") and words in lines[0], result.stderr
    assert "Traceback" not in result.output and not out.exists()


# ---------------------------------------------------------------------------------------------- on a record
def test_the_orifice_refitted_by_hand_gives_its_coefficient():
    data = two_tanks()
    effect = candidate(ORIFICE)
    fit = output_error_fit(truth_model(), columns(data), DT)[0]
    k = fit.terms.index(effect.features[0])
    found = effect.parameters({"h1": fit.coef[0, [k]]}, None, Roles.of(fit), Attachment("h1", ("h1",), ("h1",)))
    assert found["a"] == pytest.approx(a1 / A1, rel=0.05)
    assert found["a_input"] == pytest.approx(a1, rel=0.05)


def test_the_search_names_the_users_orifice_beside_the_offset():
    data = two_tanks()
    report = diagnose(linear_base(data), data, effects="offset", candidates=[candidate(ORIFICE)])
    first = report.effects[0] if report.effects else None
    assert first is not None and (first.name, first.attached_to, first.rows) == ("orifice", "h1", ("h1",)), \
        report.message
    assert first.parameters["a"] == pytest.approx(a1 / A1, rel=0.05)
    assert first.terms == ("sqrt(abs(h1))",)


def test_the_default_search_names_the_users_orifice():
    """With every catalogued effect beside it: the catalogue's sqrt_outflow on h1 is the orifice's feature term for
    term, one reading, so it is named as the user named it, and not reported as a pair the data cannot tell apart
    (they were: "sqrt_outflow on h1 or orifice on h1 ... BIC 0 apart", with an experiment to separate them)."""
    data = two_tanks()
    report = diagnose(linear_base(data), data, candidates=[candidate(ORIFICE)])
    assert report.effects and report.effects[0].name == "orifice", report.message
    assert report.effects[0].parameters["a"] == pytest.approx(a1 / A1, rel=0.05)
    assert not report.ambiguous and "cannot tell" not in report.message, report.message


def test_the_cli_candidate_is_searched_and_reported(tmp_path):
    data = two_tanks()
    path = tmp_path / "tanks.csv"
    np.savetxt(path, np.column_stack([data.time, data["h1"], data["h2"], data["u"]]), delimiter=",",
               header="time,h1,h2,u", comments="")
    result = CliRunner().invoke(main, ["diagnose", str(path), "--state", "h1,h2", "--input", "u", "--effects",
                                       "offset", "--candidate", ORIFICE, "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    first = payload["effects"][0]
    assert (first["name"], first["attached_to"]) == ("orifice", "h1"), payload["message"]
    assert first["parameters"]["a"] == pytest.approx(a1 / A1, rel=0.05)


def test_a_diagnosis_brings_its_candidates_for_its_own_thread_only():
    """Two diagnoses in threads of one process (Dask's threaded scheduler): each sees its own candidates in the
    catalogue, not the other's, and one finishing does not take a shared candidate from the other. (They were put
    in the process-wide catalogue for a diagnosis' duration: the second to bring the orifice left it out of its
    own selection, since it was there already.)"""
    import threading

    from cosim.diagnose.candidates import registered
    from cosim.diagnose.effects import EFFECTS

    orifice, leak = candidate(ORIFICE), candidate("leak: -b*h2", signals=SIGNALS)
    inside, b_done = threading.Barrier(2), threading.Event()
    seen: dict[str, object] = {}

    def first():  # holds the orifice while the other thread comes and goes
        with registered([orifice], "offset"):
            inside.wait(timeout=30)
            b_done.wait(timeout=30)
            seen["a after b"] = EFFECTS.get("orifice")

    def second():  # brings the same orifice and a leak of its own
        with registered([orifice, leak], "offset") as names:
            inside.wait(timeout=30)
            seen["b"] = (names, EFFECTS.get("orifice"), EFFECTS.get("leak"))
        seen["b after"] = ("orifice" in EFFECTS, "leak" in EFFECTS)
        b_done.set()

    errors: list[BaseException] = []

    def caught(work):
        try:
            work()
        except BaseException as error:  # (a thread's failure would otherwise show only as a missing key)
            errors.append(error)
            inside.abort()
            b_done.set()

    threads = [threading.Thread(target=caught, args=(work,)) for work in (first, second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not errors, errors
    assert seen["b"] == (["offset", "orifice", "leak"], orifice, leak)
    assert seen["b after"] == (False, False)
    assert seen["a after b"] is orifice  # still there for the first diagnosis
    assert "orifice" not in EFFECTS and "leak" not in EFFECTS  # and in neither once both are over
