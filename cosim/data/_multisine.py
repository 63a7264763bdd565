"""Multisine design: where the lines go, low-crest-factor phases, and the exact peak of a period.

The lines of a multisine are whole multiples (harmonics ``k``) of ``1/period``; one period of the unit multisine
``sum_k cos(2*pi*k*s + phi_k)`` is computed on a grid by an inverse FFT. :func:`_unit_multisine_peak` refines the
grid's peak with :func:`scipy.optimize.minimize_scalar` (imported when first used: scipy.optimize is slow to
import). The phases start from Schroeder's closed form and are lowered in crest factor by clipping iterations.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from fractions import Fraction

import numpy as np

from ..errors import InvalidSettingError
from ._signal_settings import _integer, _positive

_MULTISINE_MAX_GRID = 1 << 22  # samples per period used to place the phases and find the peak


def _unit_multisine_grid(harmonics: np.ndarray, phases: np.ndarray, size: int) -> np.ndarray:
    spectrum = np.zeros(size // 2 + 1, dtype=complex)
    spectrum[harmonics] = np.exp(1j * phases) * (size / 2)
    return np.fft.irfft(spectrum, size)


def _grid_size(harmonics: np.ndarray) -> int:
    return max(1024, 1 << int(np.ceil(np.log2(16 * int(harmonics.max()) + 1))))


def _unit_multisine_peak(harmonics: np.ndarray, phases: np.ndarray) -> float:
    """Exact peak of sum(cos(2*pi*k*s + phi_k)) over one period: dense grid, then local refinement."""
    size = _grid_size(harmonics)
    grid = np.abs(_unit_multisine_grid(harmonics, phases, size))
    peak = float(grid.max())

    def negative_magnitude(s: float) -> float:
        return -abs(float(np.sum(np.cos(2.0 * np.pi * harmonics * s + phases))))

    from scipy.optimize import minimize_scalar  # slow to import: only when a multisine is built

    for index in np.argsort(grid)[-5:]:
        result = minimize_scalar(
            negative_magnitude,
            bounds=((index - 1) / size, (index + 1) / size),
            method="bounded",
            options={"xatol": 1e-13},
        )
        peak = max(peak, -float(result.fun))
    return peak


def _schroeder_phases(harmonics: np.ndarray) -> np.ndarray:
    """Schroeder (1970) phases for equal line powers: phi_n = -2*pi*sum_{l<n} (k_n - k_l)/N."""
    n = len(harmonics)
    cumulative = np.concatenate(([0], np.cumsum(harmonics)[:-1]))  # sum of k_l for l < n
    return -2.0 * np.pi * (np.arange(n) * harmonics - cumulative) / n


def _low_crest_phases(harmonics: np.ndarray, iterations: int = 100) -> np.ndarray:
    """Schroeder phases refined by clipping iterations (Van der Ouderaa, Schoukens, Renneboog 1988)."""
    size = _grid_size(harmonics)
    phases = _schroeder_phases(harmonics)
    best_crest, best_phases = np.inf, phases
    for clip in (1.0, 1.2, 1.4):  # clipping level in RMS units; each level reaches different optima
        phases = best_phases
        for _ in range(iterations):
            x = _unit_multisine_grid(harmonics, phases, size)
            rms = math.sqrt(len(harmonics) / 2.0)
            crest = float(np.abs(x).max()) / rms
            if crest < best_crest:
                best_crest, best_phases = crest, phases
            phases = np.angle(np.fft.rfft(np.clip(x, -clip * rms, clip * rms))[harmonics])
    return best_phases


def _band_harmonics(band: Sequence[float], period: float, n: int | None, spacing: str) -> np.ndarray:
    if len(band) != 2:
        raise InvalidSettingError(f"band must be (f_lo, f_hi) in Hz, got {band!r}; e.g. band=(0.1, 20)")
    f_lo, f_hi = _positive("band low frequency", band[0]), _positive("band high frequency", band[1])
    if f_hi < f_lo:
        raise InvalidSettingError(f"band=({f_lo}, {f_hi}) is reversed; expected f_lo <= f_hi")
    k_lo = max(1, math.ceil(f_lo * period - 1e-6))
    k_hi = math.floor(f_hi * period + 1e-6)
    available = k_hi - k_lo + 1
    if available < 1:
        raise InvalidSettingError(
            f"no multiple of 1/period = {1.0 / period:g} Hz lies in band ({f_lo}, {f_hi}) Hz; "
            "lengthen period or widen the band"
        )
    if n is None:
        return np.arange(k_lo, k_hi + 1)
    n = _integer("n", n, 1)
    if n > available:
        raise InvalidSettingError(
            f"band ({f_lo}, {f_hi}) Hz holds only {available} lines at 1/period = {1.0 / period:g} Hz, "
            f"n={n} asked; lower n or lengthen period"
        )
    grid = np.geomspace(k_lo, k_hi, n) if spacing == "log" else np.linspace(k_lo, k_hi, n)
    k = np.rint(grid).astype(np.int64)
    for i in range(1, n):  # rounding merges neighbours at the low end: push them apart
        k[i] = max(k[i], k[i - 1] + 1)
    k[-1] = min(k[-1], k_hi)
    for i in range(n - 2, -1, -1):
        k[i] = min(k[i], k[i + 1] - 1)
    return k


def _common_period(freqs: Sequence[float]) -> float:
    fracs = [Fraction(f).limit_denominator(1_000_000) for f in freqs]
    if any(abs(float(q) - f) > 1e-9 * f for q, f in zip(fracs, freqs, strict=True)):
        raise InvalidSettingError("frequencies have no simple common period; give period= explicitly")
    numerator = math.gcd(*(q.numerator for q in fracs))
    denominator = math.lcm(*(q.denominator for q in fracs))
    return float(Fraction(denominator, numerator))
