"""The output-error steps of a :class:`~cosim.identify.sindyc.SINDYc` fit (``refine="output_error"``).

:func:`_refine` refines the non-zero coefficients of the equation-error model, and each record's initial
state, by :func:`~cosim.identify.output_error.refine_output_error` (step 5 of the :mod:`cosim.identify.sindyc`
docstring). With ``threshold="auto"`` it then chooses the sparsity on the output error, since equation error
cannot judge small terms on noisy data: :func:`_prune` removes coefficients by backward elimination with
Wald tests while the output error's BIC drops (step 3 of that docstring).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .model import IdentifiedModel

if TYPE_CHECKING:
    from .output_error import OutputErrorFit


def _refine(model: IdentifiedModel, runs: Sequence[tuple[np.ndarray, np.ndarray]], dt: float,
            kin: Mapping[str, str], coef_scale: np.ndarray, meta: dict[str, Any],
            known_x0: list[np.ndarray] | None, *, refine_options: Mapping[str, Any], refine_initial_state: bool,
            prune: bool) -> IdentifiedModel:
    """The model refined by output error (then pruned if `prune`); records the refinement in `meta`."""
    from .output_error import refine_output_error

    support = model.coef != 0.0
    for pos in kin:
        support[model.states.index(pos)] = False
    options = {"prior": 0.1, "continuation": True, "max_nfev": 60, **refine_options}
    fit = refine_output_error(model, [(x, u[:-1]) for x, u in runs], dt=dt, support=support,
                              estimate_x0=refine_initial_state and known_x0 is None, x0=known_x0,
                              coef_scale=coef_scale, **options)
    meta["refinement"] = {"method": "output_error", "status": fit.status, "cost": fit.cost,
                          "cost_start": fit.cost_start, "stages": fit.stages, "options": options,
                          "refined_coefficients": int(support.sum()),
                          "std_error": fit.std_error.tolist() if fit.std_error is not None else None}
    if prune:
        fit, support = _prune(model, runs, dt, fit, support, known_x0, coef_scale, meta,
                              refine_options=refine_options, refine_initial_state=refine_initial_state)
        meta["refinement"].update(status=fit.status, cost=fit.cost, refined_coefficients=int(support.sum()),
                                  std_error=fit.std_error.tolist() if fit.std_error is not None else None)
    meta["x0"] = [v.tolist() for v in fit.x0]
    meta["seconds"]["refinement"] = fit.seconds
    return IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=fit.coef, dt=dt)


def _prune(model: IdentifiedModel, runs: Sequence[tuple[np.ndarray, np.ndarray]], dt: float,
           fit: OutputErrorFit, support: np.ndarray, known_x0: list[np.ndarray] | None, coef_scale: np.ndarray,
           meta: dict[str, Any], *, refine_options: Mapping[str, Any],
           refine_initial_state: bool) -> tuple[OutputErrorFit, np.ndarray]:
    """threshold="auto" with refinement: backward elimination on the output-error fit (Wald tests, BIC).

    The least significant refined coefficient (smallest ``t = |coef| / standard error``, from the
    covariance of the output-error fit) is removed while ``t < sqrt(log(n))`` (``n`` the number of
    residuals: removing it lowers the output error's BIC, to second order). One at a time, the others and
    their covariance updated after each removal as the constrained least-squares solution
    (``theta -= C[:, j] theta_j / C[j, j]``, ``C -= C[:, j] C[j, :] / C[j, j]``), because collinear terms
    are each insignificant while jointly needed. The reduced model is refined again and kept if the
    output error's BIC ``n*log(cost) + k*log(n)`` went down; otherwise only the single least significant
    coefficient is tried. Rounds repeat on the new fit until nothing is removed.
    """
    from .output_error import refine_output_error

    n_obs = sum(len(x) for x, _ in runs) * len(model.states)
    limit = math.sqrt(math.log(n_obs))
    removed: list[dict[str, Any]] = []
    runs_oe = [(x, u[:-1]) for x, u in runs]
    seconds = fit.seconds

    def bic(f, sup: np.ndarray) -> float:
        return n_obs * math.log(max(f.cost, 1e-300)) + float(sup.sum()) * math.log(n_obs)

    for _ in range(int(support.sum())):
        if fit.covariance is None:
            break
        index = [tuple(ij) for ij in np.argwhere(support)]
        theta = np.array([fit.coef[ij] for ij in index])
        cov = np.array(fit.covariance, dtype=float)
        alive = list(range(len(index)))
        proposal: list[tuple[int, float, np.ndarray]] = []  # (index, t, theta after removing it)
        while len(alive) > 1:
            var = np.array([cov[j, j] for j in alive])
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(var > 0, np.abs(theta[alive]) / np.sqrt(var), np.inf)
            pos = int(np.argmin(t))
            if not t[pos] < limit:
                break
            j = alive.pop(pos)
            theta = theta - cov[:, j] * theta[j] / cov[j, j]
            cov = cov - np.outer(cov[:, j], cov[j, :]) / cov[j, j]
            theta[j] = 0.0
            proposal.append((j, float(t[pos]), theta.copy()))
        if not proposal:
            break
        accepted = None
        for step in (proposal, proposal[:1]):  # all Wald removals; failing that, the least significant one
            coef = fit.coef.copy()
            new_support = support.copy()
            for j, ij in enumerate(index):
                coef[ij] = step[-1][2][j] if len(step) == len(proposal) else fit.coef[ij]
            for j, _, _ in step:
                new_support[index[j]] = False
                coef[index[j]] = 0.0
            start = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=coef,
                                    dt=dt)
            trial = refine_output_error(start, runs_oe, dt=dt, support=new_support,
                                        estimate_x0=refine_initial_state and known_x0 is None,
                                        x0=known_x0 if known_x0 is not None else fit.x0,
                                        coef_scale=coef_scale, continuation=False,
                                        max_nfev=int(refine_options.get("max_nfev", 60)))
            seconds += trial.seconds
            if trial.status == "ok" and bic(trial, new_support) <= bic(fit, support):
                accepted = (trial, new_support, step)
                break
            if len(proposal) == 1:
                break
        if accepted is None:
            break
        fit, support, step = accepted
        for j, t_value, _ in step:
            i, k = index[j]
            removed.append({"state": model.states[i], "term": model.terms[k], "t": t_value})
    meta["threshold"] = {"method": "auto with refinement: dense equation-error fit, refined by output error, "
                                   "then backward elimination (Wald) of coefficients with |coef|/std_error "
                                   "below sqrt(log(n)), n the number of residuals, kept when the output "
                                   "error's BIC drops",
                         "value": limit, "residuals": n_obs, "removed": removed,
                         "equation_error": meta["threshold"]}
    object.__setattr__(fit, "seconds", seconds)
    return fit, support
