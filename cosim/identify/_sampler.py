"""Which sampler made the data: a continuous flow sampled, or a fixed-step forward-Euler solver.

The integral equation error (:class:`~cosim.identify._equation_error._IntegralEquations`) integrates the
library over each window by the trapezoid with its end correction: exact to O(dt^4) for samples of a
continuous flow. Many co-simulation FMUs do not record a continuous flow: they integrate their equations with
a fixed-step forward Euler at the communication step (the Modelica Association's Reference FMUs do), so that
``x[k+1] = x[k] + dt f(x[k], u[k])`` exactly. On such data the trapezoid is off by ``dt/2 (f(x_b) - f(x_a))``
per window, an O(dt |df/dx|) share of the target (0.7 % and 1.2 % of the two rows of the Van der Pol FMU at
mu = 1, dt = 0.01 s). Noise-free, that residual is far above the BIC floor, and the library explains it
(Euler's modified equation ``f - dt/2 (df/dx) f``): the threshold of least BIC then keeps every term it takes,
8 spurious ones on that FMU with a cubic library. The threshold rule is not at fault: on samples of a
continuous flow (``benchmarks/bench_sindy_threshold.py``, scipy's ``solve_ivp``) it finds the exact
structure; the equation error was inconsistent with the data.

:func:`_equations` therefore forms both equation errors over the same windows: the trapezoid's (as
:func:`cosim.identify._equation_error._equations`) and the left rectangle's, ``x_b - x_a = dt *
sum_{k=a}^{b-1} theta(x_k, u_k)``, exact for forward-Euler data. The data choose: the dense least-squares fit
of the regressed rows is computed on each, and the left rectangle is used when it lowers the dense fit's BIC
on the scaled equation error (the same criterion and floor as the threshold path, the sampler counted as one
more parameter). Samples of a continuous flow keep the trapezoid (their left-rectangle residual is the same
O(dt) the trapezoid has on Euler data); on noisy records both residuals are the noise's and the trapezoid is
kept unless the left rectangle is clearly better. The choice and both scores are in
``model_.meta["equation_error"]["sampler"]``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ._equation_error import _equations as _trapezoid_equations
from ._equation_error import _evaluate
from ._sparse_regression import _BIC_FLOOR
from .terms import Term


def _left_rectangle(parsed: Sequence[Term], state_names: Sequence[str], input_names: Sequence[str], x: np.ndarray,
                    u: np.ndarray, dt: float, window: int) -> np.ndarray:
    """Features ``dt * sum_{k=a}^{b-1} theta(x_k, u_k)`` of the windows ``[a, a + window]`` of one record."""
    theta = _evaluate(parsed, state_names, input_names, x[:-1], u[:len(x) - 1])
    cum = np.vstack([np.zeros((1, theta.shape[1])), np.cumsum(dt * theta, axis=0)])
    a = np.arange(0, len(x) - 1 - window + 1)
    return cum[a + window] - cum[a]


def _dense_score(features: np.ndarray, targets: np.ndarray, rows: Sequence[int], n_eff: float) -> float:
    """``sum_i N_eff*log(max(RSS_i/N, floor^2))`` of the dense least-squares fit of `rows`, each target and
    feature scaled by its RMS value (the BIC of :func:`cosim.identify._sparse_regression._sparse` without
    its term count, which is the same for both samplers)."""
    scale = np.sqrt(np.mean(features ** 2, axis=0))
    usable = scale > 0
    theta = features[:, usable] / scale[usable]
    y = targets[:, list(rows)]
    y = y / np.where(np.sqrt(np.mean(y ** 2, axis=0)) > 0, np.sqrt(np.mean(y ** 2, axis=0)), 1.0)
    coef, *_ = np.linalg.lstsq(theta, y, rcond=None)
    rss = np.mean((y - theta @ coef) ** 2, axis=0)
    return float(np.sum(n_eff * np.log(np.maximum(rss, _BIC_FLOOR ** 2))))


def _equations(runs: Sequence[tuple[np.ndarray, np.ndarray]], parsed: Sequence[Term], state_names: Sequence[str],
               input_names: Sequence[str], dt: float, kin: Mapping[str, str], *, method: str,
               options: Mapping[str, Any], noise_compensation: bool
               ) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any], np.ndarray | None]:
    """:func:`cosim.identify._equation_error._equations`; for ``"integral"``, the left rectangle's features
    instead of the trapezoid's when they fit the data better (module docstring)."""
    features, targets, n_eff, meta, noise_var = _trapezoid_equations(
        runs, parsed, state_names, input_names, dt, kin, method=method, options=options,
        noise_compensation=noise_compensation)
    rows = [i for i, s in enumerate(state_names) if s not in kin]
    if method != "integral" or not rows:
        return features, targets, n_eff, meta, noise_var
    window = int(meta["window"])
    euler = np.vstack([_left_rectangle(parsed, state_names, input_names, x, u, dt, window) for x, u in runs])
    scores = {"trapezoid": _dense_score(features, targets, rows, n_eff),
              "forward_euler": _dense_score(euler, targets, rows, n_eff)}
    # the sampler is one more parameter of the model: the left rectangle must pay for it, as a term does
    chosen = "forward_euler" if scores["forward_euler"] + math.log(n_eff) < scores["trapezoid"] else "trapezoid"
    meta["sampler"] = {"chosen": chosen, "bic_dense": scores,
                       "rule": "left rectangle (forward-Euler samples) when it lowers the dense fit's BIC by more "
                               "than log(N_eff); else the trapezoid with its end correction (a continuous flow)"}
    if chosen == "trapezoid":
        return features, targets, n_eff, meta, noise_var
    if noise_var is not None:  # a window's weights are dt*(1, ..., 1): noise variance dt^2*window, not *(window-1/2)
        noise_var = noise_var * window / (window - 0.5)
    return euler, targets, n_eff, meta, noise_var
