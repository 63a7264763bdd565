"""The base model's constant judged as an effect: ``offset`` named on the default path when the plant has one.

The default ``cosim diagnose DATA`` identifies a linear model with a constant in its equations (without it a
spring to ground stands in for an offset). Once the rounds are over the constant is tested as a candidate is
(:func:`cosim.diagnose._trials._base_offset`). Plant: a mass on a spring (m 0.5 kg, b 2 N s/m, k 80 N/m) driven
by a multisine, from its own solve_ivp simulation, 1 % noise; with a constant force of 0.8 N, and without.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from cosim.cli import main

M, B, K, F0 = 0.5, 2.0, 80.0, 0.8
DT, T = 2e-3, 8.0


def _csv(path, offset: float, seed: int = 3, noise: float = 0.01) -> str:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, T + DT / 2, DT)
    freqs, phases = np.linspace(0.3, 6.0, 8), rng.uniform(0, 2 * np.pi, 8)
    u = sum(2.0 * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True))

    def rhs(tt, s):
        k = min(int(tt / DT), len(t) - 1)  # the sampled input, held
        return [s[1], (u[k] + offset - B * s[1] - K * s[0]) / M]

    x, v = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=DT, rtol=1e-9, atol=1e-12).y
    x = x + rng.normal(scale=noise * np.ptp(x), size=x.size)
    v = v + rng.normal(scale=noise * np.ptp(v), size=v.size)
    np.savetxt(path, np.column_stack([t, x, v, u]), delimiter=",", header="t,x,v,u", comments="")
    return str(path)


def _diagnose(path: str) -> dict:
    result = CliRunner().invoke(main, ["diagnose", path, "--state", "x,v", "--input", "u", "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


@pytest.mark.slow
def test_a_constant_force_is_named_offset_with_its_size(tmp_path):
    payload = _diagnose(_csv(tmp_path / "offset.csv", F0))
    assert [(e["name"], e["attached_to"]) for e in payload["effects"]] == [("offset", "constant")], payload["message"]
    found = payload["effects"][0]
    assert found["parameters"]["offset_v"] == pytest.approx(F0, rel=0.10)
    assert 0.0 < found["uncertainty"]["offset_v"] < 0.1 * F0
    assert found["explained"]["held_out_passed"] is True


@pytest.mark.slow
def test_no_offset_is_named_without_one(tmp_path):
    payload = _diagnose(_csv(tmp_path / "none.csv", 0.0))
    assert payload["effects"] == [], payload["message"]
