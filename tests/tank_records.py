"""Two tanks in cascade, simulated with scipy's ``solve_ivp`` from their own equations (not cosim's model code).

``h1' = (u - a1*sqrt(h1)) / A1``, ``h2' = (a1*sqrt(h1) - a2*sqrt(h2) - spill) / A2``: the inflow ``u`` held over
each sample (steps among random levels plus a small multisine, keeping the levels positive), and with `top` an
overflow: a weir of coefficient ``kw * A2`` above the tank's top, ``spill = kw * A2 * max(h2 - top, 0)``, so that
the level cannot pass the top by more than a few centimetres.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from cosim.data.trajectory import Trajectory
from cosim.identify.model import IdentifiedModel

A1, A2, a1, a2 = 0.5, 0.4, 0.3, 0.25
KW = 10.0  # 1/s: the overflow's weir, as a rate of the level past the top
DT = 0.05
STATES, INPUTS = ("h1", "h2"), ("u",)


def two_tanks(n: int = 3000, seed: int = 0, noise: float = 1e-3, top: float | None = None,
              hold: int = 300, kw: float = KW) -> Trajectory:
    """`n` samples at DT of the cascade, levels measured with `noise` (m), overflow above `top` if given (its weir
    `kw`, 1/s)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    u = np.repeat(rng.uniform(0.15, 0.5, n // hold + 1), hold)[:n]
    freqs, phases = np.linspace(0.02, 0.5, 8), rng.uniform(0.0, 2 * np.pi, 8)
    u = u + 0.03 * sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True))

    def rhs(time: float, h: np.ndarray) -> list[float]:
        k = min(int(time / DT + 1e-9), n - 1)
        q1, q2 = a1 * np.sqrt(max(h[0], 0.0)), a2 * np.sqrt(max(h[1], 0.0))
        spill = kw * A2 * max(h[1] - top, 0.0) if top is not None else 0.0
        return [(u[k] - q1) / A1, (q1 - q2 - spill) / A2]

    h0 = [(u[0] / a1) ** 2, (u[0] / a2) ** 2 if top is None else min((u[0] / a2) ** 2, top)]
    sol = solve_ivp(rhs, (0.0, t[-1]), h0, t_eval=t, rtol=1e-9, atol=1e-11, max_step=DT)
    h1, h2 = sol.y + noise * rng.standard_normal(sol.y.shape)
    return Trajectory.from_arrays(t, {"h1": h1, "h2": h2, "u": u}, roles={"h1": "state", "h2": "state", "u": "input"})


def linear_base(data: Trajectory) -> IdentifiedModel:
    """The linear model ``cosim diagnose`` starts from (its BASE_SETTINGS), identified on `data`."""
    from cosim.diagnose.diagnosis import BASE_SETTINGS
    from cosim.identify.sindyc import SINDYc

    return SINDYc(**BASE_SETTINGS).fit(data, states=list(STATES), inputs=list(INPUTS)).model_


def columns(data: Trajectory) -> dict[str, np.ndarray]:
    return {name: np.asarray(data[name]) for name in (*STATES, *INPUTS)}


def truth_model(extra: dict[str, dict[str, float]] | None = None, scale: float = 0.7) -> IdentifiedModel:
    """The cascade's own structure (``u``, ``sqrt(abs(h1))``, ``sqrt(abs(h2))``), its coefficients started at
    `scale` times the truth, and `extra` terms by row (``{term: {row: coefficient}}``)."""
    terms = {"u": {"h1": 1 / A1}, "sqrt(abs(h1))": {"h1": -a1 / A1, "h2": a1 / A2},
             "sqrt(abs(h2))": {"h2": -a2 / A2}, **(extra or {})}
    coef = np.array([[scale * terms[t].get(row, 0.0) for t in terms] for row in STATES])
    return IdentifiedModel(states=STATES, inputs=INPUTS, terms=tuple(terms), coef=coef)
