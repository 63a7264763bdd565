"""Screening candidate effects on the output error: a Gauss-Newton score test along the model's free run.

Why not the equation error: with noisy positions, a stiff coupling turns the position noise into equation
error far larger than a friction force (the two-mass servo at 5 % noise: ``KL/Jm = 1e4`` times the noise on
``theta_m - theta_L``). The free-run error of a model fitted by output error is the measurement noise plus
what the model lacks; that is where an effect shows.

For a model ``x' = f(x, u)`` simulated from ``x0`` (its own estimated initial state), adding a term
``c * phi(x, u)`` to row ``i`` changes the free run, to first order in ``c``, by ``c * s(t)`` where
``s' = J(t) s + e_i phi(x_sim(t), u(t))``, ``s(0) = 0``, and ``J`` is the Jacobian of ``f`` along the free run.
The same sensitivities of the model's own coefficients (and of its initial state) form the base. Regressing the
free-run residual (each state scaled by its noise level, estimated from second differences) on the base and
the candidate's sensitivities gives the residual reduction the candidate buys with every present coefficient
re-estimated: its BIC change and its likelihood-ratio (score) test, with the residual variance estimated.

The sensitivities are integrated with the exact zero-order-hold step of the model's linear part and the
time-varying rest of the Jacobian held over each sample, in blocks of time (:mod:`._sensitivity`).

Several records (``segments``: the start of each record in the concatenated columns) are fitted at once: each
record's free run starts from its own initial state (estimated per record, n parameters each), its
sensitivities start afresh at its first sample, and nothing steps from one record into the next. The fitted
model's ``meta["x0"]`` holds one initial state per record. :func:`initial_state_fit` re-estimates only the
initial states (coefficients held), to judge a model on records it was not fitted to.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> m = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u"), coef=np.array([[1, 0], [-2, 1.0]]))
>>> t = np.arange(2001) * 1e-3
>>> u = np.sin(7 * t)
>>> sim = m.simulate([0.0, 0.0], u[:-1, None], dt=1e-3).states
>>> screen = OutputErrorScreen(m, {"x": sim[:, 0], "v": sim[:, 1], "u": u}, 1e-3)
>>> screen.base.shape[1]   # two coefficients of the v row, two initial states
4
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from scipy import linalg, special

from ..errors import DataError
from ..identify.model import IdentifiedModel
from ..identify.terms import Term
from ._free_run import (
    _bounds,
    _cost,
    _free_run,
    _matrices,
    _simulate,
    _starts,
    correlation_factor,
    free_run_cost,
    free_run_residual,
    measured_weights,
    noise_level,
)
from ._nuisance import Nuisance, _apply, _nuisance_columns, _tie_map
from ._record_band import RecordBand
from ._sensitivity import Propagator
from .effects import Attachment, Effect, Roles

# (the free-run helpers of ._free_run are imported from here too)
__all__ = ["InitialStateFit", "Nuisance", "OutputErrorScreen", "correlation_factor", "free_run_cost",
           "free_run_residual", "initial_state_fit", "measured_weights", "noise_level", "output_error_fit"]

#: Columns of sensitivities integrated in one pass (memory: samples x states x this x 8 bytes).
_CHUNK = 96
#: Terms whose values along the free run one screen keeps (each samples x 8 bytes).
_TERM_CACHE = 256


def _sample_jacobian(model: IdentifiedModel, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The Jacobian of the model's nonlinear terms as a sample-held step sees it: the slope over each sample's
    own motion (central differences spanning it), (samples, n, n). The linear terms' (the constant, states and
    inputs) is the model's ``A`` everywhere and is not included.

    Not the exact (pointwise) Jacobian: where a term turns sharply (a friction's tanh(v/eps) with eps far below
    the speed change per sample), the pointwise slope times the sample time exceeds 2, the held-over-a-sample
    sensitivity step is unstable and the Gauss-Newton steps built on it wander (measured on a two-mass record
    with Coulomb friction: Fc 0.089 with the exact slope, 0.150 with this one, truth 0.15; and 222 instead of 512
    simulations). The discrete free run itself only sees the slope across each step.

    Only the nonlinear terms are evaluated, and only in the states they use: differencing the whole right-hand
    side evaluated every term twice per state, a seventh of a 20 000-sample diagnosis.
    """
    n = len(model.states)
    jac = np.zeros((len(x), n, n))
    linear = {"1", *model.states, *model.inputs}
    used = [k for k, t in enumerate(model.terms) if t not in linear and np.any(model.coef[:, k] != 0.0)]
    if not used:
        return jac
    terms = [Term(model.terms[k]) for k in used]
    coef = model.coef[:, used]
    values = {name: u[:, j] for j, name in enumerate(model.inputs)}
    values.update({name: x[:, i] for i, name in enumerate(model.states)})
    scale = np.maximum(np.abs(x).max(axis=0), 1e-12)
    move = np.abs(np.diff(x, axis=0, append=x[-1:]))
    for j, name in enumerate(model.states):
        mine = [c for c, t in enumerate(terms) if name in t.variables]
        if not mine:
            continue
        h = np.maximum(0.5 * move[:, j], 1e-6 * scale[j])
        up = np.column_stack([terms[c].evaluate({**values, name: x[:, j] + h}) for c in mine])
        down = np.column_stack([terms[c].evaluate({**values, name: x[:, j] - h}) for c in mine])
        jac[:, :, j] = ((up - down) / (2.0 * h[:, None])) @ coef[:, mine].T
    return jac


