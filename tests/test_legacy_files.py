"""Files written before the move into rooms still load and behave as they did.

``tests/data/legacy`` holds models, controllers (PID, MPC, each also wrapped in a friction compensation), a
trajectory (CSV with its comment header, Parquet) and a sweep result written by cosim at commit e52d3d5, and
``expected.json``: what that version computed from them (``make_legacy.py`` there says how).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from controllers import load_controller
from cosim import Trajectory
from cosim.identify.model import IdentifiedModel
from cosim.study.sweep import SweepResult

LEGACY = Path(__file__).parent / "data" / "legacy"
EXPECTED = json.loads((LEGACY / "expected.json").read_text())


@pytest.mark.parametrize("name", ["model.json", "model_diagnosed.json"])
def test_a_saved_model_simulates_as_before(name):
    model = IdentifiedModel.load(LEGACY / name)
    u = 500.0 * np.sign(np.sin(np.arange(400) * 0.02))[:, None] * np.ones((1, len(model.inputs)))
    sim = model.simulate(np.zeros(len(model.states)), u, dt=1 / 2257)
    np.testing.assert_allclose(sim.states[::40], EXPECTED[name]["states"], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["pid.json", "mpc.json", "pid_diagnosed.json", "mpc_diagnosed.json"])
def test_a_saved_controller_acts_as_before(name):
    ctrl = load_controller(LEGACY / name)
    assert ctrl.kind == EXPECTED[name]["kind"]
    ctrl.reset()
    rng = np.random.default_rng(0)
    ctrl.setpoint = [0.01] * len(ctrl.tracked)
    outs = [ctrl(k * ctrl.dt, 1e-3 * rng.standard_normal(len(ctrl.outputs))).tolist() for k in range(50)]
    # to the QP solver's own accuracy: the DAQP of casadi 3.8.2 moves two of these 50 MPC moves by 6e-7 relative
    # from casadi 3.7.2's (a controller read wrongly, its weights or horizon, moves them by whole percent)
    np.testing.assert_allclose(outs, EXPECTED[name]["u"], rtol=1e-5, atol=1e-9)
    # saved again, it is the same file: class paths stay the public ones ("controllers.pid:PID"); the figures the
    # controller computes again on loading (its LQR gain, spectral radii) to LAPACK's rounding (1e-13 apart
    # between numpy builds)
    _same(json.loads(load_controller(LEGACY / name).to_json()), json.loads((LEGACY / name).read_text()))


def _same(new, old, where="") -> None:
    """`new` equals `old` (parsed JSON): the same keys, strings and structure, numbers within 1e-9 relative."""
    if isinstance(old, dict):
        assert isinstance(new, dict) and new.keys() == old.keys(), where
        for key in old:
            _same(new[key], old[key], f"{where}/{key}")
    elif isinstance(old, list):
        assert isinstance(new, list) and len(new) == len(old), where
        for i, (a, b) in enumerate(zip(new, old, strict=True)):
            _same(a, b, f"{where}[{i}]")
    elif isinstance(old, float) and not isinstance(new, bool):
        assert new == pytest.approx(old, rel=1e-9), where
    else:
        assert new == old, where


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_saved_trajectory_reads_as_before(suffix):
    traj = Trajectory.read(LEGACY / f"trajectory{suffix}")
    expected = EXPECTED["trajectory"]
    assert list(traj.names) == expected["names"]
    assert list(traj.units) == expected["units"]
    np.testing.assert_array_equal(traj.time, expected["time"])
    for name, values in expected["values"].items():
        np.testing.assert_array_equal(traj[name], values)


def test_a_saved_sweep_reads_as_before():
    result = SweepResult.load(LEGACY / "sweep.json")
    assert result.results == EXPECTED["sweep.json"]["results"]
