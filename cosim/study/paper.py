"""The reference study and its plant: published numbers, initial state, sampling, true linear model.

The study (Infrared and Laser Engineering, "Model prediction of optical infrared telescope servo system in
extreme environment") identified a telescope azimuth two-mass servo with SINDYc; ``../shared/docs/paper.md``
summarises it. Its states were in arcseconds; cosim works in SI units (rad, rad/s).

Examples
--------
>>> a, b = two_mass_matrices()
>>> round(float(a[1, 0]))          # -KL/Jm with the bundled FMU's defaults
-10000
>>> STUDY_TABLE1[0.5]["theta_L"]
0.937
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["STUDY_X0", "STUDY_DT", "STUDY_NOISE_LEVELS", "STUDY_TABLE1", "STATES", "INPUTS",
           "TWO_MASS_DEFAULTS", "two_mass_matrices"]

#: State names of the bundled two-mass servo, in the study's order X0..X3.
STATES = ("theta_m", "omega_m", "theta_L", "omega_L")
#: Inputs: motor torque and load disturbance torque.
INPUTS = ("Tm", "TL")
#: The study's initial state X0 = [-2, 0, 2, 1], here in rad and rad/s.
STUDY_X0 = {"theta_m": -2.0, "omega_m": 0.0, "theta_L": 2.0, "omega_L": 1.0}
#: The study's encoder sampling rate, 2257 Hz.
STUDY_DT = 1 / 2257
#: The study's noise levels (noise std = level x std of the clean state).
STUDY_NOISE_LEVELS = (0.0, 0.05, 0.10, 0.20, 0.30, 0.50)
#: The study's Table 1: maximum deviation of each state in % of its amplitude, by noise level.
STUDY_TABLE1 = {
    0.0: {"theta_m": 0.130, "omega_m": 0.060, "theta_L": 4.120, "omega_L": 0.004},
    0.05: {"theta_m": 4.908, "omega_m": 1.112, "theta_L": 3.524, "omega_L": 0.485},
    0.10: {"theta_m": 2.635, "omega_m": 2.642, "theta_L": 4.192, "omega_L": 0.109},
    0.20: {"theta_m": 4.600, "omega_m": 7.372, "theta_L": 3.343, "omega_L": 4.122},
    0.30: {"theta_m": 9.794, "omega_m": 14.341, "theta_L": 2.169, "omega_L": 10.839},
    0.50: {"theta_m": 14.263, "omega_m": 31.482, "theta_L": 0.937, "omega_L": 28.409},
}
#: Published accuracy: R^2 > 0.99 up to 20 % noise; bench R^2 0.9857 (square wave) and 0.9952 (sine).
STUDY_R2_CLAIM = {"r2_min": 0.99, "up_to_noise": 0.20, "bench_square": 0.9857, "bench_sine": 0.9952}
#: Linear-plant parameters of the bundled FMU (fmus/two_mass_servo/README.md).
TWO_MASS_DEFAULTS = {"Jm": 250.0, "JL": 1000.0, "KL": 2.5e6, "Bm": 50.0, "BL": 500.0}


def two_mass_matrices(parameters: Mapping[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``A, B`` of the linear two-mass model, states (theta_m, omega_m, theta_L, omega_L), inputs (Tm, TL).

    Parameters
    ----------
    parameters : mapping, optional
        Jm, JL, KL, Bm, BL; missing ones take the bundled FMU's defaults.
    """
    p = {**TWO_MASS_DEFAULTS, **(parameters or {})}
    jm, jl, kl, bm, bl = (float(p[k]) for k in ("Jm", "JL", "KL", "Bm", "BL"))
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-kl / jm, -(bm + bl) / jm, kl / jm, bl / jm],
                  [0.0, 0.0, 0.0, 1.0],
                  [kl / jl, bl / jl, -kl / jl, -bl / jl]])
    b = np.array([[0.0, 0.0], [1.0 / jm, 0.0], [0.0, 0.0], [0.0, 1.0 / jl]])
    return a, b
