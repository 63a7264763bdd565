"""Gravity in place of the spring and constant it linearises to.

Over a swing of a radian a pendulum's ``-G sin x`` is nearly a spring to ground and a softening cubic; the
default ``cosim diagnose DATA`` identifies the linear part as a spring (and a constant). The gravity trial
also fits with those base terms removed, their force moved into the sine
(:func:`cosim.diagnose._trials._without_absorbed`), so that it is not charged for parameters the plant does
not have. Plant: a damped pendulum without a spring (m 0.1 kg, b 0.4 N s/m, G 0.4 N), driven by steps from
its own solve_ivp simulation, 2 % noise. Before this, a softening ``cubic_stiffness`` was named (a false
claim; record 32 of the generalisation benchmark is the same case): on seeds 5-9 of this plant, 3 of 5 named
gravity before and 5 of 5 after, amplitude within 0.3 %. Seed 6 is one the code before named the cubic on.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from cosim.cli import main

M, B, G = 0.1, 0.4, 0.4
DT, T = 3e-3, 12.0


def _csv(path, seed: int = 6, noise: float = 0.02) -> str:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, T + DT / 2, DT)
    edges = np.cumsum(rng.uniform(0.8, 2.0, 20))
    levels = rng.uniform(-0.95, 0.95, 21) * G  # each step settles at x = asin(level / G), up to 1.25 rad
    u = levels[np.searchsorted(edges, t)]

    def rhs(tt, s):
        k = min(int(tt / DT), len(t) - 1)  # the sampled input, held
        return [s[1], (u[k] - B * s[1] - G * np.sin(s[0])) / M]

    x, v = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=DT, rtol=1e-9, atol=1e-12).y
    assert 0.5 < np.max(np.abs(x)) < 2.0  # a swing where sin x is a spring plus a little
    x = x + rng.normal(scale=noise * np.ptp(x), size=x.size)
    v = v + rng.normal(scale=noise * np.ptp(v), size=v.size)
    np.savetxt(path, np.column_stack([t, x, v, u]), delimiter=",", header="t,x,v,u", comments="")
    return str(path)


@pytest.mark.slow
def test_gravity_is_named_not_a_softening_spring(tmp_path):
    result = CliRunner().invoke(main, ["diagnose", _csv(tmp_path / "pendulum.csv"), "--state", "x,v",
                                       "--input", "u", "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert [(e["name"], e["attached_to"]) for e in payload["effects"]] == [("gravity", "x")], payload["message"]
    found = payload["effects"][0]["parameters"]
    # in the input's units (the input enters as u / m): G itself; the sine's phase puts the rest at x = 0
    assert found["amplitude_v"] == pytest.approx(G, rel=0.10)
    assert abs(abs(found["phase_v"]) - np.pi) < 0.1
    # the spring and the constant went into the sine: the model after has neither in v's equation
    v_eq = next(e for e in payload["equations_after"] if e.startswith("v'"))
    terms = re.split(r" [+-] ", v_eq.split("=", 1)[1].strip())
    assert all(re.search(r"(\bv\b|\bu\b|sin\(x\)|cos\(x\))", term) for term in terms), v_eq