class OutputErrorScreen:
    """Free-run residual of a model on data, its sensitivities, and the score of candidate terms.

    `segments` (start indices of the records in the concatenated columns; None: one record) gives each record
    its own free run and initial state; `x0` then holds one initial state per record, shape (records, n),
    and so does :attr:`x0`.

    `measured` names the states that are measurements (None: all). The others (a velocity derived from a measured
    position by a smoothing differentiator) still evolve in the free run, and their initial states are still
    estimated through the measured ones, but their entries count in no cost: the residual and every
    sensitivity hold zeros there (the shapes stay samples x states), and :attr:`n_obs` counts the measured
    entries only.
    """

    def __init__(self, model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float,
                 x0: Sequence[float] | None = None, *, estimate_x0: bool = True,
                 noise: Mapping[str, float] | None = None, segments: Sequence[int] | None = None,
                 measured: Sequence[str] | None = None,
                 _free_run: np.ndarray | None = None, _coefficients: bool = True) -> None:
        self.model, self.columns, self.dt = model, dict(columns), float(dt)
        self.estimate_x0 = bool(estimate_x0)
        self.roles = Roles.of(model)
        states, n = model.states, len(model.states)
        self.weight = measured_weights(states, measured)
        self.measured = tuple(s for s, w in zip(states, self.weight, strict=True) if w)
        X, U = _matrices(model, columns)
        self.segments = None if segments is None else [int(s) for s in segments]
        self.bounds = _bounds(self.segments, len(X))
        n_seg = len(self.bounds)
        meta_x0 = model.meta.get("x0") if isinstance(model.meta, Mapping) else None
        if x0 is not None:
            start = _starts(x0, n_seg, n)
        elif meta_x0 and (n_seg == 1 or len(meta_x0) == n_seg):
            start = _starts(meta_x0[0] if n_seg == 1 else meta_x0, n_seg, n)
        else:
            start = X[0] if n_seg == 1 else X[[a for a, _ in self.bounds]]
        if _free_run is None:  # (a fit hands over the free run it has just simulated for its line search)
            _free_run, message = _simulate(model, U, dt, start, self.bounds)
            if _free_run is None:
                raise DataError(f"the model's free run diverges on these data ({message}); diagnose a stable model")
        self.x_sim, self.U = _free_run, U
        noise = noise or {}
        self.sigma = np.array([float(noise[s]) if s in noise else noise_level(X[:, i], self.segments)
                               for i, s in enumerate(states)])
        self._scale = self.weight / self.sigma  # what multiplies a state's error: 1/sigma, 0 if not measured
        self.residual = ((X - self.x_sim) * self._scale).reshape(-1)
        self.scale_y = float(np.linalg.norm(((X - X.mean(axis=0)) * self._scale).reshape(-1)))
        self.n_obs = len(X) * len(self.measured)
        self._term_cache: dict[str, np.ndarray] = {}
        self._prepare_dynamics()
        self.base = self._base_sensitivities(start, _coefficients)
        if not np.all(np.isfinite(self.base)):
            raise DataError("the free-run sensitivities overflow: the model is too unstable on these data")

    # the projections on the base: made when first needed (a fit's intermediate screens never need them)
    @cached_property
    def q_base(self) -> np.ndarray:
        """An orthonormal basis of the base sensitivities' span, (entries, base columns)."""
        return np.linalg.qr(self.base)[0]

    @cached_property
    def r_perp(self) -> np.ndarray:
        """The residual with its projection on the base removed."""
        return self.residual - self.q_base @ (self.q_base.T @ self.residual)

    @cached_property
    def band(self) -> RecordBand:
        """What the record can show: its sample time, length, the states' noise levels and the positions' visible
        bands (through the model), with the ranges of the free run's signals (the nuisance grids and spans are
        scaled on the noise-free free run). Made once per screen."""
        return RecordBand.of(self.free_run, self.dt, dict(zip(self.model.states, map(float, self.sigma), strict=True)),
                             model=self.model, measured={s: self.columns[s] for s in self.measured},
                             segments=self.segments)

    @cached_property
    def rss0(self) -> float:
        return float(self.r_perp @ self.r_perp)

    @cached_property
    def variance(self) -> float:
        """The residual variance with every base parameter re-estimated (per measured entry)."""
        return self.rss0 / max(self.n_obs - self.base.shape[1], 1)

    @property
    def free_run(self) -> dict[str, np.ndarray]:
        """The data's columns with the states replaced by the model's free run (noise-free: nuisance grids are
        scaled on it, since the largest measured twist of two noisy positions is mostly noise)."""
        return self._values(self.x_sim)

    # ------------------------------------------------------------------ dynamics along the free run
    def _values(self, x: np.ndarray) -> dict[str, np.ndarray]:
        values = {k: np.asarray(v, dtype=float)[:len(x)] for k, v in self.columns.items()}
        for i, name in enumerate(self.model.states):
            values[name] = x[:, i]
        return values

    def _prepare_dynamics(self) -> None:
        model, x, n = self.model, self.x_sim[:-1], len(self.model.states)
        u = self.U[:-1]
        a0 = np.zeros((n, n))
        for j, name in enumerate(model.states):
            if name in model.terms:
                a0[:, j] = model.coef[:, model.terms.index(name)]
        if model.is_linear:  # the Jacobian is a0 everywhere
            self.delta_j, self.nonlinear = np.zeros((len(x), n, n)), False
        else:
            self.delta_j = _sample_jacobian(model, x, u)  # the time-varying rest of the Jacobian
            self.nonlinear = bool(np.any(np.abs(self.delta_j) > 1e-9 * max(1.0, float(np.abs(a0).max()))))
        big = np.zeros((2 * n, 2 * n))
        big[:n, :n], big[:n, n:] = a0 * self.dt, np.eye(n) * self.dt
        phi = linalg.expm(big)
        self.ad, self.gamma = phi[:n, :n], phi[:n, n:]
        # one propagator per record: its steps are the samples inside it (none across a boundary)
        self._propagators = [Propagator(self.ad, self.gamma, self.delta_j[a:b - 1] if self.nonlinear else None,
                                        b - a - 1) for a, b in self.bounds]

    def _integrate(self, forcing: np.ndarray, s0: np.ndarray | None = None) -> np.ndarray:
        """Sensitivities for forcing (samples-1, states, m) from s0: (samples, states, m).

        `s0` is (states, m), the sensitivities at each record's first sample, or (records, states, m), one
        per record; None: zero. No step goes from one record into the next (that row of `forcing` is unused).
        """
        return self._run(lambda p, a, b, s: p.integrate(forcing[a:b - 1], s), forcing.shape[2], s0)

    def _integrate_columns(self, rows: Sequence[int], values: np.ndarray, s0: np.ndarray | None = None,
                           ) -> np.ndarray:
        """:meth:`_integrate` for column c forced in state ``rows[c]`` only, by ``values[:, c]``."""
        return self._run(lambda p, a, b, s: p.integrate_columns(rows, values[a:b - 1], s), values.shape[1], s0)

    def _run(self, integrate: Callable, m: int, s0: np.ndarray | None) -> np.ndarray:
        n_seg = len(self.bounds)
        starts = [None] * n_seg if s0 is None else [s0] * n_seg if s0.ndim == 2 else list(s0)
        if n_seg == 1:
            return integrate(self._propagators[0], 0, len(self.x_sim), starts[0])
        out = np.empty((len(self.x_sim), len(self.model.states), m))
        for (a, b), p, s in zip(self.bounds, self._propagators, starts, strict=True):
            out[a:b] = integrate(p, a, b, s)
        return out

    def _flatten(self, sens: np.ndarray) -> np.ndarray:
        return (sens * self._scale[None, :, None]).reshape(-1, sens.shape[2])

    def _flatten_owned(self, sens: np.ndarray) -> np.ndarray:
        """:meth:`_flatten` in place, for sensitivities nothing else holds."""
        sens *= self._scale[None, :, None]
        return sens.reshape(-1, sens.shape[2])

    def _term_values(self, terms: Sequence[str]) -> np.ndarray:
        """Each term evaluated along the free run (inputs and extra columns from the data), (samples-1, terms).

        Each distinct term is evaluated once per screen (the free run is fixed; a column's name says what it
        holds) and kept, up to :data:`_TERM_CACHE` of them."""
        cache, shape = self._term_cache, (len(self.x_sim) - 1,)
        out = np.empty((shape[0], len(terms)))
        values = None
        for c, t in enumerate(terms):
            v = cache.get(t)
            if v is None:
                values = self._values(self.x_sim[:-1]) if values is None else values
                v = np.broadcast_to(Term(t).evaluate(values), shape)
                if len(cache) >= _TERM_CACHE:
                    cache.pop(next(iter(cache)))
                cache[t] = v
            out[:, c] = v
        return out

    def _base_sensitivities(self, start: np.ndarray, coefficients: bool = True) -> np.ndarray:
        model, n = self.model, len(self.model.states)
        cols: list[tuple[int, str]] = []
        for row in self.roles.dynamic_rows if coefficients else ():
            i = model.states.index(row)
            cols += [(i, t) for k, t in enumerate(model.terms) if model.coef[i, k] != 0.0]
        self.base_columns, self.x0 = cols, start
        n_seg, nc = len(self.bounds), len(cols)
        n_x0 = n * n_seg if self.estimate_x0 else 0  # each record's initial state is estimated too, or held
        values = np.zeros((len(self.x_sim) - 1, nc + n_x0))
        if cols:
            values[:, :nc] = self._term_values([t for _, t in cols])
        rows = [i for i, _ in cols] + [0] * n_x0
        s0 = np.zeros((n_seg, n, nc + n_x0))
        for j in range(n_seg if n_x0 else 0):  # record j's initial state moves record j only
            s0[j, :, nc + j * n:nc + (j + 1) * n] = np.eye(n)
        return self._flatten_owned(self._integrate_columns(rows, values, s0 if n_seg > 1 else s0[0]))

    # ------------------------------------------------------------------ candidates
    def _chunks(self, specs: Sequence[tuple[tuple[str, ...], tuple[str, ...]]]):
        """The (spec, row, term) columns of `specs` in groups of about :data:`_CHUNK`, a spec never split
        across two groups; each group with its flattened sensitivities."""
        group: list[tuple[int, int, str]] = []
        for k, (terms, rows) in enumerate(specs):
            cols = [(k, self.model.states.index(r), t) for r in rows for t in terms]
            if group and len(group) + len(cols) > _CHUNK:
                yield group, self._group_sensitivities(group)
                group = []
            group += cols
        if group:
            yield group, self._group_sensitivities(group)

    def _group_sensitivities(self, group: Sequence[tuple[int, int, str]]) -> np.ndarray:
        values = self._term_values([t for _, _, t in group])
        return self._flatten_owned(self._integrate_columns([i for _, i, _ in group], values))

    def candidate_sensitivities(self, specs: Sequence[tuple[tuple[str, ...], tuple[str, ...]]]) -> list[np.ndarray]:
        """For each (terms, rows) spec, the flattened sensitivities of each (row, term) coefficient."""
        out = [np.zeros((self.residual.size, 0)) for _ in specs]
        for group, sens in self._chunks(specs):
            for k, cols in _spans(group):
                out[k] = np.ascontiguousarray(sens[:, cols])
        return out

    def test_specs(self, specs: Sequence[tuple[tuple[str, ...], tuple[str, ...]]]) -> list[dict[str, Any]]:
        """``[screen.test(s) for s in screen.candidate_sensitivities(specs)]``, batched: the sensitivities of
        about :data:`_CHUNK` candidate columns are integrated and projected off the base together, and no
        candidate's columns are copied out. The same numbers to rounding."""
        out = [dict(_NO_SCORE) for _ in specs]
        for group, sens in self._chunks(specs):
            sens -= self.q_base @ (self.q_base.T @ sens)  # every column projected off the base at once
            proj_r = sens.T @ self.r_perp
            for k, cols in _spans(group):
                proj = sens[:, cols]
                out[k] = self._score(proj.T @ proj, proj_r[cols])
        return out

    def test(self, sens: np.ndarray) -> dict[str, Any]:
        """Score of candidate columns `sens` against the base: RSS drop, BIC change, p-value, size, coefficients."""
        if not np.all(np.isfinite(sens)):
            return dict(_NO_SCORE)
        proj = sens - self.q_base @ (self.q_base.T @ sens)
        return self._score(proj.T @ proj, proj.T @ self.r_perp)

    def _score(self, gram: np.ndarray, proj_r: np.ndarray) -> dict[str, Any]:
        """The score from the candidate's projected Gram matrix and its projected columns times the residual."""
        if not (np.all(np.isfinite(gram)) and np.all(np.isfinite(proj_r))):
            return dict(_NO_SCORE)
        try:
            inv = np.linalg.pinv(gram, rcond=1e-12)
        except np.linalg.LinAlgError:
            return dict(_NO_SCORE)
        coef = inv @ proj_r
        drop = float(max(proj_r @ coef, 0.0))
        q = gram.shape[0]
        rss1 = max(self.rss0 - drop, 1e-300)
        delta_bic = self.n_obs * math.log(rss1 / self.rss0) + q * math.log(self.n_obs)
        p_value = float(special.chdtrc(q, drop / self.variance))
        se = np.sqrt(np.clip(np.diag(inv) * self.variance, 0, None))
        return {"delta_bic": delta_bic, "p_value": p_value, "size": math.sqrt(drop) / max(self.scale_y, 1e-300),
                "coef": coef, "se": se, "drop": drop}


