"""A record brought to a lower rate: :func:`signal_bandwidth` (the highest frequency a signal shows above its
noise) and :func:`decimate` (every ``factor``-th sample, measured signals low-pass filtered first, held inputs
averaged over each new interval).

Sampling much faster than a plant's band costs time in every simulation and fit and adds nothing the model can
use; the usual advice of system identification is a rate of about ten times the band (Ljung, *System
Identification*, 2nd ed., section 13.7; MATLAB's ``idresamp``). :func:`decimate` is that resampling done for a
free-run (output-error) fit:

* a measured signal is filtered by the FIR low-pass ``scipy.signal.decimate`` uses (``firwin(20 factor + 1,
  1 / factor)``, Hamming window), zero-phase (``scipy.signal.resample_poly``; the record's ends extended by a
  line, not by zeros), then every ``factor``-th sample kept: in-band content is kept, white noise keeps
  :func:`noise_gain` of its variance (about ``1 / factor``);
* a held (zero-order-hold) input is averaged over each new sample interval: what a model integrating the input
  over that interval sees, to first order, where a filtered sample would smear an input step over the filter.

scipy.signal is imported when a record is decimated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from ..errors import DataError, InvalidSettingError
from ._spectrum import signal_spectrum
from .trajectory import Trajectory

__all__ = ["RATE_PER_BAND", "WORK_SAMPLES", "decimate", "decimate_arrays", "decimation_factor", "noise_gain",
           "signal_bandwidth"]

#: The rate a fit works at over the band (the highest frequency the record shows, or the model's fastest mode).
RATE_PER_BAND = 10.0
#: Fewest samples (all records together) :func:`decimation_factor` brings records down to.
WORK_SAMPLES = 4000


def signal_bandwidth(x: Sequence[float] | np.ndarray, dt: float) -> float:
    """The highest frequency (Hz) at which `x` stands above its white measurement noise (0.0: nowhere).

    The signal's spectrum is a Welch periodogram of its first differences less the noise's (the noise level from
    fourth differences); a bin counts when it stands above the noise with 99 % confidence over all bins. Its
    harmonics count too: a friction's reversals or a cogging's ripple widen the band as far as they are seen.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled, finite signal.
    dt : float
        Sampling step in s.

    Returns
    -------
    float
        Frequency in Hz, at most the Nyquist frequency ``1 / (2 dt)``.

    Raises
    ------
    DataError
        `x` not a finite 1-D array of at least 16 samples, or `dt` not positive.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(20000) * 1e-3
    >>> x = np.sin(2 * np.pi * 3.0 * t) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    >>> 2.5 < signal_bandwidth(x, 1e-3) < 10.0
    True
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or x.size < 16 or not np.all(np.isfinite(x)):
        raise DataError("signal_bandwidth takes one finite signal of at least 16 samples; drop or fill bad "
                        "samples")
    if not (np.isfinite(dt) and dt > 0):
        raise DataError(f"the sampling step must be positive, got {dt!r}")
    spectrum = signal_spectrum(x, float(dt))
    return float(spectrum.freq.max()) if spectrum.freq.size else 0.0


