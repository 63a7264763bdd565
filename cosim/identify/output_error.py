"""Output-error refinement of an identified model: minimise its free-run simulation error on the data.

Equation-error fitting (regressing derivatives, or integrals, on the library evaluated on *measured* states)
is biased when the states are noisy: the noise sits in the regressors (errors in variables). Output error
fits the coefficients so that the model, simulated from an initial state with the measured (noise-free)
inputs, follows the measured states; with white measurement noise that is the maximum-likelihood estimate
and the bias goes away. :func:`refine_output_error` does it for an :class:`~cosim.identify.model.IdentifiedModel`,
keeping its sparsity pattern (only non-zero coefficients move) and, optionally, estimating the initial state
of every record.

How
---
* Residuals: ``(x_sim[k] - x_meas[k]) / s_i`` for every sample and state, ``s_i`` the standard deviation of
  measured state i, so that states of different units weigh alike. Solved with
  :func:`scipy.optimize.least_squares` (Levenberg-Marquardt), parameters scaled by their starting magnitude.
* Linear models (terms ``1``, states, inputs) are simulated with the exact zero-order-hold discretisation, the
  recursion ``x[k+1] = Ad x[k] + d[k]`` evaluated as a scan in blocks (about ``2 sqrt(n)`` vectorised calls),
  and the Jacobian is exact: the derivative of ``expm`` (block-triangular form) gives ``dAd, dBd, dcd`` per
  coefficient (a vectorised Taylor ``expm`` of the stack), and the sensitivities obey the same recursion,
  scanned together, computed only when the optimiser asks for the Jacobian. 20 parameters on 10^4
  samples cost a few milliseconds per Jacobian.
* Nonlinear models are simulated with RK4 (one step per sample, inputs held), all finite-difference
  perturbations of the parameters at once (a Python loop over samples, NumPy over parameters: seconds).
* Horizon continuation: the fit starts on a short head of the records (5 periods of the fastest mode of the
  starting model), then doubles the horizon until it covers the whole records. A lightly damped mode makes
  the output-error cost on a long horizon full of local minima (a 1 % frequency error is a phase error of
  several radians after a few seconds); on a short horizon it is nearly quadratic, and each longer stage
  starts inside the basin of the next. While the horizon is shorter than the data, a weak prior
  (``prior`` x samples x states x squared change of the *scaled* coefficients) keeps the directions the head
  does not determine (slow modes, small input effects) at their starting values instead of letting them
  drift to fit noise; the last stage, on all data, has no prior: the result is the plain output-error fit.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> true = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-2.0, 3.0]]))
>>> u = np.sign(np.sin(np.arange(2000) * 0.01))[:, None]
>>> x = true.simulate([1.0], u, dt=0.01).states
>>> start = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.5, 2.5]]))
>>> fit = refine_output_error(start, [(x, u)], dt=0.01)
>>> np.round(fit.coef, 6).tolist(), fit.status
([[-2.0, 3.0]], 'ok')
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from ..errors import DataError, InvalidSettingError
from ._linear_run import _expm_batch, _scan, simulate_linear_batch  # (simulate_linear_batch: public here)
from ._stability import StabilityPenalty
from .model import DIVERGENCE_LIMIT, IdentifiedModel
from .terms import FUNCTIONS, Term

__all__ = ["refine_output_error", "OutputErrorFit", "simulate_linear_batch"]

_BAD_RESIDUAL = 1e6  # residual given to a simulation that diverges: the optimiser steps back


@dataclass(frozen=True, eq=False)
class OutputErrorFit:
    """Result of :func:`refine_output_error`.

    Attributes
    ----------
    coef : ndarray, shape (n_states, n_terms)
        Refined coefficients (zero where the starting model had zeros).
    x0 : list of ndarray
        Initial state of each record (estimated, or the measured first sample).
    cost : float
        Mean squared scaled residual on all data (``mean(((x_sim - x)/s)^2)``).
    cost_start : float
        The same for the starting model (with the measured first samples as initial states).
    stages : list of dict
        Horizon (samples), cost and function evaluations of each continuation stage.
    std_error : ndarray, shape (n_states, n_terms)
        Standard error of each refined coefficient from the final Jacobian (0 where not refined).
    covariance : ndarray, shape (n_refined, n_refined)
        Covariance of the refined coefficients, in the row-major order of the support (the initial states
        marginalised out), or None.
    status : str
        ``"ok"``, or ``"not_improved"`` when the refinement did not lower the cost (the starting model is
        returned then).
    seconds : float
        Wall time.
    """

    coef: np.ndarray
    x0: list
    cost: float
    cost_start: float
    stages: list = field(default_factory=list)
    std_error: np.ndarray | None = None
    covariance: np.ndarray | None = None
    status: str = "ok"
    seconds: float = 0.0




# ---------------------------------------------------------------------------------------------------------
# problem set-up


class _Problem:
    """Parameters (coefficients on the support, then one initial state per record) and residuals."""

    def __init__(self, model: IdentifiedModel, runs: Sequence[tuple[np.ndarray, np.ndarray]], dt: float,
                 support: np.ndarray, estimate_x0: bool, x0: Sequence[np.ndarray] | None,
                 coef_scale: np.ndarray | None, measured_states: Sequence[bool] | None = None):
        self.model, self.dt = model, dt
        self.n_x, self.n_u = len(model.states), len(model.inputs)
        self.runs = [(np.asarray(x, dtype=float), np.asarray(u, dtype=float).reshape(len(x) - 1, self.n_u))
                     for x, u in runs]
        self.support = support
        self.index = [tuple(ij) for ij in np.argwhere(support)]
        self.n_coef = len(self.index)
        self.estimate_x0 = estimate_x0
        measured = np.vstack([x for x, _ in self.runs])
        spread = measured.std(axis=0)
        self.scale = np.where(spread > 0, spread, np.maximum(np.abs(measured).max(axis=0), 1.0))
        # what divides a state's error: its scale, or infinity for a state that is not a measurement (a velocity
        # derived from a measured position by a smoothing differentiator: its lag and smoothing are not the
        # plant's), whose entries of the residual and the Jacobian are then zero
        self.weight = (np.ones(self.n_x) if measured_states is None
                       else np.asarray(measured_states, dtype=bool).astype(float))
        self.divisor = np.where(self.weight > 0, self.scale, np.inf)  # (x / scale: the same bits as before)
        #: The share of the residual's entries that are measurements (the others are held at zero).
        self.share = float(self.weight.sum()) / self.n_x
        self.x0_start = [np.asarray(v, dtype=float) for v in x0] if x0 is not None else \
            [x[0].copy() for x, _ in self.runs]
        self.coef0 = model.coef.copy()
        theta = [self.coef0[self.support]]
        if estimate_x0:
            theta += self.x0_start
        self.theta0 = np.concatenate(theta)
        c0 = np.abs(self.coef0[self.support])
        typical = np.where(c0 > 0, c0, 1.0)
        self.x_scale = np.concatenate([typical] + ([self.scale] * len(self.runs) if estimate_x0 else []))
        self.prior_weight = (np.ones(self.n_coef) if coef_scale is None
                             else np.asarray(coef_scale, dtype=float)[self.support])
        self.linear = model.is_linear and all(
            model.terms[k] in {"1", *model.states, *model.inputs} for _, k in self.index)
        if self.linear:
            self.columns = self._augmented_columns()
        else:
            self._theta_fn = _batched_library(model)

    # -- parameters
    def split(self, theta: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        coef = self.coef0.copy()
        coef[self.support] = theta[:self.n_coef]
        if self.estimate_x0:
            x0 = [theta[self.n_coef + r * self.n_x:self.n_coef + (r + 1) * self.n_x] for r in range(len(self.runs))]
        else:
            x0 = self.x0_start
        return coef, x0

    def _augmented_columns(self) -> np.ndarray:
        """Column of each term in ``[A | B | c]`` (size n_x + n_u + 1)."""
        cols = []
        for term in self.model.terms:
            if term == "1":
                cols.append(self.n_x + self.n_u)
            elif term in self.model.states:
                cols.append(self.model.states.index(term))
            elif term in self.model.inputs:
                cols.append(self.n_x + self.model.inputs.index(term))
            else:
                cols.append(-1)
        return np.array(cols)

    def _augmented(self, coef: np.ndarray) -> np.ndarray:
        q = self.n_x + self.n_u + 1
        m = np.zeros((q, q))
        for k, col in enumerate(self.columns):
            if col >= 0:
                m[:self.n_x, col] += coef[:, k]
        return m

    # -- residuals and Jacobian, linear models (exact sensitivities)
    def linear_residuals(self, theta: np.ndarray, horizon: int, with_jac: bool):
        coef, x0s = self.split(theta)
        n, nu, q = self.n_x, self.n_u, self.n_x + self.n_u + 1
        p = self.n_coef if with_jac else 0
        big = np.zeros((p + 1, 2 * q, 2 * q))
        m = self._augmented(coef) * self.dt
        big[:, :q, :q] = m
        big[:, q:, q:] = m
        for j, (i, k) in enumerate(self.index[:p]):
            big[j + 1, i, q + self.columns[k]] = self.dt
        with np.errstate(over="ignore", invalid="ignore"):
            e = _expm_batch(big) if np.all(np.isfinite(big)) else np.full_like(big, np.nan)
        phi = e[0, :q, :q]
        ad, bd, cd = phi[:n, :n], phi[:n, n:n + nu], phi[:n, -1]
        res, jacs = [], []
        n_runs = len(self.runs)
        for r, ((x, u), x0) in enumerate(zip(self.runs, x0s, strict=True)):
            h = min(horizon, len(x) - 1)
            xs = simulate_linear_batch(ad, bd, cd, x0, u[:h])
            res.append(((xs - x[:h + 1]) / self.divisor).ravel())
            if with_jac:
                d = e[1:, :q, q:]
                n_theta = p + (n * n_runs if self.estimate_x0 else 0)
                s = np.zeros((h + 1, n_theta, n))
                s[1:, :p] = (np.tensordot(xs[:-1], d[:, :n, :n], axes=([1], [2]))  # (BLAS, not einsum's loop)
                             + np.tensordot(u[:h], d[:, :n, n:n + nu], axes=([1], [2])) + d[None, :, :n, -1])
                if self.estimate_x0:
                    s[0, p + r * n:p + (r + 1) * n] = np.eye(n)
                s = _scan(ad, s)
                jacs.append((s / self.divisor).transpose(0, 2, 1).reshape(-1, n_theta))
        return res, jacs

    # -- residuals and Jacobian, nonlinear models (exact sensitivities by CasADi, :mod:`._sensitivity`)
    def nonlinear_sensitivities(self, theta: np.ndarray, horizon: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Residuals and their Jacobian per record, as :meth:`linear_residuals` gives them (a diverging run:
        residuals and Jacobian of NaN, which the solver's callers replace)."""
        from ._sensitivity import free_run_sensitivities

        coef, x0s = self.split(theta)
        n, p, n_runs = self.n_x, self.n_coef, len(self.runs)
        n_theta = p + (n * n_runs if self.estimate_x0 else 0)
        res, jacs = [], []
        for r, ((x, u), x0) in enumerate(zip(self.runs, x0s, strict=True)):
            h = min(horizon, len(x) - 1)
            run = free_run_sensitivities(self.model, coef, self.support, x0, u, self.dt, h)
            if run is None:
                res.append(np.full((h + 1) * n, np.nan))
                jacs.append(np.full(((h + 1) * n, n_theta), np.nan))
                continue
            xs, sens = run
            res.append(((xs - x[:h + 1]) / self.divisor).ravel())
            jac = np.zeros((h + 1, n, n_theta))
            jac[:, :, :p] = sens[:, :, :p]
            if self.estimate_x0:
                jac[:, :, p + r * n:p + (r + 1) * n] = sens[:, :, p:]
            jacs.append((jac / self.divisor[None, :, None]).reshape(-1, n_theta))
        return res, jacs

    # -- residuals, nonlinear models (batched RK4, finite differences: the reference the tests compare with)
    def nonlinear_residuals(self, thetas: np.ndarray, horizon: int) -> list[np.ndarray]:
        """Residuals for a batch of parameter vectors, shape (n_batch, n_residuals)."""
        batch = thetas.shape[0]
        coefs, x0s = zip(*(self.split(theta) for theta in thetas), strict=True)
        coef = np.stack(coefs)  # (b, n_x, n_terms)
        out = []
        for r, (x, u) in enumerate(self.runs):
            h = min(horizon, len(x) - 1)
            state = np.stack([x0s[b][r] for b in range(batch)])  # (b, n_x)
            traj = np.empty((h + 1, batch, self.n_x))
            traj[0] = state
            f = self._theta_fn
            dt = self.dt
            with np.errstate(all="ignore"):
                for k in range(h):
                    uk = u[k]
                    k1 = np.einsum("bij,bj->bi", coef, f(state, uk))
                    k2 = np.einsum("bij,bj->bi", coef, f(state + 0.5 * dt * k1, uk))
                    k3 = np.einsum("bij,bj->bi", coef, f(state + 0.5 * dt * k2, uk))
                    k4 = np.einsum("bij,bj->bi", coef, f(state + dt * k3, uk))
                    state = state + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
                    state = np.where(np.abs(state) < DIVERGENCE_LIMIT, state, np.nan)
                    traj[k + 1] = state
            out.append(((traj - x[:h + 1, None, :]) / self.divisor).transpose(1, 0, 2).reshape(batch, -1))
        return out