_NO_SCORE = {"delta_bic": 0.0, "p_value": 1.0, "size": 0.0, "coef": None, "se": None, "drop": 0.0}


def _spans(group: Sequence[tuple[int, int, str]]) -> list[tuple[int, slice]]:
    """Each spec of a group with the slice of its columns (they are consecutive)."""
    out: list[tuple[int, slice]] = []
    first = 0
    for c in range(1, len(group) + 1):
        if c == len(group) or group[c][0] != group[first][0]:
            out.append((group[first][0], slice(first, c)))
            first = c
    return out


def row_subsets(rows: Sequence[str]) -> list[tuple[str, ...]]:
    """Each row alone, and all of them together (an effect may act in one coupled row or in several)."""
    subsets = [(r,) for r in rows]
    if len(rows) > 1:
        subsets.append(tuple(rows))
    return subsets


def effect_specs(effect: Effect, attachment: Attachment, value: float | None,
                 screen: OutputErrorScreen) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    """The (terms, rows) alternatives of one effect at one place and nuisance value."""
    cols = effect.columns(attachment, value, screen.columns)
    if cols:
        screen.columns.update(cols)
    terms = effect.terms(attachment, value)
    return [(terms, rows) for rows in row_subsets([r for r in attachment.rows if r in screen.roles.dynamic_rows])]


