"""Small records of an independent simulator for the command-line tests: scipy's solve_ivp on equations written
here (none of cosim's model code), written as a user's logger writes them (a CSV with a ``t`` column).

:func:`mass_spring` is a mass on a spring with viscous and (optionally) Coulomb friction, driven by a force held
between samples (zero-order hold, as cosim assumes), a piecewise-constant random excitation.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp


def mass_spring(path: Path, *, samples: int = 3000, dt: float = 2e-3, f_n: float = 1.6, mass: float = 2.0,
                damping: float = 0.05, coulomb: float = 0.0, force: float = 40.0, hold: int = 100, noise: float = 0.0,
                seed: int = 0, positions_only: bool = False) -> Path:
    """Write ``t, F, x[, v]`` of ``m x'' = F - k x - c x' - Fc tanh(x'/1e-3)`` to `path` (CSV) and return it.

    `f_n` is the natural frequency [Hz], `damping` the damping ratio, `force` the excitation's peak [N] (a new
    uniform value every `hold` samples), `noise` the measurement noise as a share of each written signal's
    standard deviation.
    """
    rng = np.random.default_rng(seed)
    k = mass * (2.0 * math.pi * f_n) ** 2
    c = 2.0 * damping * math.sqrt(k * mass)
    t = dt * np.arange(samples)
    u = np.repeat(rng.uniform(-force, force, samples // hold + 1), hold)[:samples]

    def rhs(tt: float, s: np.ndarray) -> list[float]:
        f = u[min(int(tt / dt + 1e-9), samples - 1)]
        return [s[1], (f - k * s[0] - c * s[1] - coulomb * math.tanh(s[1] / 1e-3)) / mass]

    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, method="LSODA", max_step=dt / 2, rtol=1e-8,
                    atol=1e-10)
    x, v = sol.y
    if noise:
        x = x + rng.normal(0.0, noise * x.std(), samples)
        v = v + rng.normal(0.0, noise * v.std(), samples)
    columns = {"t": t, "F": u, "x": x} if positions_only else {"t": t, "F": u, "x": x, "v": v}
    pd.DataFrame(columns).to_csv(path, index=False)
    return path
