"""Issue 38, item 8: a command that fails writes nothing; `identify --derive` prints its fit; every message names
the command line's own flags and says what to add; a `.mat` export says whether it is continuous or discrete.

The records are an independent mass-spring simulated by scipy (tests/independent_records.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner
from independent_records import mass_spring

from cosim.cli import main


def run(*args, env=None):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False, env=env)


def one_error_line(result, *fragments: str) -> str:
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A position-only record and a linear and a nonlinear model of a full one."""
    here = tmp_path_factory.mktemp("outputs")
    mass_spring(here / "positions.csv", samples=2500, noise=0.002, seed=5, positions_only=True)
    mass_spring(here / "full.csv", samples=2500, noise=0.01, seed=6, coulomb=1.0)
    for name, extra in (("linear", []), ("nonlinear", ["--terms", "tanh(v/0.01)"])):
        result = run("identify", here / "full.csv", "--state", "x,v", "--input", "F", *extra, "-o",
                     here / f"{name}.json")
        assert result.exit_code == 0, result.stderr
    return here


def test_an_export_that_fails_on_its_second_file_writes_not_even_the_first(folder, tmp_path):
    one_error_line(run("export", folder / "linear.json", "-o", tmp_path / "ok.mat", "-o", tmp_path / "model.xyz"),
                   "-o/--output", "model.xyz", "unknown suffix '.xyz'", ".mat, .fmu, .json")
    # a failure after the .mat was made (the FMU's compiler is missing): still nothing in place
    result = run("export", folder / "linear.json", "-o", tmp_path / "ok.mat", "-o", tmp_path / "model.fmu",
                 env={"CC": "false"})  # a compiler that always fails
    assert result.exit_code == 2 and result.stderr.startswith("error: "), result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no file, no staging folder left behind
    one_error_line(run("export", folder / "linear.json", "-o", tmp_path / "a.mat", "-o", tmp_path / "a.mat"),
                   "given twice")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize(("command", "option", "name"), [
    ("identify", "-o", "model.txt"), ("diagnose", "--report", "report.pdf"), ("compare", "--plot", "fit.html")])
def test_a_wrong_output_suffix_is_refused_before_any_work(folder, tmp_path, command, option, name):
    data = folder / "full.csv"
    args = {"identify": [data, "--state", "x,v", "--input", "F"],
            "diagnose": [data, "--state", "x,v", "--input", "F"],
            "compare": [folder / "linear.json", data]}[command]
    one_error_line(run(command, *args, option, tmp_path / name), f"{name}: unknown suffix")
    assert list(tmp_path.iterdir()) == []


def test_identify_with_derive_prints_and_writes_its_fit_as_compare_scores_it(folder):
    data = folder / "positions.csv"
    result = run("identify", data, "--state", "x,x_dot", "--derive", "x", "--input", "F", "-o",
                 folder / "derived.json", "--json")
    assert result.exit_code == 0, result.stderr
    fit = json.loads(result.stdout)["fit"]
    assert set(fit["fit_pct"]) == {"x", "x_dot"} and min(fit["fit_pct"].values()) > 80.0
    text = run("identify", data, "--state", "x,x_dot", "--derive", "x", "--input", "F").stdout
    assert f"x {fit['fit_pct']['x']:.2f} %" in text and "free-run fit" in text
    scored = json.loads(run("compare", folder / "derived.json", data, "--derive", "x", "--json").stdout)
    assert scored["fit_pct"] == pytest.approx(fit["fit_pct"], rel=1e-9)
    # compare without --derive: the model's own derivation, said, the same figures
    again = run("compare", folder / "derived.json", data, "--json")
    assert again.exit_code == 0, again.stderr
    payload = json.loads(again.stdout)
    assert payload["fit_pct"] == pytest.approx(fit["fit_pct"], rel=1e-9)
    assert payload["notes"] == ["derived x_dot from x as when the model was identified (--derive x_dot=x)"]


def test_messages_name_the_flags_and_what_to_add(folder):
    one_error_line(run("identify", folder / "positions.csv", "--state", "x", "--derive", "x", "--input", "F"),
                   "--derive x adds the velocity x_dot", "--state x,x_dot")
    line = one_error_line(run("export", folder / "nonlinear.json", "-o", folder / "nl.mat"),
                          "--operating-point x=VALUE,v=VALUE,F=VALUE")
    assert "operating_point=" not in line  # the Python keyword is not the CLI's
    one_error_line(run("export", folder / "nonlinear.json", "-o", folder / "nl.mat", "--operating-point", "x=0"),
                   "no value for v, F", "add v=VALUE,F=VALUE")
    one_error_line(run("export", folder / "nonlinear.json", "-o", folder / "nl.mat", "--operating-point",
                       "x=0,v=0,F=0,q=1"), "--operating-point q: not a state or input", "x, v, F")
    one_error_line(run("export", folder / "linear.json", "-o", folder / "x.mat", "--dt", "0"),
                   "--dt must be a positive step")
    assert not (folder / "nl.mat").exists() and not (folder / "x.mat").exists()


def test_a_mat_export_is_continuous_unless_dt_is_given_linear_or_linearised(folder, tmp_path):
    for name, extra in (("linear", []), ("nonlinear", ["--operating-point", "x=0,v=0,F=0"])):
        for dt in (None, "0.002"):
            target = tmp_path / f"{name}-{dt}.mat"
            result = run("export", folder / f"{name}.json", "-o", target, *extra, *(["--dt", dt] if dt else []),
                         "--json")
            assert result.exit_code == 0, result.stderr
            [note] = json.loads(result.stdout)["notes"]
            mat = scipy.io.loadmat(target)
            assert mat["dt"].item() == (0.0 if dt is None else 0.002)
            assert ("continuous" in note) == (dt is None) and ("discrete at dt=0.002 s" in note) == (dt is not None)
            if dt is None:  # continuous: the mass-spring's own matrix, x' = v, v' = -k/m x - c/m v + F/m
                assert mat["A"][0].tolist() == [0.0, 1.0] and mat["A"][1, 0] == pytest.approx(-101.06, rel=0.05)
            else:
                assert np.all(np.abs(np.linalg.eigvals(mat["A"])) < 1.0)
