"""Several records in one diagnosis, effects judged on held-out data, and the diagnose command's bad input.

The plant is simulated here with scipy's solve_ivp and its own equations (not cosim's model code): a mass
``m v' = u - b v - a |v|`` whose friction differs between the two directions of motion (``a`` is cosim's
``viscous_asymmetry``). One record moving each way only cannot show it (``|v|`` is ``v`` or ``-v`` there, a
viscous term the linear model already has); the two records together do.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from cosim.cli import main

M, B, A = 2.0, 3.0, 1.5
DT, T = 2e-3, 10.0


def _record(sign: float, seed: int, noise: float = 0.01) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, T + DT / 2, DT)
    freqs, phases = rng.uniform(0.3, 2.5, 3), rng.uniform(0, 2 * np.pi, 3)
    u = sign * (6.0 + sum(1.5 * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True)))

    def rhs(tt, s):
        k = min(int(tt / DT), len(t) - 1)  # the sampled input, held
        return [s[1], (u[k] - B * s[1] - A * abs(s[1])) / M]

    x, v = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=DT, rtol=1e-9, atol=1e-12).y
    return {"t": t, "x": x + rng.normal(scale=noise * np.ptp(x), size=x.size),
            "v": v + rng.normal(scale=noise * np.ptp(v), size=v.size), "u": u}


def _csv(path, columns: dict[str, np.ndarray]):
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=",", header=",".join(columns), comments="")
    return str(path)


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("records")
    return {"forward": _csv(folder / "forward.csv", _record(+1.0, 1)),
            "backward": _csv(folder / "backward.csv", _record(-1.0, 2))}


def _diagnose(*args: str) -> dict:
    result = CliRunner().invoke(main, ["diagnose", *args, "--state", "x,v", "--input", "u", "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_two_records_together_name_the_asymmetry(records):
    found = _diagnose(records["forward"], records["backward"])
    assert [e["name"] for e in found["effects"]][:1] == ["viscous_asymmetry"], found["message"]
    effect = found["effects"][0]
    assert effect["parameters"]["viscous_asymmetry"] == pytest.approx(A, rel=0.05)
    assert 0 < effect["uncertainty"]["viscous_asymmetry"] < 0.05 * A
    assert found["after"]["nrmse_pct"] < 0.5 * found["before"]["nrmse_pct"]
    assert len(found["after"]["per_record"]) == 2
    # held out: it lowered the error on the halves it was not fitted to
    assert effect["explained"]["held_out_passed"] and effect["explained"]["held_out_t"] > 2


@pytest.mark.parametrize("which", ["forward", "backward"])
def test_either_record_alone_claims_no_asymmetry(records, which):
    found = _diagnose(records[which])
    assert "viscous_asymmetry" not in [e["name"] for e in found["effects"]], found["message"]


def _one_line_error(args: list[str], fragment: str, written) -> None:
    result = CliRunner().invoke(main, ["diagnose", *args, "-o", str(written)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and fragment in lines[0], result.stderr
    assert "Traceback" not in result.output
    assert not written.exists()


def test_bad_input_is_one_line_exit_2_nothing_written(records, tmp_path):
    columns = _record(+1.0, 3)
    positions_only = _csv(tmp_path / "positions.csv", {k: columns[k] for k in ("t", "x", "u")})
    short = _csv(tmp_path / "short.csv", {k: columns[k][:260] for k in ("t", "x", "u")})
    out = tmp_path / "model.json"
    # records with different signals
    _one_line_error([records["forward"], positions_only, "--state", "x,v", "--input", "u"], "'v'", out)
    # a record too short for the derivative window
    _one_line_error([short, "--state", "x,x_dot", "--derive", "x", "--derive-window", "301", "--input", "u"],
                    "window", out)
    # a velocity name that is no state
    _one_line_error([records["forward"], "--state", "x,v", "--input", "u", "--kinematics", "x=w"],
                    "'w' is not a state", out)
    # an effect frequency outside the record's band
    _one_line_error([records["forward"], "--state", "x,v", "--input", "u", "--effects", "cogging:periods=50000"],
                    "outside what these data can show", out)