def output_error_fit(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, *,
                     x0: Sequence[float] | None = None, nuisances: Sequence[Nuisance] = (), iterations: int = 15,
                     tolerance: float = 1e-7, estimate_x0: bool = True, noise: Mapping[str, float] | None = None,
                     segments: Sequence[int] | None = None, measured: Sequence[str] | None = None,
                     ) -> tuple[IdentifiedModel, np.ndarray, list[Nuisance]]:
    """Gauss-Newton output-error fit of the dynamic rows' non-zero coefficients, the initial state, and the
    placed effects' nuisance parameters (on a log scale).

    Uses the same free-run sensitivities as the screening (written by hand because it reuses them: one
    simulation and one sensitivity integration per iteration, where a generic least-squares solver would
    difference the whole simulation per parameter). A nuisance parameter's sensitivity is that of its terms'
    central difference in ``log(value)``, weighted by their coefficients. Steps are halved until the cost falls.
    The fit stops when a step buys less than `tolerance` of the cost, or when the Gauss-Newton step would
    (its predicted drop, before it is simulated).

    With ``estimate_x0=False`` the initial state stays where it starts (`x0`, else the model's ``meta["x0"]``,
    else the first sample). `noise` gives a state's noise level (its residual's scale) instead of the estimate
    from the data's second differences (:func:`noise_level`), e.g. a sensor's known resolution. `segments`
    (start indices of several records in the concatenated columns) fits all records at once, each from its
    own initial state (`x0` then holds one per record). `measured` names the states whose errors count (None:
    all; see :class:`OutputErrorScreen`).

    Returns the fitted model (its ``meta`` holds ``x0``, one initial state per record, and ``std_error``, the
    coefficients' standard errors from the final Jacobian), the standard errors as an array shaped like
    ``coef``, and the nuisances.
    """
    current, nuis = model, [replace(n, std_error=None) for n in nuisances]
    kw = {"estimate_x0": estimate_x0, "noise": noise, "segments": segments, "measured": measured}
    screen = OutputErrorScreen(current, columns, dt, x0=x0, **kw)
    cost = float(screen.residual @ screen.residual)
    jac = None  # the Jacobian at the current point, once made
    fraction = 1.0  # of the Gauss-Newton step tried first: twice the last one taken (a model that needed short
    for _ in range(iterations):  # steps needs them again, and each halving costs a simulation)
        jac = np.column_stack([screen.base, *_nuisance_columns(screen, current, nuis)])
        ties = _tie_map(screen, current, nuis, jac.shape[1])
        full = _bounded_step(jac, ties, screen.residual, nuis, screen.base.shape[1])
        if _predicted_drop(jac, full) < tolerance * cost:
            break  # converged: the step would buy less than the tolerance
        accepted = False
        for _halving in range(8):
            step = full * fraction
            trial, start, trial_nuis = _apply(current, screen, step, nuis)
            run = _free_run(trial, columns, dt, start, segments)  # a simulation only: cheap
            trial_cost = _cost(run, columns, trial, screen._scale)
            if trial_cost < cost:
                accepted = True
                break
            fraction /= 2
        if not accepted:
            break
        fraction = min(1.0, 2 * fraction)
        improvement = (cost - trial_cost) / max(cost, 1e-300)
        try:
            screen = OutputErrorScreen(trial, columns, dt, x0=start, _free_run=run, **kw)
        except DataError:  # its sensitivities overflow: stop at the last point that has them
            break
        current, cost, nuis, jac = trial, trial_cost, trial_nuis, None
        if improvement < tolerance:
            break
    if jac is None:
        jac = np.column_stack([screen.base, *_nuisance_columns(screen, current, nuis)])
    ties = _tie_map(screen, current, nuis, jac.shape[1])
    with np.errstate(over="ignore", invalid="ignore"):  # sensitivities near overflow: standard errors inf or nan
        reduced = jac @ ties
        cov = ties @ np.linalg.pinv(reduced.T @ reduced) @ ties.T * screen.variance
    first = screen.base.shape[1]
    nuis = [replace(nu, std_error=nu.value * math.sqrt(max(cov[first + j, first + j], 0.0)))
            for j, nu in enumerate(nuis)]
    se = np.zeros_like(current.coef)
    for c, (i, term) in enumerate(screen.base_columns):
        se[i, current.terms.index(term)] = math.sqrt(max(cov[c, c], 0.0))
    meta = dict(current.meta) if isinstance(current.meta, Mapping) else {}
    x0_list = screen.x0.tolist()
    meta.update(x0=x0_list if screen.x0.ndim == 2 else [x0_list],
                refinement={"method": "output_error (Gauss-Newton on free-run sensitivities)", "cost": cost,
                            "std_error": se.tolist(), "covariance": cov[:first, :first].tolist(),
                            "parameters": [[i, term] for i, term in screen.base_columns]})
    fitted = IdentifiedModel(states=current.states, inputs=current.inputs, terms=current.terms, coef=current.coef,
                             dt=current.dt, meta=meta)
    return fitted, se, nuis


