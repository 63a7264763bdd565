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
time-varying rest of the Jacobian held over each sample.

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
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import linalg, stats

from ..errors import DataError
from ..identify.model import IdentifiedModel
from ..identify.terms import Term
from .effects import Attachment, Effect, Roles

__all__ = ["Nuisance", "OutputErrorScreen", "output_error_fit"]

#: Columns of sensitivities integrated in one pass (memory: samples x states x this x 8 bytes).
_CHUNK = 96


def noise_level(y: np.ndarray) -> float:
    """Standard deviation of white measurement noise on a smooth signal, from its second differences (MAD)."""
    d2 = np.diff(np.asarray(y, dtype=float), 2)
    if d2.size == 0:
        return 1.0
    mad = float(np.median(np.abs(d2 - np.median(d2)))) * 1.4826
    sigma = mad / math.sqrt(6.0)
    return sigma if sigma > 0 else max(float(np.std(y)) * 1e-6, 1e-300)


class OutputErrorScreen:
    """Free-run residual of a model on data, its sensitivities, and the score of candidate terms."""

    def __init__(self, model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float,
                 x0: Sequence[float] | None = None, *, estimate_x0: bool = True,
                 noise: Mapping[str, float] | None = None) -> None:
        self.model, self.columns, self.dt = model, dict(columns), float(dt)
        self.estimate_x0 = bool(estimate_x0)
        self.roles = Roles.of(model)
        states = model.states
        X = np.column_stack([np.asarray(columns[s], dtype=float) for s in states])
        U = np.column_stack([np.asarray(columns[u], dtype=float) for u in model.inputs]) if model.inputs \
            else np.zeros((len(X), 0))
        meta_x0 = model.meta.get("x0") if isinstance(model.meta, Mapping) else None
        start = np.asarray(x0 if x0 is not None else (meta_x0[0] if meta_x0 else X[0]), dtype=float)
        sim = model.simulate(start, U[:-1], dt=dt)
        if not sim.ok:
            raise DataError(f"the model's free run diverges on these data ({sim.message}); diagnose a stable model")
        self.x_sim, self.U = sim.states, U
        noise = noise or {}
        self.sigma = np.array([float(noise[s]) if s in noise else noise_level(X[:, i]) for i, s in enumerate(states)])
        self.residual = ((X - self.x_sim) / self.sigma).reshape(-1)
        self.scale_y = float(np.linalg.norm(((X - X.mean(axis=0)) / self.sigma).reshape(-1)))
        self._prepare_dynamics()
        self.base = self._base_sensitivities(start)
        if not np.all(np.isfinite(self.base)):
            raise DataError("the free-run sensitivities overflow: the model is too unstable on these data")
        self.q_base, _ = np.linalg.qr(self.base)
        self.r_perp = self.residual - self.q_base @ (self.q_base.T @ self.residual)
        self.rss0 = float(self.r_perp @ self.r_perp)
        dof = max(self.residual.size - self.base.shape[1], 1)
        self.variance = self.rss0 / dof
        self.n_obs = self.residual.size

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
        jac = np.empty((len(x), n, n))
        scale = np.maximum(np.abs(x).max(axis=0), 1e-12)
        for j in range(n):
            h = 1e-6 * scale[j]
            step = np.zeros(n)
            step[j] = h
            jac[:, :, j] = (model.predict(x + step, u) - model.predict(x - step, u)) / (2 * h)
        self.delta_j = jac - a0  # the time-varying rest of the Jacobian (zero for a linear model)
        self.nonlinear = bool(np.any(np.abs(self.delta_j) > 1e-9 * max(1.0, float(np.abs(a0).max()))))
        big = np.zeros((2 * n, 2 * n))
        big[:n, :n], big[:n, n:] = a0 * self.dt, np.eye(n) * self.dt
        phi = linalg.expm(big)
        self.ad, self.gamma = phi[:n, :n], phi[:n, n:]

    def _integrate(self, forcing: np.ndarray, s0: np.ndarray | None = None) -> np.ndarray:
        """Sensitivities for forcing (samples-1, states, m) from s0 (states, m): (samples, states, m)."""
        steps, n, m = forcing.shape
        out = np.empty((steps + 1, n, m))
        s = np.zeros((n, m)) if s0 is None else s0.copy()
        out[0] = s
        ad, gamma, dj = self.ad, self.gamma, self.delta_j
        if self.nonlinear:
            for k in range(steps):
                s = ad @ s + gamma @ (dj[k] @ s + forcing[k])
                out[k + 1] = s
        else:
            for k in range(steps):
                s = ad @ s + gamma @ forcing[k]
                out[k + 1] = s
        return out

    def _flatten(self, sens: np.ndarray) -> np.ndarray:
        return (sens / self.sigma[None, :, None]).reshape(-1, sens.shape[2])

    def _term_values(self, terms: Sequence[str]) -> np.ndarray:
        """Each term evaluated along the free run (inputs and extra columns from the data), (samples-1, terms)."""
        values = self._values(self.x_sim[:-1])
        shape = (len(self.x_sim) - 1,)
        return np.column_stack([np.broadcast_to(Term(t).evaluate(values), shape) for t in terms])

    def _base_sensitivities(self, start: np.ndarray) -> np.ndarray:
        model, n = self.model, len(self.model.states)
        cols: list[tuple[int, str]] = []
        for row in self.roles.dynamic_rows:
            i = model.states.index(row)
            cols += [(i, t) for k, t in enumerate(model.terms) if model.coef[i, k] != 0.0]
        self.base_columns, self.x0 = cols, start
        steps = len(self.x_sim) - 1
        n_x0 = n if self.estimate_x0 else 0  # the initial state is estimated too, or held where it is
        forcing = np.zeros((steps, n, len(cols) + n_x0))
        if cols:
            values = self._term_values([t for _, t in cols])
            for c, (i, _) in enumerate(cols):
                forcing[:, i, c] = values[:, c]
        s0 = np.zeros((n, len(cols) + n_x0))
        s0[:, len(cols):] = np.eye(n)[:, :n_x0]
        return self._flatten(self._integrate(forcing, s0))

    # ------------------------------------------------------------------ candidates
    def candidate_sensitivities(self, specs: Sequence[tuple[tuple[str, ...], tuple[str, ...]]]) -> list[np.ndarray]:
        """For each (terms, rows) spec, the flattened sensitivities of each (row, term) coefficient."""
        n = len(self.model.states)
        flat: list[tuple[int, int, str]] = []
        for k, (terms, rows) in enumerate(specs):
            flat += [(k, self.model.states.index(r), t) for r in rows for t in terms]
        out: list[list[np.ndarray]] = [[] for _ in specs]
        steps = len(self.x_sim) - 1
        for first in range(0, len(flat), _CHUNK):
            chunk = flat[first:first + _CHUNK]
            forcing = np.zeros((steps, n, len(chunk)))
            values = self._term_values([t for _, _, t in chunk])
            for c, (_, i, _) in enumerate(chunk):
                forcing[:, i, c] = values[:, c]
            sens = self._flatten(self._integrate(forcing))
            for c, (k, _, _) in enumerate(chunk):
                out[k].append(sens[:, c])
        return [np.column_stack(cols) for cols in out]

    def test(self, sens: np.ndarray) -> dict[str, Any]:
        """Score of candidate columns `sens` against the base: RSS drop, BIC change, p-value, size, coefficients."""
        if not np.all(np.isfinite(sens)):
            return {"delta_bic": 0.0, "p_value": 1.0, "size": 0.0, "coef": None, "se": None, "drop": 0.0}
        proj = sens - self.q_base @ (self.q_base.T @ sens)
        gram = proj.T @ proj
        try:
            inv = np.linalg.pinv(gram, rcond=1e-12)
        except np.linalg.LinAlgError:
            return {"delta_bic": 0.0, "p_value": 1.0, "size": 0.0, "coef": None, "se": None, "drop": 0.0}
        coef = inv @ (proj.T @ self.r_perp)
        drop = float(max(self.r_perp @ (proj @ coef), 0.0))
        q = sens.shape[1]
        rss1 = max(self.rss0 - drop, 1e-300)
        delta_bic = self.n_obs * math.log(rss1 / self.rss0) + q * math.log(self.n_obs)
        p_value = float(stats.chi2.sf(drop / self.variance, q))
        se = np.sqrt(np.clip(np.diag(inv) * self.variance, 0, None))
        return {"delta_bic": delta_bic, "p_value": p_value, "size": math.sqrt(drop) / max(self.scale_y, 1e-300),
                "coef": coef, "se": se, "drop": drop}


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


