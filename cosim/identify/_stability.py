"""Whether an identified model is stable on the time scale of the records it was identified from.

:func:`_stability` gives the ``stable``, ``stability`` (a sentence) and, for a linear model,
``eigenvalues`` entries of ``model_.meta`` of a :class:`~cosim.identify.sindyc.SINDYc` fit. A linear model
counts as unstable when an eigenvalue's real part exceeds ``1/T`` (T the record length): a mode growing at
most e-fold over the record is marginal, since the data cannot tell it from an integrator. A nonlinear model
is judged by a free run on the longest record.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> slow = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[0.05]]))
>>> record = (np.zeros((101, 1)), np.zeros((101, 0)))   # 10 s at dt = 0.1
>>> meta = _stability(slow, [record], 0.1)   # grows e-fold in 20 s: marginal on a 10 s record
>>> meta["stable"], meta["stability"].split(" (")[0]
(True, 'marginal: largest real part of the eigenvalues 0.05 1/s')
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import linalg

from ..errors import IdentificationWarning, UnstableModelError
from .model import IdentifiedModel

#: What to try when an identified model is unstable (the end of the error's message).
#: The cost the output-error refinement gives a diverging free run (residuals of 1e6 each): the scale of the
#: stability penalty of a start whose own run overflows.
_DIVERGED_COST = 1e12
_REMEDIES = ("fix the kinematic rows (kinematics=, --kinematics), record longer or excite more, refine by output "
             "error (refine='output_error', --refine), or accept it with allow_unstable=True (--allow-unstable)")


def _unstable(model: IdentifiedModel, *, allow: bool, refined: bool) -> None:
    """Raise :class:`~cosim.errors.UnstableModelError` for an unstable model, or warn when it is allowed."""
    eig = sorted((complex(re, im) for re, im in model.meta.get("eigenvalues", [])), key=lambda z: -z.real)
    shown = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" if z.imag else f"{z.real:.4g}"
                      for z in eig if z.imag >= 0)[:160] if eig else ""
    if eig:
        what = (f"eigenvalues with the largest real parts {shown} 1/s; above {model.meta['marginal_limit']:.3g} "
                "1/s a mode grows more than e-fold over the record")
    else:
        what = model.meta.get("stability", "")
    remedies = _REMEDIES.replace("refine by output error (refine='output_error', --refine), ", "") if refined \
        else _REMEDIES
    message = f"the identified model is unstable ({what})"
    if allow:  # stacklevel: past SINDYc.fit and its BLAS wrapper, to the caller's line
        warnings.warn(f"{message}; its free-run simulation diverges", IdentificationWarning, stacklevel=4)
        return
    raise UnstableModelError(f"{message}: {remedies}", model=model, eigenvalues=eig)


def marginal_limit(runs: Sequence[tuple[np.ndarray, np.ndarray]], dt: float) -> float:
    """The fastest growth (1/s) a linear model's mode may have and count as marginal: at most e-fold over the
    longest of the records `runs` (the data cannot tell it from an integrator)."""
    return 1.0 / (max(len(x) - 1 for x, _ in runs) * dt)


def _stability(model: IdentifiedModel, runs: Sequence[tuple[np.ndarray, np.ndarray]],
               dt: float) -> dict[str, Any]:
    """The stability entries of the model's meta, judged over the longest of the records `runs`."""
    span = max(len(x) - 1 for x, _ in runs) * dt
    out: dict[str, Any] = {}
    if model.is_linear:
        a = model.linear_matrices()[0]
        eig = np.linalg.eigvals(a)
        worst = float(np.max(eig.real))
        limit = marginal_limit(runs, dt)
        out["eigenvalues"] = [[float(v.real), float(v.imag)] for v in eig]
        out["marginal_limit"] = limit
        out["stable"] = bool(worst <= limit)
        kind = "stable" if worst < 0 else "marginal" if worst <= limit else "unstable"
        out["stability"] = (f"{kind}: largest real part of the eigenvalues {worst:.6g} 1/s (marginal up to "
                            f"{limit:.3g} 1/s: at most e-fold growth over the {span:.6g} s record)")
        return out
    x, u = max(runs, key=lambda r: len(r[0]))
    sim = model.simulate(x[0], u[:-1], dt=dt)
    out["stable"] = bool(sim.ok)
    out["stability"] = ("the free run on the longest record " + ("stays in range" if sim.ok else
                        f"diverges: {sim.message}"))
    return out


def fastest_mode_hz(model: IdentifiedModel) -> float:
    """The modulus of the largest eigenvalue of the model's linear part, in Hz (0.0 for no states' terms)."""
    a = model.linear_part().linear_matrices()[0]
    return float(np.max(np.abs(np.linalg.eigvals(a)))) / (2.0 * math.pi) if a.size else 0.0


