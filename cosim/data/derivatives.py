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
from ._spectrum import signal_spectrum

__all__ = ["differentiate", "savgol_window", "DERIVATIVE_METHODS"]

#: How many candidate windows :func:`savgol_window` compares (odd, log-spaced).
_WINDOW_CANDIDATES = 80


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


def savgol_window(x: Sequence[float] | np.ndarray, dt: float, *, polyorder: int = 3, deriv: int = 1) -> int:
    """The Savitzky-Golay window (odd, samples) with the least estimated mean-square derivative error.

    The error of a Savitzky-Golay derivative has two parts: noise, which falls as the window grows (its
    variance is ``sigma^2 * sum(c_k^2)``, ``c`` the filter's coefficients), and bias, which grows with it
    (the filter's response ``H(f)`` departs from the ideal ``(2 pi i f)^deriv`` as the window covers more of
    the signal's band). Both are estimated from the data: ``sigma^2`` from fourth differences (median absolute
    deviation), the signal's spectrum from a Welch periodogram of the first differences (which flattens a
    drifting position's spectrum, so little leaks from low frequencies) less the noise's own spectrum, keeping
    only the bins that stand above the noise with 99 % confidence over all bins. The window minimising
    ``bias^2 + variance`` among about 80 odd windows from ``polyorder + 2`` to half the record wins. Clean data
    gives the shortest window; noisy or slow signals longer ones.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled signal (a position, say), finite.
    dt : float
        Sampling step in s.
    polyorder : int
        Degree of the local polynomial (3).
    deriv : int
        Which derivative the window is for (1 velocity, 2 acceleration).

    Returns
    -------
    int
        Odd window length in samples, at least ``polyorder + 2`` (or the record's length if shorter, made odd).

    Raises
    ------
    InvalidSettingError
        `dt` not positive, `deriv` not 1 or 2, `polyorder` below `deriv`.
    DataError
        `x` not a finite 1-D array.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(5000) * 1e-3
    >>> x = np.sin(2 * np.pi * t)
    >>> savgol_window(x, 1e-3)                 # clean: the shortest window
    5
    >>> noisy = x + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    >>> 100 < savgol_window(noisy, 1e-3) < 500
    True
    """
    from scipy.signal import savgol_coeffs

    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not (math.isfinite(dt) and dt > 0):
        raise InvalidSettingError(f"dt must be a positive time step in s, got {dt!r}")
    if deriv not in (1, 2):
        raise InvalidSettingError(f"deriv must be 1 or 2, got {deriv!r}")
    polyorder = _check_int("polyorder", polyorder, deriv)
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise DataError("savgol_window takes one finite signal, a 1-D array; drop or fill bad samples")
    n = x.size
    shortest = polyorder + 2 - (polyorder % 2 == 0)     # the shortest odd window above polyorder
    if n <= shortest:
        return shortest
    spectrum = signal_spectrum(x, dt)
    sigma2, freq, density, df = spectrum.noise_variance, spectrum.freq, spectrum.density, spectrum.df
    ideal = (2j * np.pi * freq) ** deriv
    longest = max(shortest, n // 2 - (n // 2 + 1) % 2)
    candidates = np.unique((np.geomspace(shortest, longest, _WINDOW_CANDIDATES) // 2 * 2 + 1).astype(int))
    best, best_mse = shortest, math.inf
    for window in candidates:
        c = savgol_coeffs(int(window), polyorder, deriv=deriv, delta=dt, use="dot")
        response = _response(c, freq, dt, df)
        mse = float(np.sum(np.abs(response - ideal) ** 2 * density) * df) + sigma2 * float(c @ c)
        if mse < best_mse:
            best, best_mse = int(window), mse
    return best


def _response(c: np.ndarray, freq: np.ndarray, dt: float, df: float) -> np.ndarray:
    """The frequency response ``sum_l c_l exp(2 pi i f dt l)`` of the centred filter `c` (lags ``-w//2 ... w//2``)
    at `freq`.

    The spectrum's bins are whole multiples of ``df = 1 / (m dt)``: there the response is a length-``m`` FFT of
    the filter folded modulo ``m`` (exact, ``m log m`` a window). Forming ``exp(2 pi i f dt l)`` for every bin and
    lag took ``bins x window`` complex exponentials: 7.4 s a signal of 25 k samples (EMPS), 80 windows up to half
    the record. Bins on no such grid take that direct sum.
    """
    lags = np.arange(c.size) - c.size // 2
    m = round(1.0 / (df * dt)) if df > 0 else 0
    bins = freq / df if df > 0 else freq
    whole = np.rint(bins)
    if m < 2 or abs(m * df * dt - 1.0) > 1e-9 or not np.allclose(bins, whole, rtol=0.0, atol=1e-6):
        return np.exp(2j * np.pi * dt * np.outer(freq, lags)) @ c
    folded = np.bincount(lags % m, weights=c, minlength=m)
    return m * np.fft.ifft(folded)[whole.astype(int) % m]


def _savgol_windows(x: np.ndarray, dt: float, order: int, window: Any, polyorder: int) -> tuple[int, ...]:
    """The window of each derivative up to `order`: chosen from the data for "auto", else the one given (or one
    per derivative), no longer than the record."""
    if window == "auto":
        chosen = [savgol_window(x, dt, polyorder=polyorder, deriv=k) for k in range(1, order + 1)]
    elif isinstance(window, (tuple, list)):
        chosen = [int(w) for w in window]
    else:
        chosen = [int(window)] * order
    top = x.size - (x.size % 2 == 0)
    return tuple(min(w, top) for w in chosen)


def _savgol(x: np.ndarray, dt: float, order: int, *, window: Any, polyorder: int) -> list[np.ndarray]:
    from scipy.signal import savgol_filter

    out = []
    for k in range(1, order + 1):
        w = _savgol_windows(x, dt, order, window, polyorder)[k - 1]
        out.append(savgol_filter(x, w, polyorder, deriv=k, delta=dt, mode="interp"))
    return out


def _savgol_min(order: int, *, window: Any, polyorder: int) -> int:
    polyorder = _check_int("savitzky_golay polyorder", polyorder, 1)
    if isinstance(window, (tuple, list)):
        return max(_savgol_min(order, window=w, polyorder=polyorder) for w in window)
    if window == "auto":
        if polyorder < order:
            raise InvalidSettingError(f"savitzky_golay needs derive_order ({order}) <= polyorder ({polyorder}); "
                                      "raise the polyorder")
        return polyorder + 2 - (polyorder % 2 == 0)
    window = _check_int("savitzky_golay window", window, 3)
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
        _savgol, MappingProxyType({"window": "auto", "polyorder": 3}), _savgol_min,
        "least-squares polynomial of degree `polyorder` (3) over a centred window of `window` samples (odd; "
        "'auto': chosen from the data by savgol_window, the least estimated mean-square error; the first and "
        "last windows at the ends), differentiated at each sample (scipy.signal.savgol_filter)"),
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

    * ``"savitzky_golay"`` (``window="auto"``, ``polyorder=3``): a cubic fitted by least squares over the
      `window` samples centred on each sample (the first and last windows at the ends), differentiated there
      (``scipy.signal.savgol_filter``). ``"auto"`` chooses the window from the data, for each derivative, by
      :func:`savgol_window` (least estimated mean-square error: noise against bias); give an odd number of
      samples to fix it. Its -3 dB bandwidth is about ``(polyorder + 1) / (3.2 * window - 4.6)`` times the
      Nyquist frequency (73 Hz at 1 kHz for 21 samples).
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