@dataclass
class Nuisance:
    """A placed effect's nuisance parameter that the output-error fit estimates with the coefficients.

    `make_terms(value)` writes the effect's terms for a value; the model holds ``make_terms(value)``.
    """

    make_terms: Callable[[float], tuple[str, ...]]
    value: float
    std_error: float | None = None  # set by the fit (first order, from the log-scale sensitivity)

    @property
    def terms(self) -> tuple[str, ...]:
        return self.make_terms(self.value)


def output_error_fit(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, *,
                     x0: Sequence[float] | None = None, nuisances: Sequence[Nuisance] = (), iterations: int = 15,
                     tolerance: float = 1e-7, estimate_x0: bool = True, noise: Mapping[str, float] | None = None,
                     ) -> tuple[IdentifiedModel, np.ndarray, list[Nuisance]]:
    """Gauss-Newton output-error fit of the dynamic rows' non-zero coefficients, the initial state, and the
    placed effects' nuisance parameters (on a log scale).

    Uses the same free-run sensitivities as the screening (written by hand because it reuses them: one
    simulation and one sensitivity integration per iteration, where a generic least-squares solver would
    difference the whole simulation per parameter). A nuisance parameter's sensitivity is that of its terms'
    central difference in ``log(value)``, weighted by their coefficients. Steps are halved until the cost falls.

    With ``estimate_x0=False`` the initial state stays where it starts (`x0`, else the model's ``meta["x0"]``,
    else the first sample). `noise` gives a state's noise level (its residual's scale) instead of the estimate
    from the data's second differences (:func:`noise_level`), e.g. a sensor's known resolution.

    Returns the fitted model (its ``meta`` holds ``x0`` and ``std_error``, the coefficients' standard errors
    from the final Jacobian), the standard errors as an array shaped like ``coef``, and the nuisances.
    """
    current, nuis = model, [Nuisance(n.make_terms, n.value) for n in nuisances]
    screen = OutputErrorScreen(current, columns, dt, x0=x0, estimate_x0=estimate_x0, noise=noise)
    cost = float(screen.residual @ screen.residual)
    for _ in range(iterations):
        jac = np.column_stack([screen.base, *_nuisance_columns(screen, current, nuis)])
        step, *_ = np.linalg.lstsq(jac, screen.residual, rcond=None)
        accepted = False
        for _halving in range(8):
            trial, start, trial_nuis = _apply(current, screen, step, nuis)
            trial_cost = free_run_cost(trial, columns, dt, start, screen.sigma)  # a simulation only: cheap
            if trial_cost < cost:
                accepted = True
                break
            step = step / 2
        if not accepted:
            break
        improvement = (cost - trial_cost) / max(cost, 1e-300)
        try:
            screen = OutputErrorScreen(trial, columns, dt, x0=start, estimate_x0=estimate_x0, noise=noise)
        except DataError:  # its sensitivities overflow: stop at the last point that has them
            break
        current, cost, nuis = trial, trial_cost, trial_nuis
        if improvement < tolerance:
            break
    jac = np.column_stack([screen.base, *_nuisance_columns(screen, current, nuis)])
    cov = np.linalg.pinv(jac.T @ jac) * screen.variance
    first = screen.base.shape[1]
    nuis = [Nuisance(nu.make_terms, nu.value, nu.value * math.sqrt(max(cov[first + j, first + j], 0.0)))
            for j, nu in enumerate(nuis)]
    se = np.zeros_like(current.coef)
    for c, (i, term) in enumerate(screen.base_columns):
        se[i, current.terms.index(term)] = math.sqrt(max(cov[c, c], 0.0))
    meta = dict(current.meta) if isinstance(current.meta, Mapping) else {}
    meta.update(x0=[screen.x0.tolist()], refinement={"method": "output_error (Gauss-Newton on free-run "
                                                              "sensitivities)", "cost": cost,
                                                     "std_error": se.tolist(),
                                                     "covariance": cov[:first, :first].tolist(),
                                                     "parameters": [[i, term] for i, term in screen.base_columns]})
    fitted = IdentifiedModel(states=current.states, inputs=current.inputs, terms=current.terms, coef=current.coef,
                             dt=current.dt, meta=meta)
    return fitted, se, nuis


