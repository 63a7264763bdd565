"""Issue 38, item 7: Python and the command line give the same answer on their defaults, and the README's spellings
work: SINDYc refines by output error as `cosim identify` does, `IdentifiedModel.to_statespace()` exists, and
``amp=`` means one thing (in the signal's units), a fraction only under ``frac=``."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from independent_records import mass_spring

import cosim
from cosim import SINDYc, signals
from cosim.cli import main
from cosim.data.trajectory import Trajectory
from cosim.errors import CosimDeprecationWarning
from cosim.identify.model import IdentifiedModel
from cosim.loop.validation import parse_scenario


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """A noisy record of an independent mass-spring (scipy), identified by the CLI and by SINDYc() alike."""
    folder = tmp_path_factory.mktemp("defaults")
    data = mass_spring(folder / "data.csv", samples=2500, noise=0.05, seed=3)
    result = run("identify", data, "--state", "x,v", "--input", "F", "-o", folder / "model.json", "--json")
    assert result.exit_code == 0, result.stderr
    frame = pd.read_csv(data)
    traj = Trajectory.from_arrays(frame["t"], {n: frame[n] for n in ("x", "v", "F")},
                                  roles={"x": "state", "v": "state", "F": "input"})
    return {"cli": json.loads(result.stdout), "path": folder / "model.json", "python": SINDYc().fit(traj)}


def test_sindyc_refines_by_output_error_by_default_as_the_cli_does(identified):
    est = identified["python"]
    assert est.get_params()["refine"] == "output_error"
    assert est.model_.meta["settings"]["refine"] == "output_error"
    cli_model = IdentifiedModel.load(identified["path"])
    assert cli_model.terms == est.model_.terms
    np.testing.assert_allclose(est.model_.coef, cli_model.coef, rtol=1e-9, atol=1e-12)
    # the same fit figures: identify's JSON is cosim.compare on the same data
    scores = cosim.compare(est.model_, est_data(identified))
    assert scores.fit_pct == pytest.approx(identified["cli"]["fit"]["fit_pct"], rel=1e-9)
    assert min(scores.fit_pct.values()) > 90.0


def est_data(identified) -> Trajectory:
    frame = pd.read_csv(identified["path"].parent / "data.csv")
    return Trajectory.from_arrays(frame["t"], {n: frame[n] for n in ("x", "v", "F")},
                                  roles={"x": "state", "v": "state", "F": "input"})


def test_a_loaded_model_exports_itself_to_a_statespace_as_the_readme_says(identified):
    model = IdentifiedModel.load(identified["path"])
    own, room = model.to_statespace(), cosim.to_statespace(model)
    for name in "ABCD":
        np.testing.assert_array_equal(getattr(own, name), getattr(room, name))
    assert own.input_labels == room.input_labels and own.state_labels == ["x", "v"]
    assert model.to_statespace(dt=0.002).dt == 0.002


def test_amp_is_in_the_inputs_unit_and_frac_a_fraction_of_its_maximum(tmp_path):
    """The bundled servo's Tm declares a maximum of 5000 N m: amp=500 and frac=0.1 drive the same 500 N m square
    as signals.square(500, 2) from Python; an old amp=0.1 still does, with a one-line deprecation warning."""
    common = ["--duration", "0.2", "--dt", "1/1000", "--json"]
    columns = {}
    for label, spec in (("amp", "square:amp=500,freq=2"), ("frac", "square:frac=0.1,freq=2"),
                        ("old", "square:amp=0.1,freq=2")):
        result = run("simulate", "bundled", "--input", f"Tm={spec}", "-o", tmp_path / f"{label}.csv", *common)
        assert result.exit_code == 0, result.stderr
        columns[label] = pd.read_csv(tmp_path / f"{label}.csv")["Tm"].to_numpy()
        warned = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
        assert len(warned) == (label == "old"), result.stderr
    assert "write frac=0.1" in warned[0] and "(500 in its unit)" in warned[0]
    python = cosim.simulate(cosim.build_fmu(), {"Tm": signals.square(500.0, 2.0)}, duration=0.2, dt=1e-3)["Tm"]
    for label in columns:
        np.testing.assert_array_equal(columns[label], python)
    assert np.abs(python).max() == 500.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", CosimDeprecationWarning)
        # the validation scenario's amp was always absolute, and stays so
        assert parse_scenario("step:amp=0.01").amplitude == 0.01
