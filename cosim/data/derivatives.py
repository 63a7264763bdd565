"""Time derivatives of uniformly sampled signals: :func:`differentiate` and its methods,
:data:`DERIVATIVE_METHODS`.

A record rarely holds every derivative a model needs (velocity from a position encoder, acceleration from a
velocity): :func:`~cosim.data.datafile.load_data` adds them with ``derive=``, by one of these methods, and
:func:`differentiate` gives them for one signal. Savitzky-Golay and Butterworth smooth while they differentiate
(for measured, noisy data); finite differences do not (for clean, simulated data). scipy.signal is imported when
a smoothing method runs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from ..errors import DataError, InvalidSettingError

__all__ = ["differentiate", "DERIVATIVE_METHODS"]


@dataclass(frozen=True)
class _Method:
    function: Callable[..., list[np.ndarray]]
    defaults: Mapping[str, Any]
    min_samples: Callable[..., int]
    summary: str


def _check_int(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise InvalidSettingError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _savgol(x: np.ndarray, dt: float, order: int, *, window: int, polyorder: int) -> list[np.ndarray]:
    from scipy.signal import savgol_filter

    return [savgol_filter(x, window, polyorder, deriv=k, delta=dt, mode="interp") for k in range(1, order + 1)]


def _savgol_min(order: int, *, window: int, polyorder: int) -> int:
    window = _check_int("savitzky_golay window", window, 3)
    polyorder = _check_int("savitzky_golay polyorder", polyorder, 1)
    if window % 2 == 0:
        raise InvalidSettingError(f"savitzky_golay window must be odd (samples centred on the point), got {window}")
    if not order <= polyorder < window:
        raise InvalidSettingError(f"savitzky_golay needs derive_order ({order}) <= polyorder ({polyorder}) < "
                                  f"window ({window}); raise the polyorder or the window")
    return window


def _butterworth(x: np.ndarray, dt: float, order: int, *, cutoff: float | None, filter_order: int
                 ) -> list[np.ndarray]:
    from scipy.signal import butter, sosfiltfilt

    cutoff = 0.1 / dt if cutoff is None else float(cutoff)
    if not 0.0 < cutoff < 0.5 / dt:
        raise InvalidSettingError(f"butterworth cutoff must lie between 0 and the Nyquist frequency "
                                  f"{0.5 / dt:g} Hz, got {cutoff:g} Hz")
    sos = butter(filter_order, cutoff, fs=1.0 / dt, output="sos")
    smooth = sosfiltfilt(sos, x)
    out = [np.gradient(smooth, dt)]
    if order == 2:
        out.append(np.gradient(out[0], dt))
    return out


def _butterworth_min(order: int, *, cutoff: float | None, filter_order: int) -> int:
    filter_order = _check_int("butterworth filter_order", filter_order, 1)
    if cutoff is not None and (isinstance(cutoff, bool) or not isinstance(cutoff, (int, float, np.floating))
                               or not math.isfinite(cutoff)):
        raise InvalidSettingError(f"butterworth cutoff must be a frequency in Hz, got {cutoff!r}")
    sections = (filter_order + 1) // 2
    return 3 * (2 * sections + 1) + 1  # scipy's sosfiltfilt pads 3 * (2 * sections + 1) samples at each end


def _finite_difference(x: np.ndarray, dt: float, order: int) -> list[np.ndarray]:
    out = [np.gradient(x, dt, edge_order=2)]
    if order == 2:
        out.append(np.gradient(out[0], dt, edge_order=2))
    return out


#: Differentiators by name: what each does, its options and their defaults.
DERIVATIVE_METHODS: Mapping[str, _Method] = MappingProxyType({
    "savitzky_golay": _Method(
        _savgol, MappingProxyType({"window": 21, "polyorder": 3}), _savgol_min,
        "least-squares polynomial of degree `polyorder` (3) over a centred window of `window` samples (21; "
        "the first and last windows at the ends), differentiated at each sample (scipy.signal.savgol_filter)"),
    "butterworth": _Method(
        _butterworth, MappingProxyType({"cutoff": None, "filter_order": 4}), _butterworth_min,
        "zero-phase Butterworth low-pass of order `filter_order` (4) at `cutoff` Hz (default a tenth of the "
        "sampling rate), run forward and backward (scipy.signal.sosfiltfilt), then central differences "
        "(numpy.gradient, applied twice for the second derivative): the EMPS reference's band-pass filtering"),
    "finite_difference": _Method(
        _finite_difference, MappingProxyType({}), lambda order: 3,
        "central differences without smoothing (numpy.gradient, second-order one-sided at the ends): exact for "
        "clean data, amplifies noise by about 1/dt"),
})


def _method(method: str, options: Mapping[str, Any] | None, order: int) -> tuple[_Method, dict[str, Any], int]:
    if method not in DERIVATIVE_METHODS:
        raise InvalidSettingError(f"unknown derive_method {method!r}; expected one of "
                                  f"{', '.join(DERIVATIVE_METHODS)}")
    if isinstance(order, bool) or order not in (1, 2):
        raise InvalidSettingError(f"derive_order must be 1 (velocity) or 2 (velocity and acceleration), "
                                  f"got {order!r}")
    entry = DERIVATIVE_METHODS[method]
    options = dict(options or {})
    unknown = [k for k in options if k not in entry.defaults]
    if unknown:
        allowed = ", ".join(entry.defaults) or "none"
        raise InvalidSettingError(f"derive_method {method!r} has no option {unknown[0]!r}; its options: {allowed}")
    options = {**entry.defaults, **options}
    return entry, options, entry.min_samples(order, **options)


def differentiate(x: Sequence[float] | np.ndarray, dt: float, *, order: int = 1, method: str = "savitzky_golay",
                  options: Mapping[str, Any] | None = None) -> tuple[np.ndarray, ...]:
    """Time derivatives of a uniformly sampled signal: ``(dx/dt,)`` or ``(dx/dt, d2x/dt2)``.

    Methods (:data:`DERIVATIVE_METHODS`, options in brackets with their defaults):

    * ``"savitzky_golay"`` (``window=21`` samples, ``polyorder=3``): a cubic fitted by least squares over the
      21 samples centred on each sample (the first and last 21 at the ends), differentiated there
      (``scipy.signal.savgol_filter``). Its -3 dB bandwidth is about ``(polyorder + 1) / (3.2 * window - 4.6)``
      times the Nyquist frequency: 73 Hz at 1 kHz with the defaults.
    * ``"butterworth"`` (``cutoff=fs/10`` Hz, ``filter_order=4``): zero-phase Butterworth low-pass (forward and
      backward, ``scipy.signal.sosfiltfilt``), then central differences (``numpy.gradient``, applied twice for
      the second derivative). This is the band-pass filtering of the robotics identification practice (the
      EMPS benchmark's reference method), with the rule of thumb cutoff >= 5 x the closed-loop bandwidth.
    * ``"finite_difference"``: central differences, no smoothing; for clean data.

    Parameters
    ----------
    x : array_like, shape (n,)
        Samples, finite, uniformly spaced in time.
    dt : float
        Sampling step in s.
    order : {1, 2}
        Highest derivative returned.
    method : str
        One of :data:`DERIVATIVE_METHODS`.
    options : mapping, optional
        The method's options (see above); others are refused.

    Returns
    -------
    tuple of ndarray
        The first derivative, and the second with ``order=2``.

    Raises
    ------
    InvalidSettingError
        Unknown method or option, bad option value, order not 1 or 2, dt not positive.
    DataError
        `x` not a finite 1-D array, or shorter than the method needs (the message says the minimum).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(101) * 0.01
    >>> v, a = differentiate(t**3, 0.01, order=2, method="savitzky_golay")
    >>> bool(np.allclose(v, 3 * t**2)), bool(np.allclose(a, 6 * t))
    (True, True)
    >>> differentiate(np.sin(t), 0.01, method="butterworth", options={"cutoff": 5.0})[0][50].round(3)
    np.float64(0.878)
    """
    entry, options, minimum = _method(method, options, order)
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not (math.isfinite(dt) and dt > 0):
        raise InvalidSettingError(f"dt must be a positive time step in s, got {dt!r}")
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise DataError(f"differentiate takes one signal, a 1-D array; got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        row = int(np.argmin(np.isfinite(x)))
        raise DataError(f"the signal is {x[row]} at sample {row}; differentiate finite samples only")
    if x.size < minimum:
        raise DataError(f"the signal has {x.size} samples; {method} needs at least {minimum} "
                        f"(options {options}); use a longer record or a smaller window")
    return tuple(np.asarray(d, dtype=float) for d in entry.function(x, float(dt), order, **options))