def free_run_residual(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, x0: Sequence[float],
                      sigma: np.ndarray) -> np.ndarray | None:
    """Free-run residual of `model` from `x0`, each state scaled by its noise level (None if it diverges)."""
    X = np.column_stack([np.asarray(columns[s], dtype=float) for s in model.states])
    U = np.column_stack([np.asarray(columns[u], dtype=float) for u in model.inputs]) if model.inputs \
        else np.zeros((len(X), 0))
    sim = model.simulate(np.asarray(x0, dtype=float), U[:-1], dt=dt)
    return (X - sim.states) / sigma if sim.ok else None


def free_run_cost(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, x0: np.ndarray,
          sigma: np.ndarray) -> float:
    """Scaled free-run cost of `model` from `x0` (inf if it diverges)."""
    r = free_run_residual(model, columns, dt, x0, sigma)
    return math.inf if r is None else float(np.sum(r * r))


def correlation_factor(residual: np.ndarray, lags: int = 50) -> float:
    """How many samples of a residual carry one sample's worth of information: its long-run variance over its
    variance, ``1 + 2 sum_k (1 - k/(L+1)) rho_k`` (Bartlett weights, L lags), averaged over the columns, at
    least 1.

    Tests that treat a coloured residual as white overstate their evidence by this factor: a model that
    leaves a slow, structured error (an effect the catalogue lacks) makes chance correlations look
    significant. Dividing the sample count by it keeps them honest; after a right effect the residual is
    white and the factor is about 1.
    """
    r = np.atleast_2d(np.asarray(residual, dtype=float).T).T
    n = r.shape[0]
    lags = max(1, min(lags, n // 20))
    weights = 1.0 - np.arange(1, lags + 1) / (lags + 1)
    factors = []
    for col in r.T:
        c = col - col.mean()
        var = float(c @ c)
        if var <= 0.0:
            continue
        rho = np.array([float(c[k:] @ c[:-k]) / var for k in range(1, lags + 1)])
        factors.append(1.0 + 2.0 * float(weights @ rho))
    return max(1.0, float(np.mean(factors))) if factors else 1.0


def _nuisance_columns(screen: OutputErrorScreen, model: IdentifiedModel, nuis: Sequence[Nuisance]) -> list:
    """Sensitivity of the free run to log(value) of each nuisance parameter."""
    out = []
    h = 0.02
    n = len(model.states)
    steps = len(screen.x_sim) - 1
    for nu in nuis:
        present = nu.terms
        up, down = nu.make_terms(nu.value * math.exp(h)), nu.make_terms(nu.value * math.exp(-h))
        forcing = np.zeros((steps, n, 1))
        f_up, f_down = screen._term_values(up), screen._term_values(down)
        for t_i, term in enumerate(present):
            if term not in model.terms:
                continue
            k = model.terms.index(term)
            for i in range(n):
                if model.coef[i, k] != 0.0:
                    forcing[:, i, 0] += model.coef[i, k] * (f_up[:, t_i] - f_down[:, t_i]) / (2 * h)
        out.append(screen._flatten(screen._integrate(forcing))[:, 0])
    return out


def _apply(model: IdentifiedModel, screen: OutputErrorScreen, step: np.ndarray,
           nuis: Sequence[Nuisance]) -> tuple[IdentifiedModel, np.ndarray, list[Nuisance]]:
    coef = model.coef.copy()
    nb = len(screen.base_columns)
    for c, (i, term) in enumerate(screen.base_columns):
        coef[i, model.terms.index(term)] += step[c]
    n = len(model.states) if screen.estimate_x0 else 0
    start = screen.x0 + step[nb:nb + n] if n else screen.x0
    terms = list(model.terms)
    new_nuis = []
    for j, nu in enumerate(nuis):
        value = nu.value * math.exp(float(np.clip(step[nb + n + j], -1.0, 1.0)))
        for old, new in zip(nu.terms, nu.make_terms(value), strict=True):
            if old in terms:
                terms[terms.index(old)] = new
        new_nuis.append(Nuisance(nu.make_terms, value))
    return IdentifiedModel(states=model.states, inputs=model.inputs, terms=tuple(terms), coef=coef,
                           dt=model.dt), start, new_nuis