def decimation_factor(records: Sequence[np.ndarray], dt: float, *, mode_hz: float = 0.0, min_samples: int = 200,
                      work_samples: int = WORK_SAMPLES) -> int:
    """The factor that brings records sampled every `dt` s down to :data:`RATE_PER_BAND` times their band.

    The band is the highest :func:`signal_bandwidth` of any column of any record (measured signals, not inputs),
    or `mode_hz` (a model's fastest mode) if higher. Records of at most `work_samples` samples together are kept
    as they are (1), and none is brought below `work_samples` samples together or `min_samples` on its own:
    fewer samples leave a fit's checks and grids coarse, for little time saved.

    Parameters
    ----------
    records : sequence of ndarray, shape (n_k, signals)
        The measured signals of each record.
    dt : float
        Their common step in s.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(20000) * 1e-3
    >>> x = np.sin(2 * np.pi * 2.0 * t) + 1e-3 * np.random.default_rng(0).standard_normal(t.size)
    >>> decimation_factor([x[:, None]], 1e-3)    # a 2 Hz band: 20 Hz would do, 4000 samples are kept
    5
    """
    lengths = [len(r) for r in records]
    total = sum(lengths)
    if total <= work_samples:
        return 1
    band = max([mode_hz] + [signal_bandwidth(np.asarray(r, dtype=float)[:, j], dt) for r in records
                            for j in range(np.shape(r)[1])])
    by_band = math.inf if band <= 0.0 else math.floor(1.0 / (dt * RATE_PER_BAND * band))
    return int(max(1, min(by_band, total // work_samples, min(lengths) // min_samples)))


def decimate_arrays(measured: np.ndarray, held: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`decimate` on arrays: `measured` (n, k) low-pass filtered and sampled, `held` (n, m) averaged over
    each new step; both ``ceil(n / factor)`` rows."""
    from scipy.signal import resample_poly

    measured, held = np.asarray(measured, dtype=float), np.asarray(held, dtype=float)
    if factor == 1:
        return measured, held
    n = len(measured)
    starts = np.arange(0, n, factor)
    counts = np.diff(np.append(starts, n))
    slow = resample_poly(measured, 1, factor, axis=0, window=_low_pass(factor), padtype="line")[:starts.size]
    mean = np.add.reduceat(held, starts, axis=0) / counts.reshape(-1, *([1] * (held.ndim - 1)))
    return slow, mean


@lru_cache(maxsize=32)
def _low_pass(factor: int) -> np.ndarray:
    from scipy.signal import firwin

    return firwin(20 * factor + 1, 1.0 / factor, window="hamming")


def noise_gain(factor: int) -> float:
    """The share of a white noise's variance that :func:`decimate` keeps on a measured signal (about
    ``1 / factor``; 1.0 for factor 1).

    >>> round(noise_gain(4), 3)
    0.241
    """
    return 1.0 if factor == 1 else float(np.sum(_low_pass(int(factor)) ** 2))


def decimate(traj: Trajectory, factor: int, *, held: Sequence[str] | None = None) -> Trajectory:
    """`traj` at a ``factor`` times longer step: samples ``0, factor, 2 factor, ...``.

    Parameters
    ----------
    traj : Trajectory
        A uniformly sampled record.
    factor : int
        The new step over the old, at least 1 (1 gives `traj` back).
    held : sequence of str, optional
        The signals held between samples (inputs), averaged over each new interval; the others are measured,
        low-pass filtered and sampled. Default: the record's inputs.

    Returns
    -------
    Trajectory
        ``ceil(n / factor)`` samples, the same names, units and roles; ``meta["decimated"]`` holds the factor,
        the old step and :func:`noise_gain`.

    Raises
    ------
    InvalidSettingError
        `factor` not a positive integer, or `held` naming a signal that `traj` does not have.
    DataError
        `traj` not uniformly sampled, or too short for the filter (fewer than ``2 factor`` samples).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(1000) * 1e-3
    >>> traj = Trajectory.from_arrays(t, {"u": np.sign(np.sin(2 * np.pi * t)), "x": np.sin(2 * np.pi * t)},
    ...                               roles={"u": "input", "x": "state"})
    >>> slow = decimate(traj, 4)
    >>> len(slow), round(slow.dt, 6), float(slow["u"][0])
    (250, 0.004, 0.75)
    >>> error = np.abs(slow["x"] - np.sin(2 * np.pi * slow.time))   # in-band: kept (the ends extrapolated)
    >>> bool(error[5:-5].max() < 1e-3 and error.max() < 5e-3)
    True
    """
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise InvalidSettingError(f"the decimation factor must be a positive integer, got {factor!r}")
    factor = int(factor)
    if factor == 1:
        return traj
    held = tuple(traj.inputs if held is None else held)
    unknown = [name for name in held if name not in traj.names]
    if unknown:
        raise InvalidSettingError(f"held names {unknown[0]!r}, which is not a signal of the record; signals are "
                                  f"{list(traj.names)}")
    if not traj.is_uniform():
        raise DataError("decimate needs a uniformly sampled record; resample it onto a uniform grid first")
    n = len(traj)
    if n < 2 * factor:
        raise DataError(f"a record of {n} samples is too short to decimate by {factor}; use a smaller factor")
    measured = [name for name in traj.names if name not in held]
    slow, mean = decimate_arrays(traj[measured].reshape(n, -1), traj[list(held)].reshape(n, -1), factor)
    columns = {**dict(zip(measured, slow.T, strict=True)), **dict(zip(held, mean.T, strict=True))}
    columns = {name: columns[name] for name in traj.names}
    starts = np.arange(0, n, factor)
    meta = {**traj.meta, "decimated": {"factor": factor, "from_dt": traj.dt, "noise_gain": noise_gain(factor)}}
    return Trajectory.from_arrays(traj.time[starts], columns, units=dict(zip(traj.names, traj.units, strict=True)),
                                  roles=dict(zip(traj.names, traj.roles, strict=True)), meta=meta)
