"""The plants of the benchmark's record families (records 200 on, :mod:`independent_families`): their equations,
two integrators and the visibility of their effects. Its own equations, scipy's solve_ivp; no cosim import.

Plants (a :class:`System`)
    ``mass`` (states ``x, v``, input ``u``) and ``pendulum`` (``theta, omega``, ``tau``)::

        m v' = g(u) - b v - k x + sum of the effects' forces

    ``tanks``, a cascade of two tanks (levels ``h1, h2``, inflow ``u``)::

        A1 h1' = u - q1        A2 h2' = q1 - q2        (q_i = a_i sqrt(h_i) with sqrt_outflow, else linear)

Effects (cosim's catalogue names), each a *quantity* along the run that enters the derivative rows with fixed
gains (a force enters ``v`` with 1/m; tank 1's outflow enters ``h1`` with -1/A1 and ``h2`` with +1/A2):
``coulomb_friction`` ``-Fc tanh(v/eps)``; ``stribeck`` ``-Fs exp(-(v/vs)^2) tanh(v/eps)``;
``viscous_asymmetry`` ``-d |v|``; ``offset`` ``F0``; ``gravity`` ``-G sin(x)``; ``cubic_stiffness``
``-k3 x^3`` (a Duffing spring to ground, hardening); ``saturation`` and ``deadzone`` ``g(u) - u`` (the plant
sees the clipped or dead-zoned command, the record writes the command); ``sqrt_outflow`` ``a_i sqrt(h_i)``;
``hard_stop`` (a level that cannot pass ``bound``: at the bound a rising derivative is set to 0, the excess
spills; its quantity is the derivative removed).

Integrators: ``lsoda`` (every sample interval on its own, the input held, ``solve_ivp(LSODA)``'s bits by
``_held_lsoda``, as independent_plants.simulate) or ``euler`` (forward Euler with ``substeps`` equal steps per
sample interval, as an FMU's fixed-step solver gives a record).

Visibility (:func:`visibility`): an effect's non-linear part over the noise. The effect's quantity along the
noise-free run is fitted by least squares on the states, the input and a constant (what a linear model can
take up of it); the run is made again with that linear fit in its place (the other effects kept), and the
RMS difference of each written signal between the two runs, over that signal's noise standard deviation, is
averaged in square. An offset, which a model's constant takes up whole and cosim names as such, is rated by
its plain contribution (the run without it). ``combined``: every effect replaced by its linear fit at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from _held_lsoda import lsoda_interval
from scipy.integrate import solve_ivp

NAMES = {"mass": ("x", "v", "u"), "pendulum": ("theta", "omega", "tau"), "tanks": ("h1", "h2", "u")}


@dataclass(frozen=True)
class System:
    """A family plant: ``kind`` (mass, pendulum, tanks), parameters ``p`` and its effects (dicts with ``name``,
    ``at``, ``params``); ``integrator`` ``{"method": "lsoda"}`` or ``{"method": "euler", "substeps": s}``."""

    kind: str
    p: dict[str, float]
    effects: list[dict] = field(default_factory=list)
    integrator: dict = field(default_factory=lambda: {"method": "lsoda"})

    @property
    def states(self) -> tuple[str, str]:
        return NAMES[self.kind][:2]

    @property
    def input(self) -> str:
        return NAMES[self.kind][2]

    def with_effects(self, effects: list[dict]) -> System:
        return System(self.kind, self.p, effects, self.integrator)


def _dz(u: float, w: float) -> float:
    return u - w if u > w else (u + w if u < -w else 0.0)


def _quantity(e: dict, y: np.ndarray, u: float) -> float:
    """Effect `e`'s quantity (a force, a flow) at state `y`, command `u` (not the hard stop's)."""
    q, name = e["params"], e["name"]
    x, v = y[0], y[1]
    if name == "coulomb_friction":
        return -q["Fc"] * math.tanh(v / q["eps"])
    if name == "stribeck":
        return -q["Fs"] * math.exp(-(v / q["vs"]) ** 2) * math.tanh(v / q["eps"])
    if name == "viscous_asymmetry":
        return -q["d"] * abs(v)
    if name == "offset":
        return q["F0"]
    if name == "gravity":
        return -q["G"] * math.sin(x)
    if name == "cubic_stiffness":
        return -q["k3"] * x ** 3
    if name == "saturation":
        return min(max(u, -q["level"]), q["level"]) - u
    if name == "deadzone":
        return _dz(u, q["width"]) - u
    if name == "sqrt_outflow":
        h = y[0] if e["at"] == "h1" else y[1]
        return q["a_flow"] * math.sqrt(max(h, 0.0))
    raise ValueError(name)


def _gains(system: System, e: dict) -> np.ndarray:
    """How effect `e`'s quantity enters the derivative rows."""
    p = system.p
    if system.kind == "tanks":
        if e["name"] == "hard_stop":
            return np.array([1.0, 0.0]) if e["at"] == "h1" else np.array([0.0, 1.0])
        return np.array([-1 / p["A1"], 1 / p["A2"]]) if e["at"] == "h1" else np.array([0.0, -1 / p["A2"]])
    return np.array([0.0, 1.0 / p["m"]])


