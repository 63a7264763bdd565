"""`diagnose`'s initial state (estimated, or held at the measured first sample) and per-state noise levels.

The mass-spring-damper of ``diagnose_fixtures`` with a Coulomb friction the model lacks, measured with noise.
Holding the initial state must keep it exactly at the first sample through every fit; a given noise level must
be the residual's scale; bad settings get one line that says what to do, from the API and the CLI.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from diagnose_fixtures import DT, MODEL, assert_one_line_error, record, write_csv

from cosim.cli import main
from cosim.data.trajectory import Trajectory
from cosim.diagnose.diagnosis import diagnose
from cosim.diagnose.screening import OutputErrorScreen, noise_level
from cosim.errors import InvalidSettingError

FC = 0.6


def friction_record(n: int = 3000, noise: float = 0.0, seed: int = 0) -> dict[str, np.ndarray]:
    """The model's plant plus Coulomb friction FC*sign(v); white noise on x and v."""
    clean = record(n, coulomb=FC)
    rng = np.random.default_rng(seed)
    return {**clean, **{k: clean[k] + noise * np.std(clean[k]) * rng.standard_normal(n) for k in ("x", "v")}}


def trajectory(columns: dict[str, np.ndarray]) -> Trajectory:
    return Trajectory.from_arrays(columns["t"], {k: columns[k] for k in ("x", "v", "u")},
                                  roles={"x": "state", "v": "state", "u": "input"})


@pytest.fixture(scope="module")
def noisy():
    return trajectory(friction_record(noise=0.02))


def test_measured_initial_state_is_held_through_every_fit(noisy):
    first = [noisy["x"][0], noisy["v"][0]]
    held = diagnose(MODEL, noisy, effects="coulomb_friction,offset", x0="measured")
    estimated = diagnose(MODEL, noisy, effects="coulomb_friction,offset")
    assert [e.name for e in held.effects] == ["coulomb_friction"] == [e.name for e in estimated.effects]
    assert held.model_after.meta["x0"][0] == first  # exactly the first sample, after every refit
    assert held.steps[-1][1].meta["x0"][0] == first
    # estimated, it moves off the noisy first sample (by about the noise: 2 % of the spread)
    spread = np.ptp(noisy["x"])
    assert 1e-5 * spread < abs(estimated.model_after.meta["x0"][0][0] - first[0]) < 0.1 * spread
    # both find the friction within 10 %
    for report in (held, estimated):
        assert report.effects[0].parameters["Fc"] == pytest.approx(FC, rel=0.10)


def test_given_initial_state_is_used(noisy):
    report = diagnose(MODEL, noisy, effects="offset", x0=[0.0, 0.0])
    assert report.model_after.meta["x0"][0] == [0.0, 0.0]


def test_noise_level_is_the_residual_scale_and_the_initial_state_drops_from_the_base(noisy):
    columns = {k: noisy[k] for k in ("x", "v", "u")}
    free = OutputErrorScreen(MODEL, columns, DT)
    given = OutputErrorScreen(MODEL, columns, DT, noise={"x": 1e-3}, estimate_x0=False)
    assert given.sigma[0] == 1e-3 and given.sigma[1] == pytest.approx(noise_level(noisy["v"]))
    assert free.sigma[0] == pytest.approx(noise_level(noisy["x"]))
    assert free.base.shape[1] == given.base.shape[1] + 2  # the two initial states are no longer estimated
    np.testing.assert_allclose(given.residual.reshape(-1, 2)[:, 0] * 1e-3, noisy["x"] - given.x_sim[:, 0])


@pytest.mark.parametrize(("kwargs", "fragment"), [
    ({"x0": "first"}, 'x0 must be "estimate", "measured" or 2 values, got \'first\''),
    ({"x0": [1.0]}, r"x0 must hold 2 finite values \(x, v\), got \[1.0\]"),
    ({"noise": {"y": 1e-3}}, r"noise names 'y', which is not a state of the model; states are \['x', 'v'\]"),
    ({"noise": {"x": -1.0}}, "the noise level of 'x' must be positive, got -1.0"),
])
def test_bad_settings_say_what_is_wrong(noisy, kwargs, fragment):
    with pytest.raises(InvalidSettingError, match=fragment):
        diagnose(MODEL, noisy, effects="offset", **kwargs)


@pytest.fixture()
def csv(tmp_path):
    return write_csv(tmp_path / "friction.csv", friction_record(noise=0.02)), MODEL.save(tmp_path / "model.json")


def cli(*args):
    return CliRunner().invoke(main, ["diagnose", *map(str, args)], catch_exceptions=False)


def test_cli_measured_initial_state_and_noise(csv):
    data, model = csv
    result = cli(data, "--state", "x,v", "--input", "u", "--model", model, "--effects", "coulomb_friction",
                 "--x0", "measured", "--noise", "x=1e-3,v=2e-3", "--json")
    assert result.exit_code == 0, result.stderr
    payload = json.loads(result.stdout)
    assert payload["effects"][0]["name"] == "coulomb_friction"
    assert payload["effects"][0]["parameters"]["Fc"] == pytest.approx(FC, rel=0.10)


@pytest.mark.parametrize(("args", "fragment"), [
    (["--noise", "x=fast"], "--noise x"),
    (["--noise", "y=1e-3"], "noise names 'y', which is not a state of the model"),
    (["--noise", "x=0"], "the noise level of 'x' must be positive"),
])
def test_cli_bad_noise_is_one_line(csv, args, fragment):
    data, model = csv
    assert_one_line_error(cli(data, "--state", "x,v", "--input", "u", "--model", model, *args), fragment)