def _bounded_step(jac: np.ndarray, ties: np.ndarray, residual: np.ndarray, nuis: Sequence[Nuisance],
                  first: int) -> np.ndarray:
    """The Gauss-Newton step in the full parameters, with every nuisance the step would take out of its bounds
    moved onto the bound (held there when it is already on it), and the other parameters solved again given
    that move: an active set, so that the step stays a consistent descent step rather than the free one clipped
    afterwards in one coordinate only."""
    full = ties @ _gauss_newton_step(jac @ ties, residual)
    fixed = {}
    for j, nu in enumerate(nuis):
        k = first + j
        lo, hi = nu.bounds
        move = float(np.clip(full[k], -1.0, 1.0))  # the log-step _apply takes
        if nu.value * math.exp(move) < lo:  # (then log(lo / value) > move >= -1: within _apply's clip)
            fixed[k] = 0.0 if nu.at_bound(-1.0) else math.log(lo / nu.value)
        elif nu.value * math.exp(move) > hi:
            fixed[k] = 0.0 if nu.at_bound(1.0) else math.log(hi / nu.value)
    if not fixed:
        return full
    held = list(fixed)
    moves = np.array([fixed[k] for k in held])
    rest = residual - jac[:, held] @ moves
    jac = jac.copy()
    jac[:, held] = 0.0
    full = ties @ _gauss_newton_step(jac @ ties, rest)
    full[held] = moves
    return full


