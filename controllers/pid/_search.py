"""The PID tuner's design search (private to :mod:`controllers.pid`): candidate gains at each crossover, the
robust ones, their predicted step responses, the choice among them, and what to say when none is robust.

At a crossover ``wc`` :func:`_shapes_at` solves the PI and PID shapes (or, with a measured velocity, the PI
gains for each velocity gain) that put the loop's phase margin exactly at ``wc``; :func:`_robust_at` keeps
those that meet the margins with a stable closed loop; :func:`_step_figures` predicts their setpoint and
load steps; :func:`_design` runs down the crossovers and picks the design; :func:`_not_met` explains a
failure. With input limits and a set-point step to deliver (:class:`_Demand`), :func:`_deliver` also steps the
PID's exact law, limits and anti-windup on, against the model (:mod:`controllers.pid._saturation`), and a
design is admissible only when that saturated step keeps the overshoot limit too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import brentq

from ._plant import _loop_figures, _Plant, _shape, _wrap
from ._saturation import _Actuator, _figures, _saturated_steps

#: Integral times ``Ti*wc`` and derivative filters ``n = Td/tf`` the search tries at each crossover.
_ALPHAS = (1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0)
_NS = (2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 30.0)
#: ``Td*wc`` grid on which the phase condition is bracketed before it is solved exactly.
_BETAS = np.logspace(-3.0, 2.0, 201)
#: Crossover candidates per decade, decades searched below `max_crossover`, and how far below the highest
#: crossover with an admissible step response the candidates still compete.
_WC_PER_DECADE = 24
_WC_DECADES = 6.0
_WC_SPAN = 2.0
#: Tolerance on the phase margin of secondary gain crossings [deg].
_PM_TOL = 0.5
#: Velocity structure: the relative tolerance on the position loop's crossover being the lowest one.
_FIRST_TOL = 0.01
#: Setpoint weights tried, settling band, and time samples of the predicted step responses.
_B_GRID = np.linspace(0.0, 1.0, 41)
_SETTLE = 0.02
_STEPS = 2000
#: With a step to deliver: every this many crossovers of the grid are tried first (a coarse scan down to the
#: highest crossover that delivers it), the best designs by load-step IAE stepped there, the set-point weights
#: tried under saturation, and the saturated run's length in linear horizons.
_COARSE = 4
_COARSE_BEST = 4
_SAT_WEIGHTS = 3
_SAT_HORIZONS = 2.0
#: The longest saturated step stepped in the search [samples]: a loop whose step needs more (a crossover some
#: 1e-4 of the sample rate) is not tried.
_SAT_MAX_SAMPLES = 100_000


@dataclass(frozen=True)
class _Demand:
    """A set-point step the design must deliver through its actuator: `step` (and its opposite when the
    limits are not symmetric about the bias)."""

    step: float
    act: _Actuator

    @property
    def steps(self) -> tuple[float, ...]:
        a = self.act
        symmetric = math.isclose(a.hi - a.u0, a.u0 - a.lo, rel_tol=1e-12) or not math.isfinite(a.hi - a.lo)
        return (self.step,) if symmetric else (self.step, -self.step)


class _Candidate:
    """One PI(D) shape at one crossover, with its loop figures and (once computed) its step figures."""

    def __init__(self, wc: float, kp: float, ti: float, td: float, tf: float, n: float | None) -> None:
        self.wc, self.kp, self.ti, self.td, self.tf, self.n = wc, kp, ti, td, tf, n
        self.figs: dict[str, Any] = {}
        self.b = self.overshoot = self.settling = self.iae_load = math.nan
        self.admissible = False
        self.horizon = math.nan  # length of the predicted linear step [s]
        self.ok_b: np.ndarray = np.zeros(0)  # set-point weights whose linear step is admissible, best first
        self.delivers: bool | None = None  # the saturated step keeps the limits (None: not stepped)

    def gains(self) -> tuple[float, float, float, float]:
        return self.kp, self.kp / self.ti, self.kp * self.td, self.tf


def _shapes_at(plant: _Plant, wc: float, pm: float, derivative: bool | None,
               ns: Sequence[float]) -> list[_Candidate]:
    """PI and PID shapes with ``arg L(e^{j wc dt}) = -180 deg + pm`` and ``|L| = 1`` at `wc`."""
    if plant.velocity is not None:
        return _velocity_shapes(plant, wc, pm)
    h = plant.dt
    zc = np.exp(1j * wc * h)
    pc = complex(plant.response(np.array([zc]))[0])
    if not (abs(pc) > 0 and math.isfinite(abs(pc))):
        return []
    phi = float(_wrap(-math.pi + pm - np.angle(pc)))  # phase the controller must supply at wc
    out: list[_Candidate] = []
    q = 1.0 / (zc - 1.0)
    if derivative is not True and -math.pi / 2 < phi < 0:  # PI: angle(1 + x*q) = phi with x = dt/Ti
        rot = np.exp(-1j * phi)
        x = math.sin(phi) / (rot * q).imag
        if x > 0 and (rot * (1 + x * q)).real > 0:
            out.append(_Candidate(wc, 1.0 / abs((1 + x * q) * pc), h / x, 0.0, 0.0, None))
    if derivative is not False and -math.pi / 2 < phi < math.pi / 2:
        tds = _BETAS / wc
        for alpha in _ALPHAS:
            ti = alpha / wc
            for n in ns:
                f = _wrap(np.angle(_shape(zc, h, ti, tds, tds / n)) - phi)
                up = np.nonzero((f[:-1] < 0) & (f[1:] >= 0))[0]  # the first (smallest Td) solution
                if not up.size:
                    continue
                i = int(up[0])

                def err(td: float, ti: float = ti, n: float = n) -> float:
                    return float(_wrap(np.angle(_shape(zc, h, ti, td, td / n)) - phi))

                td = brentq(err, tds[i], tds[i + 1], xtol=1e-15 / wc, rtol=1e-13)
                out.append(_Candidate(wc, 1.0 / abs(_shape(zc, h, ti, td, td / n) * pc), ti, td, td / n, n))
    return out


def _velocity_shapes(plant: _Plant, wc: float, pm: float) -> list[_Candidate]:
    """PI + velocity-feedback gains with ``L(e^{j wc dt}) = -e^{+-j pm}`` for every velocity gain in
    ``plant.kds``: the loop is linear in ``(kp, ki, kd)``, so at a given ``kd`` the complex condition is a 2 x 2
    real linear system in ``(kp, ki)``; solutions with ``kp, ki > 0`` are kept."""
    h = plant.dt
    zc = np.exp(1j * wc * h)
    pt, pv = plant.responses(np.array([zc]))[:, 0]
    if not (np.isfinite(pt) and np.isfinite(pv) and abs(pt) > 0):
        return []
    q = pt * h / (zc - 1.0)
    m = np.array([[pt.real, q.real], [pt.imag, q.imag]])
    if abs(np.linalg.det(m)) <= 1e-12 * abs(pt) * abs(q):
        return []
    out = []
    for sign in (1.0, -1.0):
        rhs = -np.exp(1j * sign * pm) - plant.kds * pv
        kps, kis = np.linalg.solve(m, np.vstack([rhs.real, rhs.imag]))
        out += [_Candidate(wc, float(kp), float(kp / ki), float(kd / kp), 0.0, None)
                for kp, ki, kd in zip(kps, kis, plant.kds, strict=True) if kp > 0 and ki > 0]
    return out


def _robust_at(plant: _Plant, wc: float, pm: float, derivative: bool | None, gm_min: float, mm_min: float,
               ns: Sequence[float]) -> list[_Candidate]:
    """The shapes at `wc` that meet the margins on the frequency grid and give a stable closed loop."""
    ok: list[_Candidate] = []
    if wc > plant.wc_cap:
        return ok
    pm_deg = math.degrees(pm)
    for c in _shapes_at(plant, wc, pm, derivative, ns):
        fg = c.figs = _loop_figures(plant.w, plant.loop(*c.gains()))
        if fg["pm"] < pm_deg - _PM_TOL or fg["gm"] < gm_min or fg["gm_low"] > 1.0 / gm_min or fg["mm"] < mm_min:
            continue
        if plant.velocity is not None and fg["w_first"] < wc * (1.0 - _FIRST_TOL):
            continue  # wc is not the position loop's crossover (the lowest)
        cl = plant.closed_loop(*c.gains())
        if cl is not None and np.max(np.abs(np.linalg.eigvals(cl[0]))) < 1.0:
            ok.append(c)
    return ok


def _held_step_responses(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, m: int,
                         k: int) -> np.ndarray:
    """Outputs at samples ``0, m, ..., k*m`` of ``x+ = A x + B w``, ``y = C x + D w`` for each unit input held
    from sample 0 (columns of `b`), from x = 0: ``(k + 1) x n_inputs``.

    Uses ``x_j = (I - A^j)(I - A)^-1 B`` with the eigendecomposition of a stable `A`; falls back to the
    recursion when the eigenvectors are ill-conditioned.
    """
    n = a.shape[0]
    x_end = np.linalg.solve(np.eye(n) - a, b)
    y_end = c @ x_end + d
    lam, v = np.linalg.eig(a)
    if np.linalg.cond(v) < 1e8 and np.all(np.abs(lam) > 1e-12):
        g = (c @ v).ravel()
        hh = np.linalg.solve(v, x_end)
        powers = np.exp(np.log(lam)[:, None] * (m * np.arange(k + 1))[None, :])  # lam**j, n x (k + 1)
        return (y_end - ((g[:, None] * powers).T @ hh).real).reshape(k + 1, -1)
    am = np.linalg.matrix_power(a, m)
    x = np.zeros_like(b)
    y = np.empty((k + 1, b.shape[1]))
    y[0] = (c @ x + d)[0]
    nm = (np.eye(n) - am) @ x_end
    for i in range(1, k + 1):
        x = am @ x + nm
        y[i] = (c @ x + d)[0]
    return y


def _step_figures(plant: _Plant, c: _Candidate, b: float | None, max_overshoot: float | None) -> None:
    """Predicted unit setpoint step (best or given b) and input load step of the linear loop, into `c`.

    The setpoint figures are the worst over the loop gains ``plant.gains`` (scaling the controller's gains
    is scaling the plant's input gain, as far as the setpoint response goes).
    """
    kp, ki, kd, tf = c.gains()
    a, bm, cy, dy = plant.closed_loop(kp, ki, kd, tf)  # type: ignore[misc]
    h = plant.dt
    rho = float(np.max(np.abs(np.linalg.eigvals(a))))
    tau = h / -math.log(rho) if rho > 0 else h
    horizon = min(max(12.0 * tau, 10.0 / c.wc), 100.0 / c.wc)
    m = max(1, math.ceil(horizon / (h * _STEPS)))
    k = math.ceil(horizon / (h * m))
    nominal = _held_step_responses(a, bm, cy, dy, m, k)
    step = m * h
    c.iae_load = float(np.sum(np.abs(nominal[:, 2])) * step)
    weights = _B_GRID if b is None else np.array([b])
    overshoot = np.zeros(weights.size)
    settling = np.zeros(weights.size)
    for g in plant.gains:
        y = nominal
        if g != 1.0:
            cl = plant.closed_loop(g * kp, g * ki, g * kd, tf)
            if cl is None or np.max(np.abs(np.linalg.eigvals(cl[0]))) >= 1.0:
                overshoot[:], settling[:] = math.inf, math.inf
                break
            y = _held_step_responses(*cl, m, k)
        ys = weights[:, None] * y[None, :, 0] + y[None, :, 1]
        overshoot = np.maximum(overshoot, np.maximum(ys.max(axis=1) - 1.0, 0.0) * 100.0)
        outside = np.abs(ys - 1.0) > _SETTLE
        last = k + 1 - np.argmax(outside[:, ::-1], axis=1)  # the sample after the last one outside the band
        ts = np.where(outside.any(axis=1), last * step, 0.0)
        ts[outside[:, -1]] = math.inf  # not settled within the horizon
        settling = np.maximum(settling, ts)
    ok = np.ones(weights.size, bool) if max_overshoot is None else overshoot <= max_overshoot + 1e-9
    c.admissible = bool(ok.any() and np.isfinite(settling[ok]).any())
    c.horizon = k * step
    good = ok & np.isfinite(settling)
    c.ok_b = weights[good][np.argsort(settling[good], kind="stable")]
    j = int(np.argmin(np.where(ok, settling, np.inf))) if c.admissible else int(np.argmin(overshoot))
    c.b, c.overshoot, c.settling = float(weights[j]), float(overshoot[j]), float(settling[j])


def _design(plant: _Plant, pm: float, bandwidth: float | None, derivative: bool | None, gm_min: float,
            mm_min: float, w_max: float, ns: Sequence[float], b: float | None,
            max_overshoot: float | None, demand: _Demand | None = None) -> tuple[_Candidate | None, list[_Candidate]]:
    """The chosen design (None when no shape is robust) and every robust candidate that was considered.

    Admissible candidates (overshoot within `max_overshoot`; with a `demand`, also in the saturated step)
    compete on the load-step IAE; when there are none, the one with the least overshoot is returned (its
    ``admissible`` is False); with a demand no design delivers, the design without it (``delivers`` False).
    """
    if demand is not None:
        best, robust = _deliver(plant, pm, bandwidth, derivative, gm_min, mm_min, w_max, ns, b, max_overshoot,
                                demand)
        if best is not None:
            return best, robust
        best, _ = _design(plant, pm, bandwidth, derivative, gm_min, mm_min, w_max, ns, b, max_overshoot)
        if best is not None:
            best.delivers = False
        return best, robust
    if bandwidth is not None:
        grid = np.array([bandwidth])
    else:
        grid = _grid(w_max)
    robust: list[_Candidate] = []
    w_robust = w_admissible = 0.0  # highest crossovers with a robust and with an admissible candidate
    for wc in grid:
        if wc < (w_admissible / _WC_SPAN if w_admissible else w_robust / _WC_SPAN**2):
            break
        for c in _robust_at(plant, float(wc), pm, derivative, gm_min, mm_min, ns):
            _step_figures(plant, c, b, max_overshoot)
            robust.append(c)
            w_robust = w_robust or float(wc)
            if c.admissible and not w_admissible:
                w_admissible = float(wc)
    return _choose(robust), robust


def _grid(w_max: float) -> np.ndarray:
    return w_max * 10.0 ** (-np.arange(int(_WC_DECADES * _WC_PER_DECADE) + 1) / _WC_PER_DECADE)


def _choose(robust: list[_Candidate]) -> _Candidate | None:
    if not robust:
        return None
    admissible = [c for c in robust if c.admissible]
    if admissible:
        return min(admissible, key=lambda c: c.iae_load)
    return min(robust, key=lambda c: (round(c.overshoot, 3), c.iae_load))


def _saturated_check(plant: _Plant, cands: list[_Candidate], demand: _Demand, max_overshoot: float | None) -> None:
    """Step every candidate with a linearly admissible step through the actuator (a few set-point weights, the
    loop gains of ``plant.gains`` at their extremes, both step signs when the limits are not symmetric); keep
    for each the weight whose saturated steps all keep `max_overshoot` and settle, settling fastest at the
    model's gain; set ``delivers`` and ``admissible``."""
    todo = [c for c in cands if c.admissible and c.delivers is None]
    if not todo:
        return
    gains = sorted({min(plant.gains), 1.0, max(plant.gains)})
    steps = demand.steps
    rows, owners = [], []
    for i, c in enumerate(todo):
        lower = np.sort(c.ok_b[c.ok_b < c.b])  # a lower weight kicks the input less at the step
        weights = [c.b, *lower[np.linspace(0, lower.size - 1, _SAT_WEIGHTS - 1).astype(int)]] if lower.size else [c.b]
        for w in list(dict.fromkeys(float(x) for x in weights))[:_SAT_WEIGHTS]:
            kp, ki, kd, tf = c.gains()
            for g in gains:
                for st in steps:
                    rows.append((g * kp, g * ki, g * kd, tf, w, st))
                    owners.append((i, w, g))
    arr = np.array(rows)
    n = max(2, math.ceil(_SAT_HORIZONS * max(c.horizon for c in todo) / plant.dt))
    if n > _SAT_MAX_SAMPLES:
        for c in todo:
            c.delivers = c.admissible = False
        return
    y, _ = _saturated_steps(plant, arr[:, :4], arr[:, 4], arr[:, 5], demand.act, n)
    overshoot = np.empty(arr.shape[0])
    settling = np.empty(arr.shape[0])
    for st in steps:  # _figures takes one step size
        j = arr[:, 5] == st
        overshoot[j], settling[j] = _figures(y[:, j], st, plant.dt)
    limit = math.inf if max_overshoot is None else max_overshoot + 1e-9
    verdict: dict[tuple[int, float], list[float]] = {}  # (candidate, weight) -> [ok, nominal settling, overshoot]
    for (i, w, g), os_, ts in zip(owners, overshoot, settling, strict=True):
        entry = verdict.setdefault((i, w), [1.0, 0.0, 0.0])
        entry[0] = entry[0] * float(os_ <= limit and math.isfinite(ts))
        if g == 1.0:
            entry[1], entry[2] = max(entry[1], ts), max(entry[2], os_)
    for i, c in enumerate(todo):
        options = [(ts, w, os_) for (j, w), (ok, ts, os_) in verdict.items() if j == i and ok]
        c.delivers = c.admissible = bool(options)
        if options:
            c.settling, c.b, c.overshoot = min(options)


def _deliver(plant: _Plant, pm: float, bandwidth: float | None, derivative: bool | None, gm_min: float,
             mm_min: float, w_max: float, ns: Sequence[float], b: float | None, max_overshoot: float | None,
             demand: _Demand) -> tuple[_Candidate | None, list[_Candidate]]:
    """:func:`_design` with a step to deliver: the highest crossover whose design delivers it is found on a
    coarse scan (every :data:`_COARSE` th crossover, its :data:`_COARSE_BEST` best designs by IAE stepped), then
    the crossovers just above it and down to half the highest delivering one compete as in :func:`_design`.
    None when no robust design delivers the step."""
    cache: dict[int, list[_Candidate]] = {}
    grid = np.array([bandwidth]) if bandwidth is not None else _grid(w_max)

    def at(i: int) -> list[_Candidate]:
        if i not in cache:
            cache[i] = _robust_at(plant, float(grid[i]), pm, derivative, gm_min, mm_min, ns)
            for c in cache[i]:
                _step_figures(plant, c, b, max_overshoot)
        return cache[i]

    top = None
    for i in range(0, grid.size, _COARSE):
        best = sorted((c for c in at(i) if c.admissible), key=lambda c: c.iae_load)[:_COARSE_BEST]
        _saturated_check(plant, best, demand, max_overshoot)
        if any(c.delivers for c in best):
            top = i
            break
        if best and _SAT_HORIZONS * max(c.horizon for c in best) / plant.dt > _SAT_MAX_SAMPLES:
            break  # lower crossovers step longer still
    if top is None:
        return None, [c for cands in cache.values() for c in cands]
    above = [c for i in range(max(0, top - _COARSE + 1), top) for c in at(i)]
    _saturated_check(plant, above, demand, max_overshoot)
    w_top = max(c.wc for c in [*above, *cache[top]] if c.delivers)
    below = [c for i in range(top, grid.size) if grid[i] >= w_top / _WC_SPAN for c in at(i)]
    bar = min((c.iae_load for c in [*above, *below] if c.delivers), default=math.inf)
    _saturated_check(plant, [c for c in below if c.iae_load < bar], demand, max_overshoot)
    competing = [c for c in [*above, *below] if c.delivers is not None or not c.admissible]
    for c in competing:
        c.admissible = bool(c.delivers)
    considered = [c for cands in cache.values() for c in cands]
    return _choose([c for c in competing if c.wc >= w_top / _WC_SPAN]), considered


def _any_robust(plant: _Plant, pm: float, bandwidth: float | None, derivative: bool | None, gm_min: float,
                mm_min: float, w_max: float, ns: Sequence[float]) -> _Candidate | None:
    """The highest-crossover robust candidate (margins and stability only), or None."""
    grid = [bandwidth] if bandwidth is not None else _grid(w_max)
    for wc in grid:
        found = _robust_at(plant, float(wc), pm, derivative, gm_min, mm_min, ns)
        if found:
            return found[0]
    return None


#: Phase margins [deg] tried to say what is reachable when a target is not.
_PM_PROBE = (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 85.0)


def _reachable_pms(feasible: Any, below: float | None = None) -> str:
    """Which of :data:`_PM_PROBE` (below `below`) satisfy `feasible(pm_rad)`, said in a few words."""
    ok = [pm for pm in _PM_PROBE if (below is None or pm < below) and feasible(math.radians(pm))]
    if not ok:
        return "no phase margin from 10 to 85 deg is"
    if len(ok) == 1:
        return f"a phase margin of {ok[0]:g} deg is"
    return f"phase margins of {ok[0]:g} to {ok[-1]:g} deg are"


def _not_met(plant: _Plant, pm_deg: float, bandwidth: float | None, derivative: bool | None, gm_db: float,
             gm_min: float, mm_min: float, w_max: float, ns: Sequence[float]) -> str:
    """One line: which target no PI(D) meets, and what is reachable instead."""
    kind = {None: "PI(D)", True: "PID", False: "PI"}[derivative]
    limits = f"gain margin >= {gm_db:g} dB and modulus margin >= {mm_min:g}"
    where = f"on {plant.input} -> {plant.output}"
    if plant.velocity is not None:
        kind, where = "PI with velocity feedback", f"{where} with {plant.velocity} fed back"
    if _any_robust(plant.negated(), math.radians(pm_deg), bandwidth, derivative, gm_min, mm_min, w_max, ns):
        return (f"the model's gain from {plant.input} to {plant.output} is negative (more input, less output) and "
                "PID gains are positive: tune on the negated model (-sys) and negate the PID's output, or swap "
                "the sign of the measurement")
    if bandwidth is not None:
        top = _any_robust(plant, math.radians(pm_deg), None, derivative, gm_min, mm_min, w_max, ns)
        at_bw = _reachable_pms(lambda pm: _any_robust(plant, pm, bandwidth, derivative, gm_min, mm_min, w_max, ns)
                               is not None)
        reach = (f"{at_bw} reachable at {bandwidth:.4g} rad/s; "
                 + (f"with {pm_deg:g} deg the highest crossover is about {top.wc:.3g} rad/s "
                    f"({top.wc / 2 / math.pi:.3g} Hz)" if top else
                    f"no crossover up to {w_max:.4g} rad/s gives {pm_deg:g} deg"))
        return (f"no {kind} gives crossover {bandwidth:.4g} rad/s with phase margin {pm_deg:g} deg, {limits} {where}: "
                f"{reach}")
    reach = _reachable_pms(lambda pm: _any_robust(plant, pm, None, derivative, gm_min, mm_min, w_max, ns)
                           is not None, below=pm_deg)
    return (f"no {kind} reaches phase margin {pm_deg:g} deg with {limits} and crossover <= {w_max:.4g} rad/s {where}; "
            f"{reach} reachable")

