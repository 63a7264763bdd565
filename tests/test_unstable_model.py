"""An unstable identified model is an error by default (UnstableModelError), a warning with allow_unstable=True;
`cosim identify` exits 1 without writing the model unless --allow-unstable."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from cosim.cli import main
from cosim.data.trajectory import Trajectory
from cosim.errors import CosimError, IdentificationWarning, UnstableModelError
from cosim.identify.sindyc import SINDYc


def unstable_record() -> Trajectory:
    """x' = 0.8 x + u (an unstable first-order plant) under a square wave, solved by solve_ivp."""
    dt = 0.01
    t = np.arange(400) * dt

    def u(tt):
        return np.sign(np.sin(5.0 * tt))

    sol = solve_ivp(lambda tt, s: [0.8 * s[0] + u(tt)], (0, t[-1]), [0.1], t_eval=t, rtol=1e-10, atol=1e-12,
                    max_step=dt / 4)
    return Trajectory.from_arrays(t, {"x": sol.y[0], "u": u(t)}, roles={"x": "state", "u": "input"})


def stable_record() -> Trajectory:
    """A mass on a spring with damping, x'' = -4 x - 0.4 x' + 2 u, under a square wave."""
    dt = 0.005
    t = np.arange(4000) * dt

    def u(tt):
        return np.sign(np.sin(0.8 * tt))

    sol = solve_ivp(lambda tt, s: [s[1], -4 * s[0] - 0.4 * s[1] + 2 * u(tt)], (0, t[-1]), [1.0, 0.0], t_eval=t,
                    rtol=1e-10, atol=1e-12, max_step=dt / 4)
    return Trajectory.from_arrays(t, {"x": sol.y[0], "x_dot": sol.y[1], "u": u(t)},
                                  roles={"x": "state", "x_dot": "state", "u": "input"})


@pytest.mark.parametrize("refine", [None, "output_error"])
def test_unstable_model_raises_with_eigenvalues_and_what_to_try(refine):
    with pytest.raises(UnstableModelError) as info:
        SINDYc(refine=refine).fit(unstable_record())
    err = info.value
    assert isinstance(err, CosimError) and isinstance(err, ValueError)
    message = str(err)
    assert "\n" not in message and "largest real parts 0.79" in message  # 0.8 up to the held-input reading
    assert "allow_unstable=True" in message and "kinematics" in message
    # refinement is suggested only where it was off (the default has it on, as the CLI)
    assert ("refine='output_error'" in message) == (refine is None)
    assert err.eigenvalues[0].real == pytest.approx(0.8, rel=1e-2)
    assert err.model is not None and err.model.meta["stable"] is False


def test_allow_unstable_warns_and_keeps_the_model():
    with pytest.warns(IdentificationWarning, match="unstable"):
        est = SINDYc(allow_unstable=True).fit(unstable_record())
    assert est.model_.meta["stable"] is False
    assert est.model_.meta["eigenvalues"][0][0] == pytest.approx(0.8, rel=1e-2)


def test_stable_model_fits_without_warning(recwarn):
    est = SINDYc().fit(stable_record())
    assert est.model_.meta["stable"] is True
    assert est.equations()[0] == "x' = 1 x_dot"  # the kinematic row, found by the names, exact
    row = dict(zip(est.terms_, est.coef_[1], strict=True))
    assert [row["x"], row["x_dot"], row["u"]] == pytest.approx([-4.0, -0.4, 2.0], rel=1e-2)
    assert not [w for w in recwarn if issubclass(w.category, IdentificationWarning)]


def test_cli_exits_1_without_writing_unless_allowed(tmp_path):
    data = tmp_path / "unstable.csv"
    unstable_record().write(data)
    model = tmp_path / "model.json"
    runner = CliRunner()
    result = runner.invoke(main, ["identify", str(data), "--state", "x", "--input", "u", "--no-refine",
                                  "-o", str(model)])
    assert result.exit_code == 1, result.output
    assert "error: the identified model is unstable" in result.output and "--allow-unstable" in result.output
    assert "Traceback" not in result.output and not model.exists()
    result = runner.invoke(main, ["identify", str(data), "--state", "x", "--input", "u", "--no-refine",
                                  "--allow-unstable", "-o", str(model), "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.output.strip().splitlines()[-1])
    assert model.exists() and payload["stable"] is False and "unstable" in payload["warnings"][0]


def test_cli_prints_the_kinematics(tmp_path):
    data = tmp_path / "spring.csv"
    stable_record().write(data)
    runner = CliRunner()
    result = runner.invoke(main, ["identify", str(data), "--state", "x,x_dot", "--input", "u", "--no-refine"])
    assert result.exit_code == 0, result.output
    assert "kinematics: x' = x_dot (names)" in result.output
    result = runner.invoke(main, ["identify", str(data), "--state", "x,x_dot", "--input", "u", "--no-refine",
                                  "--kinematics", "none", "--json"])
    assert json.loads(result.output)["kinematics"] == []
    result = runner.invoke(main, ["identify", str(data), "--state", "x,x_dot", "--input", "u", "--no-refine",
                                  "--kinematics", "x=x_dot", "--json"])
    assert [p["found"] for p in json.loads(result.output)["kinematics"]] == ["given"]