def _batched_library(model: IdentifiedModel):
    """``f(state (b, n_x), u (n_u,)) -> theta (b, n_terms)``, generated from the terms' checked expressions."""
    names = {name: f"x[:, {i}]" for i, name in enumerate(model.states)}
    names.update({name: f"u[{j}]" for j, name in enumerate(model.inputs)})
    exprs = [Term(t).to_source(names) for t in model.terms]
    source = "def theta(x, u):\n    return [" + ", ".join(exprs) + "]"
    namespace: dict[str, Any] = {f"_f_{name}": funcs[0] for name, funcs in FUNCTIONS.items()}
    exec(compile(source, "<cosim batched library>", "exec"), namespace)  # built from checked ASTs only
    raw = namespace["theta"]

    def theta(state: np.ndarray, u: np.ndarray) -> np.ndarray:
        # (filled in place: np.stack of np.broadcast_to copies took 8 % of a 4000-sample diagnosis)
        values = raw(state, u)
        out = np.empty((state.shape[0], len(values)))
        for i, v in enumerate(values):
            out[:, i] = v
        return out

    return theta


def _finite(r: np.ndarray) -> np.ndarray:
    if np.all(np.isfinite(r)):
        return r
    return np.full_like(r, _BAD_RESIDUAL)


def _first_horizon(model: IdentifiedModel, coef: np.ndarray, dt: float, n_max: int, n_params: int,
                   n_x: int) -> int:
    """Five periods (or 2*pi time constants) of the fastest mode of the starting model, in samples."""
    rate = 0.0
    if model.is_linear:
        a = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=coef).linear_matrices()[0]
        with np.errstate(all="ignore"):
            eig = np.linalg.eigvals(a)
        if np.all(np.isfinite(eig)) and eig.size:
            rate = float(np.max(np.abs(eig)))
    if rate > 0:
        head = int(5 * 2 * math.pi / rate / dt)
    else:
        head = n_max // 8
    head = max(head, 50, 4 * n_params // max(n_x, 1))
    return int(min(head, n_max))


class _Stage:
    """Residuals and Jacobian of one continuation stage: data on `horizon` samples, plus the prior rows, plus
    (with `stability`) the penalty rows of the linear part's growing modes."""

    def __init__(self, residuals, jacobian, horizon: int, weight: np.ndarray | None, anchor: np.ndarray,
                 n_coef: int, stability: StabilityPenalty | None = None):
        self.residuals, self.jacobian, self.horizon = residuals, jacobian, horizon
        self.weight, self.anchor, self.n_coef, self.stability = weight, anchor, n_coef, stability

    def fun(self, t: np.ndarray) -> np.ndarray:
        parts = [self.residuals(t, self.horizon)]
        if self.weight is not None:
            parts.append(self.weight * (t[:self.n_coef] - self.anchor))
        if self.stability is not None:
            parts.append(self.stability.rows(t)[0])
        return np.concatenate(parts)

    def jac(self, t: np.ndarray) -> np.ndarray:
        parts = [self.jacobian(t, self.horizon)]
        if self.weight is not None:
            parts.append(np.hstack([np.diag(self.weight), np.zeros((self.n_coef, t.size - self.n_coef))]))
        if self.stability is not None:
            parts.append(self.stability.rows(t)[1])
        return np.vstack(parts)


def refine_output_error(model: IdentifiedModel, runs: Sequence[tuple[np.ndarray, np.ndarray]], *, dt: float,
                        support: np.ndarray | None = None, estimate_x0: bool = True,
                        x0: Sequence[np.ndarray] | None = None, coef_scale: np.ndarray | None = None,
                        prior: float = 0.1, prior_anchor: np.ndarray | None = None, continuation: bool = True,
                        max_nfev: int = 60, fd_step: float = 1e-6, exact_jacobian: bool = True,
                        stability_limit: float | None = None, measured: Sequence[bool] | None = None
                        ) -> OutputErrorFit:
    """Refine a model's non-zero coefficients (and initial states) by minimising its free-run error.

    Parameters
    ----------
    model : IdentifiedModel
        The starting model (typically an equation-error fit).
    runs : sequence of (x, u)
        Measured records: states ``x`` of shape (n+1, n_states) at ``t0 + k*dt`` and zero-order-hold inputs
        ``u`` of shape (n, n_inputs) (row k held over step k), in the model's state and input order.
    dt : float
        Sampling step of every record.
    support : ndarray of bool, shape (n_states, n_terms), optional
        Coefficients to refine; default: the non-zero ones. The others keep their values.
    estimate_x0 : bool
        Estimate each record's initial state (recommended with noisy data: the first measured sample is as
        noisy as any other); otherwise the first measured sample (or `x0`) is used.
    x0 : sequence of ndarray, optional
        Starting initial states (default: the first measured samples).
    coef_scale : ndarray, shape (n_states, n_terms), optional
        Factor that makes each coefficient dimensionless (the identification's feature scale / target
        scale); the continuation prior acts on ``coef * coef_scale``. Default 1.
    prior : float
        Weight of the continuation prior (0 switches it off); not applied on the last, full-horizon stage.
    continuation : bool
        Grow the horizon from a short head to the full records (recommended for lightly damped models).
    max_nfev : int
        Function evaluations per stage.
    fd_step : float
        Relative finite-difference step (nonlinear models with ``exact_jacobian=False`` only).
    exact_jacobian : bool
        Nonlinear models: the free run's exact sensitivities, stepped with it by CasADi
        (:mod:`cosim.identify._sensitivity`), rather than forward differences (one more simulation per
        parameter). Linear models always have an exact Jacobian.
    stability_limit : float, optional
        Keep the linear part stable: each eigenvalue with a positive real part adds a penalty row to every
        stage (:class:`~cosim.identify._stability.StabilityPenalty`); the fit ends well inside ``Re(lambda) <=
        stability_limit`` (1/s), as MATLAB's ``ssest`` with ``EnforceStability``. None (default): unconstrained.
    measured : sequence of bool, optional
        Per state, whether it is a measurement (default: all). A state that is not (a velocity derived from a
        measured position by a smoothing differentiator) still evolves in the free run and its initial state is
        still estimated, through the measured states, but its error counts in no cost: fitting a smoothed,
        lagging derivative pulls a lightly damped model away from the plant. The costs are means over the
        measured states. Two cautions, measured on the generalisation benchmark, why cosim's own fits keep
        derived velocities in their cost: from an equation-error start, positions alone admit degenerate fits
        (on a closed-loop record, a mode so fast that the position follows the input statically), which the
        derived velocity's error rules out; and the positions-only cost is flatter, so a fit may end at points
        that differ between BLAS kernels by more than 1e-4 (docs/issue39_selection.md).

    Returns
    -------
    OutputErrorFit

    Raises
    ------
    InvalidSettingError
        Bad settings or shapes.
    DataError
        Non-finite data.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> true = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-1.0]]))
    >>> x = true.simulate([2.0], n_steps=500, dt=0.01).states
    >>> fit = refine_output_error(true, [(x, np.zeros((500, 0)))], dt=0.01)
    >>> round(float(fit.coef[0, 0]), 8), round(float(fit.x0[0][0]), 8)
    (-1.0, 2.0)
    """
    started = time.perf_counter()
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise InvalidSettingError(f"dt must be a positive number of seconds, got {dt!r}")
    if not runs:
        raise InvalidSettingError("give at least one record (x, u) to refine on")
    n_x, n_u = len(model.states), len(model.inputs)
    for x, u in runs:
        x, u = np.asarray(x), np.asarray(u)
        if x.ndim != 2 or x.shape[1] != n_x or x.shape[0] < 3:
            raise InvalidSettingError(f"each record's states must have shape (n+1, {n_x}) with n >= 2, "
                                      f"got {x.shape}")
        if u.size != (x.shape[0] - 1) * n_u:
            raise InvalidSettingError(f"each record's inputs must have shape ({x.shape[0] - 1}, {n_u}) "
                                      f"(one row per step), got {u.shape}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
            raise DataError("a record holds NaN or inf; clean the data before refining")
    support = (model.coef != 0.0) if support is None else np.asarray(support, dtype=bool)
    if support.shape != model.coef.shape:
        raise InvalidSettingError(f"support must have the shape of coef {model.coef.shape}, got {support.shape}")
    if measured is not None and (len(measured) != n_x or not any(measured)):
        raise InvalidSettingError(f"measured must give {n_x} flags, one per state, at least one true; "
                                  f"got {list(measured)}")
    problem = _Problem(model, runs, float(dt), support, bool(estimate_x0), x0, coef_scale, measured)
    share = problem.share
    n_max = max(len(x) - 1 for x, _ in problem.runs)
    n_params = problem.theta0.size

    def cost_of(theta: np.ndarray, horizon: int) -> float:
        if problem.linear:
            res = np.concatenate(problem.linear_residuals(theta, horizon, False)[0])
        else:
            res = np.concatenate([r[0] for r in problem.nonlinear_residuals(theta[None], horizon)])
        return float(np.mean(res ** 2)) / share if np.all(np.isfinite(res)) else math.inf

    start_theta = problem.theta0.copy()
    if estimate_x0:  # the starting cost is that of the starting model from the measured first samples
        start_theta[problem.n_coef:] = np.concatenate([x[0] for x, _ in problem.runs])
    cost_start = cost_of(start_theta, n_max)

    horizon = _first_horizon(model, model.coef, dt, n_max, n_params, n_x) if continuation else n_max
    theta = problem.theta0.copy()
    stages: list[dict[str, Any]] = []
    cache: dict[str, Any] = {}
    exact = bool(exact_jacobian) and not problem.linear

    def residuals(t: np.ndarray, h: int) -> np.ndarray:
        if problem.linear:  # the Jacobian only when asked for: rejected trial steps need the residuals only
            res, _ = problem.linear_residuals(t, h, False)
            return _finite(np.concatenate(res))
        if exact:  # the run with its sensitivities, kept for the Jacobian the solver asks for next
            cache["key"], (res, jac) = (t.tobytes(), h), problem.nonlinear_sensitivities(t, h)
            cache["jac"] = np.vstack(jac)
            return _finite(np.concatenate(res))
        return _finite(np.concatenate([r[0] for r in problem.nonlinear_residuals(t[None], h)]))

    def jacobian(t: np.ndarray, h: int) -> np.ndarray:
        if problem.linear or exact:
            if cache.get("key") != (t.tobytes(), h):
                cache["key"], cache["jac"] = (t.tobytes(), h), np.vstack(
                    (problem.linear_residuals(t, h, True) if problem.linear
                     else problem.nonlinear_sensitivities(t, h))[1])
            jac = cache["jac"]
            return np.where(np.isfinite(jac), jac, 0.0)
        steps = fd_step * np.maximum(np.abs(t), problem.x_scale)
        batch = np.vstack([t, t + np.diag(steps)])
        rows = np.hstack(problem.nonlinear_residuals(batch, h))
        rows = np.where(np.isfinite(rows), rows, _BAD_RESIDUAL)
        return ((rows[1:] - rows[0]) / steps[:, None]).T

    anchor = problem.theta0[:problem.n_coef] if prior_anchor is None else \
        np.asarray(prior_anchor, dtype=float)[problem.support]
    final_jac = None
    while True:
        last = horizon >= n_max
        weight = 0.0 if last else prior * (horizon + 1) * n_x * share * len(problem.runs)
        penalty = None
        if stability_limit is not None:
            r0 = residuals(theta, horizon)
            penalty = StabilityPenalty(problem, stability_limit, float(np.mean(r0 ** 2)) / share,
                                       int(round(r0.size * share)))
        stage = _Stage(residuals, jacobian, horizon, math.sqrt(weight) * problem.prior_weight if weight > 0 else None,
                       anchor, problem.n_coef, penalty)
        n_res = stage.fun(theta).size
        method = "lm" if n_res >= theta.size else "trf"
        sol = least_squares(stage.fun, theta, jac=stage.jac, method=method, x_scale=problem.x_scale, xtol=1e-10,
                            ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
        theta = sol.x
        stages.append({"horizon": int(horizon), "cost": float(2.0 * sol.cost / n_res) / share, "nfev": int(sol.nfev)})
        if last:
            final_jac = sol.jac
            break
        horizon = min(n_max, 2 * horizon)

    cost = cost_of(theta, n_max)
    coef, x0s = problem.split(theta)
    std_error = np.zeros_like(coef)
    covariance = None
    if final_jac is not None and math.isfinite(cost):
        n_res = final_jac.shape[0] * share  # the entries that are measurements
        with np.errstate(all="ignore"):
            try:
                cov = np.linalg.pinv(final_jac.T @ final_jac) * cost * n_res / max(n_res - theta.size, 1)
                covariance = cov[:problem.n_coef, :problem.n_coef]
                std_error[problem.support] = np.sqrt(np.clip(np.diag(covariance), 0, None))
            except np.linalg.LinAlgError:
                pass
    status = "ok"
    if not (cost <= cost_start) and math.isfinite(cost_start):
        status = "not_improved"
        coef, x0s, cost = model.coef.copy(), [x[0].copy() for x, _ in problem.runs], cost_start
        std_error, covariance = np.zeros_like(coef), None
    return OutputErrorFit(coef=coef, x0=[np.array(v) for v in x0s], cost=cost, cost_start=cost_start,
                          stages=stages, std_error=std_error, covariance=covariance, status=status,
                          seconds=time.perf_counter() - started)