def _base(system: System, y: np.ndarray, u: float) -> np.ndarray:
    p = system.p
    if system.kind == "tanks":  # a linear outflow where there is no sqrt_outflow (never in the families)
        return np.array([(u - p.get("c1", 0.0) * y[0]) / p["A1"],
                         (p.get("c1", 0.0) * y[0] - p.get("c2", 0.0) * y[1]) / p["A2"]])
    return np.array([y[1], (u - p["b"] * y[1] - p["k"] * y[0]) / p["m"]])


def derivative(system: System, y: np.ndarray, u: float, linear: dict[int, np.ndarray] | None = None,
               frozen: bool | None = None) -> tuple[np.ndarray, float]:
    """``y'`` at state `y` and held command `u`, and the hard stop's removed derivative (0 without one).

    `linear` maps an effect's position in ``system.effects`` to coefficients over ``[states, u, 1]`` that
    replace its quantity (its linear fit, for :func:`visibility`). `frozen` (a hard stop's row): None clamps
    at the bound, True holds the row, False leaves it free (the LSODA integrator's events switch the two)."""
    d = _base(system, y, u)
    z = None
    stop = None
    for i, e in enumerate(system.effects):
        if linear is not None and i in linear:
            if z is None:
                z = np.array([y[0], y[1], u, 1.0])
            d = d + _gains(system, e) * float(linear[i] @ z)
        elif e["name"] == "hard_stop":
            stop = e
        else:
            d = d + _gains(system, e) * _quantity(e, y, u)
    removed = 0.0
    if stop is not None:
        r = 0 if stop["at"] == system.states[0] else 1
        if frozen or (frozen is None and y[r] >= stop["params"]["bound"] and d[r] > 0):
            removed, d[r] = -d[r], 0.0
    return d, removed


def _clamp(system: System, y: np.ndarray, linear: dict[int, np.ndarray] | None) -> np.ndarray:
    for i, e in enumerate(system.effects):
        if e["name"] == "hard_stop" and not (linear and i in linear):
            r = 0 if e["at"] == system.states[0] else 1
            y[r] = min(y[r], e["params"]["bound"])
    return y


def simulate(system: System, u: np.ndarray, dt: float, x0: np.ndarray | None = None,
             linear: dict[int, np.ndarray] | None = None, rtol: float = 1e-8, atol: float = 1e-11) -> np.ndarray:
    """The states at ``k dt`` (``len(u) + 1`` rows) under the commands `u`, each held over its interval."""
    n = len(u)
    y = np.zeros(2) if x0 is None else np.asarray(x0, dtype=float).copy()
    out = np.empty((n + 1, 2))
    out[0] = y
    euler = system.integrator.get("method") == "euler"
    sub = int(system.integrator.get("substeps", 1))
    h = dt / sub
    for k in range(n):
        uk = float(u[k])
        if euler:
            for _ in range(sub):
                y = _clamp(system, y + h * derivative(system, y, uk, linear)[0], linear)
        else:
            y = _lsoda_step(system, y, uk, k * dt, (k + 1) * dt, linear, rtol, atol)
        if not np.all(np.isfinite(y)) or np.max(np.abs(y)) > 1e9:
            raise RuntimeError(f"the run diverged at t={k * dt:.4g}")
        out[k + 1] = y
    return out


