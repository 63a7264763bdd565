"""Derivatives of sampled signals by pysindy's differentiators, chosen by name.

:func:`_differentiator` makes the pysindy object for a ``differentiation`` or ``velocity_method`` name of
:class:`~cosim.identify.sindyc.SINDYc` (:data:`~cosim.identify.sindyc.DIFFERENTIATION_METHODS`, except
"integral" and "zoh"); :func:`_derive_velocity` derives a velocity state from a measured position
(``velocities=``): by default (``"auto"``) with cosim's Savitzky-Golay derivative whose window is chosen from
the data (:func:`cosim.data.derivatives.savgol_window`) or given (``derive_window``), else with one of pysindy's
differentiators. pysindy is imported when a differentiator is first asked for.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import DataError, InvalidSettingError


def _differentiator(method: str, options: Mapping[str, Any], n: int):
    """A pysindy differentiation object for `method` with user `options` (defaults where needed)."""
    import pysindy as ps

    opts = dict(options)
    if method == "finite_difference":
        return ps.FiniteDifference(order=int(opts.pop("order", 2)), **opts)
    if method == "smoothed_finite_difference":
        kws = {"window_length": int(opts.pop("window_length", 21)), "polyorder": int(opts.pop("polyorder", 3))}
        if kws["window_length"] > n:
            raise ValueError(f"window_length {kws['window_length']} is longer than the {n} samples")
        return ps.SmoothedFiniteDifference(smoother_kws=kws, **opts)
    return ps.SINDyDerivative(kind=method, **opts)


def _derive_velocity(position: np.ndarray, t: np.ndarray, name: str, method: str,
                     options: Mapping[str, Any], window: int | None = None) -> tuple[np.ndarray, int | None]:
    """The velocity `name` derived from samples of a `position` at times `t`, and the window used.

    ``"auto"``: a cubic Savitzky-Golay derivative over `window` samples, or over the window with the least
    estimated mean-square error (:func:`~cosim.data.derivatives.savgol_window`) when `window` is None.
    Otherwise the pysindy differentiator `method` with `options` (the window is then None); without
    `options`, ``"smoothed_finite_difference"`` uses a 7-sample window and cubic smoothing. A differentiator
    that fails raises :class:`~cosim.errors.InvalidSettingError`, one that gives NaN or inf
    :class:`~cosim.errors.DataError`.
    """
    if method == "auto":
        from scipy.signal import savgol_filter

        from ..data.derivatives import savgol_window

        dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
        used = int(window) if window is not None else savgol_window(position, dt)
        used = min(used, len(position) - (len(position) % 2 == 0))
        if used < 5:
            raise DataError(f"deriving {name!r} needs at least 5 samples of its position; record longer")
        value = savgol_filter(position, used, 3, deriv=1, delta=dt, mode="interp")
        return np.asarray(value, dtype=float), used
    options = dict(options)
    if method == "smoothed_finite_difference" and not options:
        options = {"window_length": 7, "polyorder": 3}
    try:
        diff = _differentiator(method, options, len(position))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            value = np.asarray(diff(position[:, None], t), dtype=float).ravel()
    except (ValueError, TypeError, KeyError, np.linalg.LinAlgError) as exc:
        raise InvalidSettingError(f"deriving {name!r} with {method} failed ({exc}); check "
                                  "velocity_options") from None
    if not np.all(np.isfinite(value)):
        raise DataError(f"deriving {name!r} with {method} gave non-finite values; "
                        "check velocity_options")
    return value, None
