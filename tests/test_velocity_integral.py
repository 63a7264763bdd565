"""The velocity-integral start of the output-error refinement (:mod:`cosim.identify._velocity_integral`).

With pinned kinematics the positions are taken from the integrals of their velocities, so a twist whose
signal is near its position noise keeps its spring. Plant: two inertias on a damped shaft, the kinematics
tests' own solve_ivp simulation (:func:`test_kinematics.two_mass`), 8 s (4 s at 5 kHz), noise a share of each
signal's range. Measured over 8 s when written (stiffness over truth, velocity-integral / plain equation error):
1 kHz, 10 Hz shaft, 2 %: 0.975 / 1.006; 5 %: 0.857 / 0.000; 5 kHz, 20 Hz, 2 %: 1.002 / 0.000; 200 Hz, 3 Hz,
2 %: 1.014 / 0.971.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_kinematics import two_mass

from cosim.data.trajectory import Trajectory
from cosim.identify._refinement import _velocity_start
from cosim.identify._velocity_integral import velocity_integral_start
from cosim.identify.model import IdentifiedModel
from cosim.identify.sindyc import SINDYc

STATES = ("theta_m", "omega_m", "theta_L", "omega_L")
KIN = {"theta_m": "omega_m", "theta_L": "omega_L"}
J1, J2 = 0.02, 0.06  # as two_mass simulates them


def _record(fs: float, f_res: float, noise: float) -> tuple[np.ndarray, np.ndarray, float]:
    x = two_mass(fs, f_res=f_res, noise=noise, duration=min(8.0, 20_000 / fs))
    f1, f2 = np.random.default_rng(0).uniform(0.3, 3.0, 2)  # two_mass's torque, same seed
    t = np.arange(len(x)) / fs
    u = np.sign(np.sin(2 * np.pi * f1 * t + 0.3)) + 0.5 * np.sin(2 * np.pi * f2 * t)
    return x, u[:, None], (2 * np.pi * f_res) ** 2 * J1 * J2 / (J1 + J2)


def _template(dt: float) -> IdentifiedModel:
    terms = ("1", *STATES, "u")
    coef = np.ones((4, len(terms)))
    for pos, vel in KIN.items():
        coef[STATES.index(pos)] = 0.0
        coef[STATES.index(pos), terms.index(vel)] = 1.0
    return IdentifiedModel(states=STATES, inputs=("u",), terms=terms, coef=coef, dt=dt)


@pytest.mark.parametrize("fs,f_res,noise,tol", [(1000, 10.0, 0.05, 0.2), (5000, 20.0, 0.02, 0.05),
                                                (200, 3.0, 0.02, 0.05)])
def test_the_shaft_spring_survives_position_noise(fs, f_res, noise, tol):
    x, u, k = _record(fs, f_res, noise)
    start = _velocity_start(_template(1 / fs), [(x, u)], 1 / fs, KIN)
    assert start is not None
    # omega_m' = -k/J1 theta_m + ...: the stiffness the start carries, over the truth
    assert -start.coef[1, 1] * J1 / k == pytest.approx(1.0, abs=tol)
    assert start.coef[0].tolist() == _template(1 / fs).coef[0].tolist()  # kinematic rows kept as they are
    if noise >= 0.02 and fs >= 1000:  # where the plain equation-error fit loses the spring
        traj = Trajectory.from_arrays(np.arange(len(x)) / fs, {**dict(zip(STATES, x.T, strict=True)), "u": u[:, 0]},
                                      roles={**dict.fromkeys(STATES, "state"), "u": "input"})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            plain = SINDYc(library="linear", include_constant=True, threshold=0.0, kinematics=KIN, refine=None,
                           allow_unstable=True).fit(traj, states=list(STATES), inputs=["u"]).model_
        assert abs(-plain.coef[1, 1] * J1 / k) < 0.2


def test_no_start_without_kinematics_or_data():
    x, u, _ = _record(1000, 10.0, 0.01)
    model = _template(1e-3)
    assert velocity_integral_start(model, [(x, u)], 1e-3, {}, 48) is None
    assert velocity_integral_start(model, [(x[:100], u[:100])], 1e-3, KIN, 48) is None  # fewer than 3 blocks