def _lsoda_step(system: System, y: np.ndarray, u: float, t0: float, t1: float,
                linear: dict[int, np.ndarray] | None, rtol: float, atol: float) -> np.ndarray:
    """One sample interval by LSODA; a hard stop's row is held at its bound between two events (reaching the
    bound; its free derivative turning negative), so the solver never steps across the switch."""
    stop = next(((i, e) for i, e in enumerate(system.effects) if e["name"] == "hard_stop"
                 and not (linear and i in linear)), None)
    opts = {"method": "LSODA", "rtol": rtol, "atol": atol, "max_step": t1 - t0, "min_step": 1e-10 * (t1 - t0)}
    if stop is None:
        try:
            # the state as Python floats: the same arithmetic as on NumPy scalars, at a fraction of the cost
            return lsoda_interval(lambda t, s: derivative(system, s.tolist(), u, linear)[0], t0, t1, y,
                                  **{k: v for k, v in opts.items() if k != "method"})
        except RuntimeError as exc:
            raise RuntimeError(f"integration failed at t={t0:.4g}: {exc}") from None
    r = system.states.index(stop[1]["at"])
    bound = stop[1]["params"]["bound"]
    t = t0
    for _ in range(20):
        free = derivative(system, y, u, linear, frozen=False)[0][r]
        frozen = bool(y[r] >= bound * (1 - 1e-12) and free > 0)

        def event(t, s, frozen=frozen):
            return derivative(system, s, u, linear, frozen=False)[0][r] if frozen else s[r] - bound
        event.terminal, event.direction = True, (-1 if frozen else 1)
        try:
            sol = solve_ivp(lambda t, s, frozen=frozen: derivative(system, s, u, linear, frozen=frozen)[0],
                            (t, t1), y, events=event, **opts)
        except ValueError:  # an event function at zero where the segment starts: the clamp, for this rest
            sol = solve_ivp(lambda t, s: derivative(system, s, u, linear)[0], (t, t1), y, **opts)
        if not sol.success:
            raise RuntimeError(f"integration failed at t={t:.4g}: {sol.message}")
        y, t = sol.y[:, -1].copy(), float(sol.t[-1])
        if sol.status == 1 and not frozen:
            y[r] = bound
        if sol.status == 0 or t >= t1:
            break
    return _clamp(system, y, linear)


def quantities(system: System, states: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Each effect's quantity at the samples of a run (columns in ``system.effects``' order)."""
    uu = np.append(u, u[-1])
    out = np.empty((len(states), len(system.effects)))
    for i, e in enumerate(system.effects):
        if e["name"] == "hard_stop":
            out[:, i] = [derivative(system, y, float(c))[1] for y, c in zip(states, uu, strict=True)]
        else:
            out[:, i] = [_quantity(e, y, float(c)) for y, c in zip(states, uu, strict=True)]
    return out


def linear_fits(system: System, runs: list[tuple[np.ndarray, np.ndarray]]) -> dict[int, np.ndarray]:
    """Per effect, the least-squares fit of its quantity on ``[states, u, 1]`` over the noise-free `runs`
    (states, commands), pooled."""
    z = np.vstack([np.column_stack([s, np.append(u, u[-1]), np.ones(len(s))]) for s, u in runs])
    q = np.vstack([quantities(system, s, u) for s, u in runs])
    return {i: np.linalg.lstsq(z, q[:, i], rcond=None)[0] for i in range(len(system.effects))}


def _ratio(a: np.ndarray, b: np.ndarray, written: list[int], sigma: list[float]) -> float:
    per = [float(np.sqrt(np.mean((a[:, i] - b[:, i]) ** 2))) / s for i, s in zip(written, sigma, strict=True)]
    return float(np.sqrt(np.mean(np.square(per))))


def visibility(system: System, runs: list[dict]) -> dict:
    """The effects' non-linear part over the noise (see the module notes), pooled over `runs`: dicts with
    ``u`` (commands), ``x0``, ``dt``, ``states`` (the noise-free run), ``written`` (state indices) and
    ``sigma`` (their noise standard deviations). Returns ``{"effects": [...], "combined": float}``."""
    fits = linear_fits(system, [(r["states"], r["u"]) for r in runs])

    def compare(linear: dict | None, effects: list[dict] | None = None) -> float:
        sq = []
        for r in runs:
            sys_ = system if effects is None else system.with_effects(effects)
            try:
                other = simulate(sys_, r["u"], r["dt"], r["x0"], linear)
            except RuntimeError:
                return math.inf
            sq.append(_ratio(r["states"], other, r["written"], r["sigma"]) ** 2)
        return float(np.sqrt(np.mean(sq)))

    per = []
    for i, e in enumerate(system.effects):
        if e["name"] == "offset":
            per.append(compare(None, [x for j, x in enumerate(system.effects) if j != i]))
        else:
            per.append(compare({i: fits[i]}))
    combined = compare({i: f for i, f in fits.items() if system.effects[i]["name"] != "offset"}) \
        if any(e["name"] != "offset" for e in system.effects) else 0.0
    return {"effects": per, "combined": combined}
