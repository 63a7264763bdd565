"""The sparse regression of a :class:`~cosim.identify.sindyc.SINDYc` fit: scale-aware STLSQ, threshold by BIC.

:func:`_sparse_fit` divides each feature and each target by its RMS value, so that a coefficient is the
fraction of the target its term explains and one threshold fits states of any unit, and runs
:func:`_sparse` on that scaled problem: pysindy's ``STLSQ`` (:func:`_stlsq`) with the given threshold or,
for ``"auto"``, the threshold of least BIC on the equation error along the threshold path (step 3 of the
:mod:`cosim.identify.sindyc` docstring). With noise compensation the normal equations are bias-compensated
first, and the directions whose signal is below their noise are dropped.

With ``refine="output_error"`` and ``"auto"``, :mod:`cosim.identify.sindyc` asks for :data:`AUTO_IF_EXACT`:
the threshold of least BIC when its model explains every regressed target to :data:`_EXACT` (a noise-free
record: the equation error decides the structure, and output error only adjusts the coefficients), else the
dense fit, which output error prunes (on noisy data equation error cannot judge small terms). Before, the dense
fit was always refined: on noise-free records output error's Wald tests keep every term (their standard errors
vanish with the noise), 2-12 spurious terms per system of ``benchmarks/bench_sindy_threshold.py``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Residual RMS, relative to the target's RMS, below which the "auto" threshold treats a fit as exact.
_BIC_FLOOR = 1e-6
_MAX_CANDIDATES = 40
#: The equation-error threshold of an "auto" fit refined by output error: the threshold of least BIC when its
#: model leaves a residual RMS of at most :data:`_EXACT` of every regressed target (the record decides the
#: structure), else 0 (the dense fit, pruned by output error: equation error cannot judge small terms on noisy
#: data).
AUTO_IF_EXACT = "auto-if-exact"
#: Residual RMS, relative to the target's RMS, up to which the equation error decides the structure. Noise-free
#: records leave 1e-15 (forward-Euler samples, left rectangle) to 3.5e-7 (Van der Pol at mu = 5, dt = 0.01 s,
#: trapezoid with end correction); 0.5 % of noise leaves 7e-3 or more (``benchmarks/bench_sindy_threshold.py``).
_EXACT = 1e-4
#: Noise compensation keeps a direction of the normal equations if its signal exceeds this multiple of its noise.
_NOISE_MARGIN = 1.0


@dataclass(frozen=True)
class _SparseFit:
    """The sparse coefficients of some rows, the threshold used and how it was chosen."""

    #: Coefficients of the regressed rows, shape (rows, terms), in the data's units.
    coef: np.ndarray
    threshold: float
    #: How the threshold was chosen (``model_.meta["threshold"]``).
    meta: dict[str, Any]
    #: RMS of each regressed row's scaled equation error.
    residual_rms: list[float]
    #: RMS of each feature over RMS of each target, shape (states, terms): the unit of a scaled coefficient.
    coef_scale: np.ndarray


def _sparse_fit(features: np.ndarray, targets: np.ndarray, rows: list[int], n_eff: float,
                noise_var: np.ndarray | None, threshold: float | str, ridge: float) -> _SparseFit:
    """Regress the targets of `rows` on the features, scaled by their RMS values (no rows: nothing regressed).

    `noise_var` is the noise variance of each feature column (noise compensation) or None; `threshold` a
    number, ``"auto"`` or :data:`AUTO_IF_EXACT` (module docstring).
    """
    feat_scale = np.sqrt(np.mean(features ** 2, axis=0))
    usable = feat_scale > 0
    targ_scale = np.sqrt(np.mean(targets ** 2, axis=0))
    targ_scale = np.where(targ_scale > 0, targ_scale, 1.0)
    coef = np.zeros((len(rows), features.shape[1]))
    residual_rms: list[float] = []
    if rows:
        theta_s = features[:, usable] / feat_scale[usable]
        y_s = targets[:, rows] / targ_scale[rows]
        noise_s = None if noise_var is None else noise_var[usable] * len(features) / feat_scale[usable] ** 2
        xi, value, meta = _sparse(theta_s, y_s, n_eff, noise_s, "auto" if threshold == AUTO_IF_EXACT else threshold,
                                  ridge)
        residual_rms = np.sqrt(np.mean((y_s - theta_s @ xi.T) ** 2, axis=0)).tolist()
        if threshold == AUTO_IF_EXACT:
            exact = max(residual_rms) <= _EXACT
            if not exact:  # noisy, or not in the library: the dense fit, for output error to prune
                xi, value, meta = _sparse(theta_s, y_s, n_eff, noise_s, 0.0, ridge)
                residual_rms = np.sqrt(np.mean((y_s - theta_s @ xi.T) ** 2, axis=0)).tolist()
            meta = {**meta, "rule": AUTO_IF_EXACT, "exact": _EXACT, "decided_by_equation_error": bool(exact)}
        coef[:, usable] = xi * targ_scale[rows, None] / feat_scale[usable]
    else:
        value = 0.0 if threshold in ("auto", AUTO_IF_EXACT) else float(threshold)
        meta = {"method": "none: every row is a fixed kinematic row", "value": value}
    coef_scale = np.ones((targets.shape[1], features.shape[1]))
    coef_scale[:, usable] = feat_scale[usable][None, :] / targ_scale[:, None]
    return _SparseFit(coef=coef, threshold=value, meta=meta, residual_rms=residual_rms, coef_scale=coef_scale)


def _stlsq(r: np.ndarray, qy: np.ndarray, threshold: float, n: int, ridge: float) -> np.ndarray:
    """pysindy STLSQ on the compressed problem ``(R, Q^T y)`` of ``theta = Q R``: the same solution as on
    ``(theta, y)`` (the two least-squares objectives differ by a constant), at a fraction of the cost."""
    from pysindy.optimizers import STLSQ

    opt = STLSQ(threshold=float(threshold), alpha=float(ridge) * n, max_iter=50, normalize_columns=False,
                unbias=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(r, qy)
    coef = np.asarray(opt.coef_, dtype=float).reshape(qy.shape[1], r.shape[1])
    return np.where(np.isfinite(coef), coef, 0.0)


def _sparse(theta: np.ndarray, y: np.ndarray, n_eff: float, noise: np.ndarray | None, threshold: float | str,
            ridge: float):
    """STLSQ (given or "auto" threshold) on the scaled problem; `noise` is the noise part of each column's
    sum of squares (noise compensation), or None."""
    n = theta.shape[0]
    q, r = np.linalg.qr(theta)
    qy = q.T @ y
    gram = r.T @ r
    cross = theta.T @ y
    y2 = np.sum(y ** 2, axis=0)
    compensation: dict[str, Any] = {"applied": False}
    if noise is not None and np.any(noise > 0):
        # bias-compensated normal equations, truncated to the directions whose signal exceeds the noise
        noise_gram = np.diag(noise)
        ev, vec = np.linalg.eigh(gram - noise_gram)
        noise_level = np.einsum("ij,ik,kj->j", vec, noise_gram, vec)
        keep = ev > _NOISE_MARGIN * noise_level + 1e-12 * max(float(ev.max()), 1e-300)
        r = np.sqrt(ev[keep])[:, None] * vec[:, keep].T
        qy = (vec[:, keep].T @ cross) / np.sqrt(ev[keep])[:, None]
        compensation = {"applied": True, "dropped_directions": int((~keep).sum()),
                        "method": "bias-compensated least squares, directions with signal below "
                                  f"{_NOISE_MARGIN:g} x noise dropped"}

    def rss(xi: np.ndarray) -> np.ndarray:  # plain (uncompensated) residual sum of squares / n
        return np.maximum(y2 - 2.0 * np.einsum("ij,ji->i", xi, cross) + np.einsum("ij,jk,ik->i", xi, gram, xi),
                          0.0) / n

    if threshold != "auto":
        value = float(threshold)
        return _stlsq(r, qy, value, n, ridge), value, {"method": "given", "value": value,
                                                       "noise_compensation": compensation}
    dense = _stlsq(r, qy, 0.0, n, ridge)
    mags = np.unique(np.abs(dense[dense != 0.0]))
    cuts = [0.0] + [math.sqrt(a * b) for a, b in zip(mags[:-1], mags[1:], strict=True)]
    if len(cuts) > _MAX_CANDIDATES:
        cuts = [0.0] + list(np.geomspace(cuts[1], cuts[-1], _MAX_CANDIDATES - 1))
    candidates, best = [], None
    for cut in cuts:
        xi = dense if cut == 0.0 else _stlsq(r, qy, cut, n, ridge)
        k = int(np.count_nonzero(xi))
        score = float(np.sum(n_eff * np.log(np.maximum(rss(xi), _BIC_FLOOR ** 2))) + k * math.log(n_eff))
        candidates.append({"threshold": float(cut), "nonzero": k, "bic": score})
        if best is None or score <= best[0] + 1e-9 * abs(best[0]):
            best = (score, cut, xi)
    assert best is not None
    meta = {"method": "auto: BIC on the scaled equation error along the STLSQ threshold path",
            "value": float(best[1]), "floor": _BIC_FLOOR, "n_eff": n_eff, "samples": n,
            "noise_compensation": compensation, "candidates": candidates}
    return best[2], float(best[1]), meta