def stabilised(model: IdentifiedModel, coef: np.ndarray, movable: np.ndarray, limit: float,
               states: np.ndarray, steps: int = 20) -> np.ndarray | None:
    """`coef` of a linear `model` with its modes that grow faster than `limit` (1/s) reflected into the left
    half-plane, by steps on the `movable` coefficients that cost the least equation error on `states`: None
    when it does not get there.

    A start for the output-error refinement, not a fit: an unstable mode the data do not excite costs nothing in
    the free run, and its mirror image (the same speed, decaying) costs about as little, the way a subspace or
    prediction-error method reflects an unstable pole to enforce stability (e.g. MATLAB's ``ssest`` with
    ``EnforceStability``). The model's structure stays: kinematic rows are not movable, so the reflection is
    made by first-order eigenvalue sensitivities (``d lambda = w^H dA v``) on the dynamic rows' state
    coefficients: the change that moves each unstable eigenvalue's real part to minus itself at the least cost
    in equation error on the records' `states` (samples x states; the change a row's terms make there, in
    square), repeated until every real part is at most `limit`. So the data's least-determined directions move
    (two positions a stiff shaft keeps together: the shaft's stiffness), not what the data pin down.
    """
    work = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms,
                           coef=np.array(coef, dtype=float), dt=model.dt)
    if not work.is_linear:
        return None
    columns = [work.terms.index(s) if s in work.terms else -1 for s in work.states]
    entries = [(i, j) for i in range(len(work.states)) for j, k in enumerate(columns)
               if k >= 0 and movable[i, k]]
    if not entries:
        return None
    gram = states.T @ states / len(states)
    weight = np.array([[gram[j, j2] if i == i2 else 0.0 for i2, j2 in entries] for i, j in entries])
    weight += 1e-9 * np.trace(weight) / len(entries) * np.eye(len(entries))
    for _ in range(steps):
        a = work.linear_matrices()[0]
        # (left and right eigenvectors matched: the unstable modes are simple even where a rigid body's are not)
        lam, left, right = linalg.eig(a, left=True, right=True)
        bad = [k for k in range(len(lam)) if lam[k].real > limit and lam[k].imag >= 0.0]
        if not bad:
            return work.coef
        norms = [complex(left[:, k].conj() @ right[:, k]) for k in bad]
        if any(abs(v) < 1e-12 for v in norms):
            return None
        gain = np.array([[(left[i, k].conj() * right[j, k] / v).real for i, j in entries]
                         for k, v in zip(bad, norms, strict=True)])
        change = np.array([-2.0 * lam[k].real for k in bad])
        # least cost d' W d with gain d = change: d = W^-1 G' (G W^-1 G')^-1 change
        spread = np.linalg.solve(weight, gain.T)
        try:
            step = spread @ np.linalg.solve(gain @ spread, change)
        except np.linalg.LinAlgError:
            return None
        coef_new = work.coef.copy()
        for (i, j), d in zip(entries, step, strict=True):
            coef_new[i, columns[j]] += d
        if not np.all(np.isfinite(coef_new)):
            return None
        work = IdentifiedModel(states=work.states, inputs=work.inputs, terms=work.terms, coef=coef_new,
                               dt=work.dt)
    return None


class StabilityPenalty:
    """Penalty rows that keep the linear part's eigenvalues in the closed left half-plane: one row per
    eigenvalue, ``gain * max(Re(lambda), 0) / limit``, and its exact derivative (a simple eigenvalue moves by
    ``w^H dA v / w^H v`` when A moves by dA).

    `problem` is the output-error refinement's parameter layout (``split``, ``index``, ``model``). The gain
    makes a growth of `limit` (1/s) cost `strength` times the data's cost at the stage's start (`data_cost` per
    residual, `n_res` residuals), so the constrained optimum stays well inside ``Re(lambda) <= limit``. Written
    by hand: scipy's ``least_squares`` takes bounds on parameters, not constraints on eigenvalues."""

    def __init__(self, problem: Any, limit: float, data_cost: float, n_res: int, strength: float = 100.0):
        self.problem, self.limit = problem, float(limit)
        if not math.isfinite(data_cost):  # a start whose free run overflows: the cost of a diverging one
            data_cost = _DIVERGED_COST
        self.gain = math.sqrt(strength * max(data_cost, 1e-300) * n_res)
        states = list(problem.model.states)
        # the parameters that are entries of A: (parameter index, row, column)
        self.entries = [(p, i, states.index(problem.model.terms[k])) for p, (i, k) in enumerate(problem.index)
                        if problem.model.terms[k] in states]
        self.columns = [problem.model.terms.index(s) if s in problem.model.terms else -1 for s in states]

    def rows(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        coef, _ = self.problem.split(t)
        n = len(self.columns)
        a = np.zeros((n, n))
        for j, k in enumerate(self.columns):
            if k >= 0:
                a[:, j] = coef[:, k]
        jac = np.zeros((n, t.size))
        if not np.all(np.isfinite(a)):
            return np.zeros(n), jac
        lam, left, right = linalg.eig(a, left=True, right=True)
        value = np.maximum(lam.real, 0.0) * self.gain / self.limit
        for m in np.flatnonzero(lam.real > 0.0):
            norm = complex(left[:, m].conj() @ right[:, m])
            if abs(norm) < 1e-12:  # a defective eigenvalue: no derivative to follow
                continue
            for p, i, j in self.entries:
                jac[m, p] = (left[i, m].conj() * right[j, m] / norm).real * self.gain / self.limit
        return value, jac
