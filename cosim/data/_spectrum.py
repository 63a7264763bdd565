"""A sampled signal's own spectrum, above its white measurement noise: shared by the derivative window
(:func:`~cosim.data.derivatives.savgol_window`) and the record's band (:func:`~cosim.data.decimation.signal_bandwidth`).

scipy.signal and scipy.stats are imported when a spectrum is estimated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def noise_variance(x: np.ndarray) -> float:
    """Variance of white noise on `x` from its fourth differences (robust: median absolute deviation).

    A fourth difference of white noise has variance ``70 sigma^2``; of a smooth signal sampled fast it is tiny,
    and the median makes the few large ones (steps, kinks) count as outliers, not as noise.
    """
    if x.size < 9:
        return 0.0
    d = np.diff(x, n=4)
    mad = float(np.median(np.abs(d - np.median(d))))
    return (1.4826 * mad) ** 2 / 70.0


@dataclass(frozen=True)
class SignalSpectrum:
    """The frequency bins (Hz) where a signal stands above its noise, its own one-sided density there (the
    noise's taken off), the bins' spacing and the noise variance."""

    freq: np.ndarray
    density: np.ndarray
    df: float
    noise_variance: float


def signal_spectrum(x: np.ndarray, dt: float) -> SignalSpectrum:
    """The spectrum of `x` (finite, 1-D, sampled every `dt` s) where it stands above its white noise.

    The noise variance comes from fourth differences (:func:`noise_variance`), the signal's spectrum from a
    Welch periodogram of the first differences (which flattens a drifting position's spectrum, so little leaks
    from low frequencies) less the noise's own spectrum; only the bins that stand above the noise with 99 %
    confidence over all bins are kept.
    """
    from scipy.signal import welch
    from scipy.stats import chi2

    sigma2 = noise_variance(x)
    y = np.diff(x)
    nper = int(min(y.size, 2 ** math.ceil(math.log2(max(y.size / 8, 64)))))
    f, pyy = welch(y, fs=1.0 / dt, nperseg=nper, detrend="linear")
    f, pyy = f[1:], pyy[1:]
    gain = 4.0 * np.sin(np.pi * f * dt) ** 2           # |1 - exp(-i w dt)|^2: differencing
    floor = 2.0 * sigma2 * dt * gain                     # the white noise's one-sided density after differencing
    dof = 2.0 * max(y.size / nper, 1.0)
    keep = pyy > floor * (chi2.ppf(1.0 - 0.01 / max(f.size, 1), dof) / dof)
    df = float(f[1] - f[0]) if f.size > 1 else 1.0 / (x.size * dt)
    return SignalSpectrum(freq=f[keep], density=(pyy[keep] - floor[keep]) / gain[keep], df=df,
                          noise_variance=sigma2)
