"""The equation error of a :class:`~cosim.identify.sindyc.SINDYc` fit: features and targets from the data.

:func:`_equations` stacks, over every record, the library terms (features) and what the model must give
from them (targets), by the ``differentiation`` method; how each method forms them, and why, is step 2 of
the :mod:`cosim.identify.sindyc` docstring:

* ``"integral"``: :class:`_IntegralEquations`, sliding windows integrated with the input held, the
  trapezoid's end correction taken along the field fitted so far (:func:`_dense_field`), and with
  ``noise_compensation`` the white-noise variance of the states (:func:`_white_noise_variance`) turned into
  the noise part of each feature's sum of squares, for the sparse regression to remove;
* ``"zoh"``: derivatives of the dense linear model from the matrix logarithm of the least-squares
  discrete-time map (:func:`_zoh_dense`);
* a pysindy differentiator (:mod:`cosim.identify._differentiation`): derivatives at the samples, the
  library evaluated on the smoothed states with the mean of the inputs held before and after each sample.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..errors import DataError, InvalidSettingError
from ..numbers import check_memory
from ._differentiation import _differentiator
from .terms import Term


def _window(options: Mapping[str, Any]) -> int:
    """The integration window of ``"integral"``, in samples, from the ``differentiation_options``."""
    return int(options.get("window", 30))


def _equations(runs: Sequence[tuple[np.ndarray, np.ndarray]], parsed: Sequence[Term], state_names: Sequence[str],
               input_names: Sequence[str], dt: float, kin: Mapping[str, str], *, method: str,
               options: Mapping[str, Any], noise_compensation: bool
               ) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any], np.ndarray | None]:
    """Stack features and targets of every record: (features, targets, N_eff, meta, noise variance or None)."""
    samples = sum(len(x) for x, _ in runs)
    # the term matrix, its integrals and a least-squares copy: refused up front on a machine too small for them
    check_memory(4.0 * samples * (len(parsed) + len(state_names)),
                 what=f"identifying {len(parsed)} terms on {samples:,} samples",
                 hint="decimate the record (decimate=N, --decimate N), shorten it, or use a smaller library")
    meta: dict[str, Any] = {"method": method}
    feats, targs = [], []
    noise_var = None
    if method == "zoh":
        allowed = {"1", *state_names, *input_names}
        nonlinear = [t.text for t in parsed if t.text not in allowed]
        if nonlinear:
            raise InvalidSettingError(f"differentiation='zoh' is exact for linear libraries only; the library "
                                      f"has {', '.join(nonlinear)}; use differentiation='integral'")
        dense = _zoh_dense(runs, parsed, state_names, input_names, dt)
        meta["dense_continuous_coef"] = dense.tolist()
        for x, u in runs:
            theta = _evaluate(parsed, state_names, input_names, x[:-1], u[:-1])
            feats.append(theta)
            targs.append(theta @ dense.T)
        n_eff = sum(len(x) - 1 for x, _ in runs)
    elif method == "integral":
        window = _window(options)
        meta["window"] = window
        systems = [_IntegralEquations(parsed, state_names, input_names, x, u, dt, window) for x, u in runs]
        targets = np.vstack([s.targets for s in systems])
        coef = None
        for _ in range(3):  # trapezoid, then two passes of the end correction along the fitted field
            features = np.vstack([s.features(coef) for s in systems])
            coef = _dense_field(features, targets, parsed, state_names, kin)
        feats, targs = [features], [targets]
        n_eff = sum((len(x) - 1) / window for x, _ in runs)
        if noise_compensation:
            sigma2 = _white_noise_variance(runs, len(state_names))
            meta["noise_std"] = dict(zip(state_names, np.sqrt(sigma2).tolist(), strict=True))
            # a window's trapezoid weights are dt*(1/2, 1, ..., 1, 1/2): noise variance dt^2*(window - 1/2)
            noise_var = np.array([sigma2[state_names.index(t.text)] * dt ** 2 * (window - 0.5)
                                  if t.text in state_names else 0.0 for t in parsed])
    else:
        options = dict(options)
        meta["options"] = options
        for x, u in runs:
            t = dt * np.arange(len(x))
            try:
                diff = _differentiator(method, options, len(x))
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    xdot = np.asarray(diff(x, t), dtype=float)
            except (ValueError, TypeError, KeyError, np.linalg.LinAlgError) as exc:
                raise InvalidSettingError(f"differentiation {method!r} failed ({exc}); check "
                                          "differentiation_options") from None
            smooth = getattr(diff, "smoothed_x_", None)
            xs = np.asarray(smooth, dtype=float) if smooth is not None and np.shape(smooth) == x.shape else x
            good = np.all(np.isfinite(xdot), axis=1) & np.all(np.isfinite(xs), axis=1)
            if good.sum() < 2:
                raise InvalidSettingError(f"differentiation {method!r} gave no finite derivatives; check "
                                          "differentiation_options")
            # a central derivative at t_k measures the mean of the slopes before and after the sample,
            # where the inputs u[k-1] and u[k] are held: evaluate the library the same way
            before = np.vstack([u[:1], u[:-1]])
            theta = 0.5 * (_evaluate(parsed, state_names, input_names, xs, before)
                           + _evaluate(parsed, state_names, input_names, xs, u))
            feats.append(theta[good])
            targs.append(xdot[good])
        n_eff = sum(len(f) for f in feats)
    features, targets = np.vstack(feats), np.vstack(targs)
    if not (np.all(np.isfinite(features)) and np.all(np.isfinite(targets))):
        bad = [term.text for term, ok in zip(parsed, np.all(np.isfinite(features), axis=0), strict=True)
               if not ok]
        raise DataError(f"the library is not finite on the data (terms {', '.join(bad) or '?'}); "
                        "remove terms such as log or 1/x that the data makes infinite")
    return features, targets, max(float(n_eff), 1.0), meta, noise_var


def _dense_field(features: np.ndarray, targets: np.ndarray, parsed, state_names, kin) -> np.ndarray:
    """Least-squares coefficients of every row (kinematic rows exact): the field for the end correction."""
    scale = np.sqrt(np.mean(features ** 2, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    sol, *_ = np.linalg.lstsq(features / scale, targets, rcond=None)
    coef = (sol / scale[:, None]).T
    names = [t.text for t in parsed]
    for pos, vel in kin.items():
        row = state_names.index(pos)
        coef[row] = 0.0
        coef[row, names.index(vel)] = 1.0
    return np.where(np.isfinite(coef), coef, 0.0)


def _evaluate(parsed: Sequence[Term], state_names: Sequence[str], input_names: Sequence[str], x: np.ndarray,
              u: np.ndarray) -> np.ndarray:
    values = {n: x[:, i] for i, n in enumerate(state_names)}
    values.update({n: u[:, j] for j, n in enumerate(input_names)})
    with np.errstate(all="ignore"):
        return np.column_stack([t.evaluate(values) for t in parsed])


class _IntegralEquations:
    """Sliding windows ``[a, a + window]`` of one record: targets ``x_b - x_a``, features ``integral theta``.

    Interval k (input held at ``u[k]``) is integrated by the trapezoid on ``theta(x_k, u_k)`` and
    ``theta(x_{k+1}, u_k)`` plus its end correction ``-dt^2/12 * (g'(t_{k+1}-) - g'(t_k+))``, which makes
    it exact to O(dt^5) per interval (O(dt^4) per window) for any input pattern, because inside an interval
    the integrand is smooth. The derivative ``g'`` of each term along the trajectory is taken along the
    model's own vector field, ``grad g . (coef @ theta)``, with the input held: :meth:`features` takes the
    current coefficient estimate, and the fit iterates (the correction is ~(omega*dt)^2/12 of the feature, so
    two passes reach the O(dt^4) floor).
    """

    def __init__(self, parsed, state_names, input_names, x: np.ndarray, u: np.ndarray, dt: float, window: int):
        self.parsed, self.state_names, self.input_names = parsed, state_names, input_names
        self.x, self.u, self.dt = x, u[:len(x) - 1], dt
        n = len(x) - 1
        self.g0 = _evaluate(parsed, state_names, input_names, x[:-1], self.u)  # theta(x_k, u_k)
        self.g1 = _evaluate(parsed, state_names, input_names, x[1:], self.u)   # theta(x_{k+1}, u_k)
        self.trapezoid = np.vstack([np.zeros((1, self.g0.shape[1])),
                                    np.cumsum(0.5 * dt * (self.g0 + self.g1), axis=0)])
        self.a = np.arange(0, n - window + 1)
        self.b = self.a + window
        self.targets = x[self.b] - x[self.a]

    def _slope(self, points: np.ndarray, theta: np.ndarray, coef: np.ndarray) -> np.ndarray:
        """d theta/dt at `points` (inputs held) along the field ``coef @ theta``: central difference."""
        velocity = theta @ coef.T
        size = np.max(np.abs(velocity), axis=0)
        scale = np.max(np.abs(self.x), axis=0)
        h = 1e-6 * float(np.min(np.where(size > 0, np.maximum(scale, 1e-300) / np.where(size > 0, size, 1.0),
                                          np.inf)))
        if not math.isfinite(h) or h <= 0:
            return np.zeros_like(theta)
        plus = _evaluate(self.parsed, self.state_names, self.input_names, points + h * velocity, self.u)
        minus = _evaluate(self.parsed, self.state_names, self.input_names, points - h * velocity, self.u)
        return (plus - minus) / (2.0 * h)

    def features(self, coef: np.ndarray | None) -> np.ndarray:
        cum = self.trapezoid
        if coef is not None:
            d0 = self._slope(self.x[:-1], self.g0, coef)
            d1 = self._slope(self.x[1:], self.g1, coef)
            correction = np.vstack([np.zeros((1, d0.shape[1])), np.cumsum(d1 - d0, axis=0)])
            cum = cum - self.dt ** 2 / 12.0 * correction
        return cum[self.b] - cum[self.a]


def _white_noise_variance(runs, n_states: int) -> np.ndarray:
    """Variance of white measurement noise on each state, from fourth differences of the samples.

    A fourth difference of a smooth signal sampled fast is tiny, of white noise it has variance
    ``70*sigma^2``; the median absolute deviation (x 1.4826) makes steps and kinks in the signal (square-wave
    edges) count as outliers, not as noise.
    """
    d = np.vstack([np.diff(x, n=4, axis=0) for x, _ in runs if len(x) > 8] or [np.zeros((1, n_states))])
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return (1.4826 * mad) ** 2 / 70.0


def _zoh_dense(runs, parsed, state_names, input_names, dt: float) -> np.ndarray:
    """Dense continuous coefficients from the least-squares discrete map and the matrix logarithm."""
    from scipy.linalg import logm

    n, m = len(state_names), len(input_names)
    names = [t.text for t in parsed]
    has_const = "1" in names
    q = n + m + (1 if has_const else 0)
    order = list(state_names) + list(input_names) + (["1"] if has_const else [])
    z = np.vstack([np.column_stack([x[:-1], u[:-1]] + ([np.ones((len(x) - 1, 1))] if has_const else []))
                   for x, u in runs])
    target = np.vstack([x[1:] for x, _ in runs])
    g, *_ = np.linalg.lstsq(z, target, rcond=None)
    big = np.eye(q)
    big[:n, :] = g.T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log = logm(big)
    log = np.asarray(log)
    if np.iscomplexobj(log):
        if np.max(np.abs(log.imag)) > 1e-6 * max(np.max(np.abs(log.real)), 1e-300):
            raise DataError("the fitted discrete-time map has no real matrix logarithm (eigenvalues on the negative "
                            "real axis: noisy data or too coarse a sampling); use differentiation='integral'")
        log = log.real
    cont = log[:n] / dt
    if not np.all(np.isfinite(cont)):
        raise DataError("the discrete-time map is singular (is every state and input excited?); use "
                        "differentiation='integral'")
    dense = np.zeros((n, len(names)))
    for k, name in enumerate(names):
        dense[:, k] = cont[:, order.index(name)]
    return dense
