"""Accuracy measures of a model's prediction against measured data.

Plain functions on arrays. With 1-D arrays each returns a float; with 2-D arrays (samples x signals) it
returns one value per column. `measured` is the reference (in the reference study's protocol: the *clean*
simulation), `predicted` the model's free-run prediction of it.

=====================  ================================================================================
:func:`r2`             coefficient of determination, ``1 - SS_res/SS_tot`` (the study's R^2)
:func:`nrmse_fit_pct`  MATLAB ``compare`` fit, ``100*(1 - ||y - yhat|| / ||y - mean(y)||)``
:func:`max_deviation_pct`  the study's Table 1 measure: ``max|y - yhat|`` in % of the peak-to-peak amplitude
:func:`k_step_ahead_error`  RMS error of k-step-ahead predictions of a model on a trajectory
=====================  ================================================================================

Examples
--------
>>> import numpy as np
>>> y = np.array([0.0, 1.0, 2.0, 3.0])
>>> [round(float(f(y, y + 0.1)), 4) for f in (r2, nrmse_fit_pct, max_deviation_pct)]
[0.992, 91.0557, 3.3333]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import DataError, InvalidSettingError

__all__ = ["r2", "nrmse_fit_pct", "max_deviation_pct", "k_step_ahead_error", "k_step_ahead_predictions",
           "METRICS"]


def _pair(measured: Any, predicted: Any) -> tuple[np.ndarray, np.ndarray]:
    try:
        y = np.asarray(measured, dtype=float)
        f = np.asarray(predicted, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"measured and predicted must be numeric arrays ({exc}); convert them to floats") from None
    if y.shape != f.shape:
        raise DataError(f"measured has shape {y.shape} but predicted has shape {f.shape}; compare arrays of the "
                        "same shape (samples x signals)")
    if y.ndim not in (1, 2) or y.shape[0] < 2:
        raise DataError(f"expected 1-D or 2-D arrays with at least two samples, got shape {y.shape}")
    for name, arr in (("measured", y), ("predicted", f)):
        if not np.all(np.isfinite(arr)):
            row = int(np.argmax(~np.isfinite(arr).reshape(arr.shape[0], -1).all(axis=1)))
            raise DataError(f"{name} holds NaN or inf at sample {row}; drop those samples (a diverged simulation "
                            "ends in NaN)")
    return y, f


def _out(values: np.ndarray, one_d: bool) -> float | np.ndarray:
    return float(values[0]) if one_d else values


def r2(measured: Any, predicted: Any) -> float | np.ndarray:
    """Coefficient of determination ``R^2 = 1 - SS_res/SS_tot`` (the reference study's accuracy measure).

    ``SS_res = sum (y_i - f_i)^2``, ``SS_tot = sum (y_i - mean(y))^2``; 1 is a perfect prediction, 0 is as
    good as predicting the mean, and it is negative for worse. A constant measured signal has ``SS_tot = 0``:
    then R^2 is 1 for a perfect prediction and ``-inf`` otherwise.

    Parameters
    ----------
    measured, predicted : array_like, shape (n,) or (n, m)
        Reference and prediction; per column when 2-D.

    Returns
    -------
    float or ndarray of shape (m,)

    Examples
    --------
    >>> r2([1.0, 2.0, 3.0], [1.0, 2.0, 4.0])
    0.5
    >>> r2([[1.0, 0.0], [2.0, 1.0], [3.0, 0.0]], [[1.0, 0.0], [2.0, 1.0], [3.0, 1.0]]).round(6).tolist()
    [1.0, -0.5]
    """
    y, f = _pair(measured, predicted)
    one_d = y.ndim == 1
    y, f = y.reshape(len(y), -1), f.reshape(len(f), -1)
    ss_res = np.sum((y - f) ** 2, axis=0)
    ss_tot = np.sum((y - y.mean(axis=0)) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = np.where(ss_tot > 0, 1.0 - ss_res / np.where(ss_tot > 0, ss_tot, 1.0),
                         np.where(ss_res == 0, 1.0, -np.inf))
    return _out(value, one_d)


def nrmse_fit_pct(measured: Any, predicted: Any) -> float | np.ndarray:
    """MATLAB ``compare`` fit in %: ``100*(1 - ||y - yhat|| / ||y - mean(y)||)`` (2-norms over samples).

    100 is a perfect prediction, 0 is as good as the mean; it relates to R^2 by
    ``fit = 100*(1 - sqrt(1 - R^2))``.

    Parameters
    ----------
    measured, predicted : array_like, shape (n,) or (n, m)

    Returns
    -------
    float or ndarray of shape (m,)

    Examples
    --------
    >>> round(nrmse_fit_pct([1.0, 2.0, 3.0], [1.0, 2.0, 4.0]), 6)   # 100*(1 - 1/sqrt(2))
    29.289322
    """
    y, f = _pair(measured, predicted)
    one_d = y.ndim == 1
    y, f = y.reshape(len(y), -1), f.reshape(len(f), -1)
    num = np.linalg.norm(y - f, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = np.where(den > 0, 100.0 * (1.0 - num / np.where(den > 0, den, 1.0)),
                         np.where(num == 0, 100.0, -np.inf))
    return _out(value, one_d)


def max_deviation_pct(measured: Any, predicted: Any) -> float | np.ndarray:
    """Maximum absolute deviation in % of the measured signal's amplitude (the study's Table 1 measure).

    ``100 * max_i |y_i - f_i| / (max(y) - min(y))``. The reference study does not say what "amplitude" is;
    cosim takes the **peak-to-peak range of the measured (clean) signal**, ``max(y) - min(y)``, because it is
    defined for any signal (also one with an offset or a drift, where a half range or an RMS value would
    mislead) and it is what a plot's vertical extent shows. A constant measured signal has amplitude 0: the
    result is then 0 for a perfect prediction and ``inf`` otherwise.

    Parameters
    ----------
    measured, predicted : array_like, shape (n,) or (n, m)

    Returns
    -------
    float or ndarray of shape (m,)

    Examples
    --------
    >>> round(max_deviation_pct([0.0, 4.0, 2.0], [0.0, 4.0, 2.2]), 9)   # 0.2 of a 4.0 range
    5.0
    """
    y, f = _pair(measured, predicted)
    one_d = y.ndim == 1
    y, f = y.reshape(len(y), -1), f.reshape(len(f), -1)
    dev = np.max(np.abs(y - f), axis=0)
    amplitude = np.max(y, axis=0) - np.min(y, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = np.where(amplitude > 0, 100.0 * dev / np.where(amplitude > 0, amplitude, 1.0),
                         np.where(dev == 0, 0.0, np.inf))
    return _out(value, one_d)


#: Metrics by name, as used by ``SINDYc.score(metric=...)``: name -> (function, higher is better).
METRICS = {"r2": (r2, True), "nrmse": (nrmse_fit_pct, True), "fit": (nrmse_fit_pct, True),
           "max_deviation": (max_deviation_pct, False)}


def k_step_ahead_error(model: Any, trajectory: Any, k: int) -> dict[str, float]:
    """RMS error of k-step-ahead predictions of `model` on `trajectory`, per state.

    From every measured state ``x[j]`` (j = 0 .. n-1-k) the model is simulated `k` steps with the trajectory's
    zero-order-hold inputs ``u[j] .. u[j+k-1]``, and the prediction is compared with the measured ``x[j+k]``.
    ``k = 1`` is the one-step-ahead (equation-error-like) accuracy; a large `k` approaches the free-run
    (output-error) accuracy. A linear model is stepped with its exact zero-order-hold discretisation, a
    nonlinear one with RK4 (one step per sample), all starting points at once.

    Parameters
    ----------
    model : IdentifiedModel or SINDYc
        A fitted model (a fitted :class:`~cosim.identify.sindyc.SINDYc` is accepted for its ``model_``).
    trajectory : Trajectory
        Measured data holding the model's states and inputs, uniformly sampled.
    k : int
        Prediction horizon in samples, 1 <= k < number of samples.

    Returns
    -------
    dict
        State name -> RMS error, in the state's unit. A prediction that leaves the model's range gives ``inf``.

    Raises
    ------
    InvalidSettingError
        `k` out of range, or a model that is not fitted.
    UnknownVariableError
        The trajectory lacks a state or input of the model.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> from cosim.data.trajectory import Trajectory
    >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 1.0]]))
    >>> run = model.simulate([0.0], np.ones((200, 1)), dt=0.01).to_trajectory()
    >>> err = k_step_ahead_error(model, run, 10)
    >>> err["x"] < 1e-12
    True
    """
    from .model import IdentifiedModel

    model = getattr(model, "model_", model)
    if not isinstance(model, IdentifiedModel):
        raise InvalidSettingError(f"expected an IdentifiedModel or a fitted SINDYc, got {type(model).__name__}; "
                                  "fit the estimator first")
    n = len(trajectory)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k < n:
        raise InvalidSettingError(f"k must be an integer between 1 and {n - 1} (samples in the trajectory - 1), "
                                  f"got {k!r}")
    if n > 1 and not trajectory.is_uniform():
        raise DataError("the trajectory is not uniformly sampled; k-step-ahead prediction needs one step dt")
    x = np.asarray(trajectory[list(model.states)], dtype=float).reshape(n, -1)
    u = np.asarray(trajectory[list(model.inputs)], dtype=float).reshape(n, -1) if model.inputs else None
    predicted = k_step_ahead_predictions(model, x, u, trajectory.dt, k)
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.sqrt(np.mean((predicted - x[k:]) ** 2, axis=0))
    err = np.where(np.isfinite(err), err, np.inf)
    return {name: float(err[i]) for i, name in enumerate(model.states)}


def k_step_ahead_predictions(model: Any, x: np.ndarray, u: np.ndarray | None, dt: float, k: int) -> np.ndarray:
    """Predictions of ``x[k:]``, each from the measured state `k` samples before with the zero-order-hold inputs
    in between: a linear model stepped with its exact discretisation, a nonlinear one with RK4 (one step per
    sample), all starting points at once. Rows that leave the model's range hold inf or NaN."""
    n = len(x)
    u = np.zeros((n, 0)) if u is None else u
    m = n - k
    state = x[:m].copy()
    with np.errstate(over="ignore", invalid="ignore"):
        if model.is_linear:
            ad, bd, cd = model.discretize(dt)
            for i in range(k):
                state = state @ ad.T + u[i:i + m] @ bd.T + cd
        else:
            f = model.predict
            for i in range(k):
                ui = u[i:i + m]
                k1 = f(state, ui)
                k2 = f(state + 0.5 * dt * k1, ui)
                k3 = f(state + 0.5 * dt * k2, ui)
                k4 = f(state + dt * k3, ui)
                state = state + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return state