def _gauss_newton_step(jac: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """The least-squares step (QR with column pivoting: rank-deficient columns get no step)."""
    return linalg.lstsq(jac, residual, lapack_driver="gelsy", check_finite=False)[0]


def _predicted_drop(jac: np.ndarray, step: np.ndarray) -> float:
    """The fall of the cost the linearised model predicts for `step`."""
    fitted = jac @ step
    return float(fitted @ fitted)


@dataclass(frozen=True)
class InitialStateFit:
    """Initial states fitted with a model's coefficients held (:func:`initial_state_fit`).

    `x0` is (n,) for one record, (records, n) for several; `residual` (samples, n) is the free-run residual
    from them, each state scaled by `sigma` (zero for a state not measured); `cost` its sum of squares.
    """

    x0: np.ndarray
    residual: np.ndarray
    cost: float
    sigma: np.ndarray


def initial_state_fit(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, *,
                      segments: Sequence[int] | None = None, noise: Mapping[str, float] | None = None,
                      sigma: np.ndarray | None = None, x0: Any = None, iterations: int = 15,
                      tolerance: float = 1e-9, measured: Sequence[str] | None = None) -> InitialStateFit:
    """Each record's initial state fitted by output error with the model's coefficients held fixed.

    How a model does on records it was not fitted to: only what the record itself decides (where it starts)
    is estimated. Gauss-Newton on the initial-state sensitivities (one step for a linear model), from `x0`
    (else the model's ``meta["x0"]`` if it has one per record, else each record's first sample). `sigma` (one
    noise level per state) scales the residual, e.g. the fitting data's; else `noise` and the levels
    estimated from these data, as in :func:`output_error_fit`; `measured` too.

    Raises DataError if the model's free run diverges from the start.
    """
    if sigma is not None:
        noise = dict(zip(model.states, np.asarray(sigma, dtype=float).tolist(), strict=True))
    kw = {"noise": noise, "segments": segments, "measured": measured, "_coefficients": False}
    screen = OutputErrorScreen(model, columns, dt, x0=x0, **kw)
    cost = float(screen.residual @ screen.residual)
    fraction = 1.0  # of the Gauss-Newton step tried first, as in output_error_fit
    for _ in range(iterations):
        full = _gauss_newton_step(screen.base, screen.residual)
        if _predicted_drop(screen.base, full) < tolerance * cost:
            break  # converged (after one step for a linear model): no simulation to find it out
        start, run, trial_cost = screen.x0, None, math.inf
        for _halving in range(8):
            start = screen.x0 + (full * fraction).reshape(screen.x0.shape)
            run = _free_run(model, columns, dt, start, segments)
            trial_cost = _cost(run, columns, model, screen._scale)
            if trial_cost < cost:
                break
            fraction /= 2
        if not trial_cost < cost:
            break
        fraction = min(1.0, 2 * fraction)
        improvement = (cost - trial_cost) / max(cost, 1e-300)
        screen = OutputErrorScreen(model, columns, dt, x0=start, _free_run=run, **kw)
        cost = trial_cost
        if improvement < tolerance:
            break
    return InitialStateFit(screen.x0, screen.residual.reshape(-1, len(model.states)), cost, screen.sigma)
