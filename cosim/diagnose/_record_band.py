"""What a record can show: its sample time, length, noise levels and the nuisance ranges the data make identifiable.

An effect's nuisance grid comes from the physics of the record, not from fixed numbers
(:meth:`cosim.diagnose.effects.Effect.grid`). Each rule below gives the range ``(lo, hi)`` in which the nuisance
can be told from the data (None: the effect cannot be identified at that place) and the grid over it:

* **periodic in a position** (cogging, ``n`` periods per radian on ``p``): the torque's frequency at the typical
  speed, ``n |v|_90 / (2 pi)``, stays below ``0.8`` of the Nyquist frequency; at the median speed while moving
  (above :data:`MOVING_SHARE` of the typical speed) it stays below
  :data:`RESONANCE_FACTOR` times the model's fastest resonance, if it has one (:func:`visible_band`: the ripple
  must pass the plant for half the record at least, not at its top speed); and the position's range holds at
  least two periods (``n ptp(p) / (2 pi) >= 2``; the range is the free run's, or the measured one less four
  noise levels where that is larger: a poor base model's free run can move less than the plant). The grid is
  uniform, at the record's resolution in ``n`` (``pi / ptp(p)``: two neighbours stay 90 % correlated along the
  range), at most :data:`PERIODIC_POINTS` values. Gravity (one period per ``2 pi``) needs the angle to turn
  through :data:`GRAVITY_MIN_RANGE`;
* **Stribeck velocity** ``vs``: between :data:`STRIBECK_NOISE` noise levels of the velocity (and the speed step
  per sample at a reversal) and a third of the largest speed, keeping only values where at least
  :data:`MIN_SHARE` of the samples move slower than ``2 vs`` and as many faster;
* **Coulomb smoothing velocity**: from the speed step per sample at a reversal to a few noise levels of the
  velocity, within ``[1e-4, 0.1]`` of the largest speed. A smaller one is a sign function on the sample grid:
  the free run then switches on the last bits of the speed near a reversal, and its cost is no smooth function
  of the parameters (issue 39: with a tenth of the step, the fits on EMPS took the smoothing velocity to
  1e-5-3e-3 m/s and named different effects under different BLAS kernels). The output-error fit keeps it in
  this span (:attr:`~cosim.diagnose._nuisance.Nuisance.bounds`); where the data ask for a sharper switch it
  rests at the lower end;
* **delay**: whole samples from 1 to :data:`DELAY_SHARE` of the record (at most :data:`DELAY_MAX`), spaced by
  about 25 %.

:class:`RecordBand` holds what the rules read besides the signals (built by the ranking from the screen: the
free run's columns, ``screen.dt``, ``screen.sigma``).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Share of the Nyquist frequency a periodic effect's frequency may reach at the typical speed.
NYQUIST_SHARE = 0.8
#: A periodic effect's frequency stays below this many times the model's fastest resonance.
RESONANCE_FACTOR = 10.0
#: Least periods of a periodic effect over the position's range.
MIN_PERIODS = 2.0
#: Percentile of the speed that stands for the typical speed.
SPEED_PERCENTILE = 90.0
#: Samples slower than this share of the typical speed stand still (they show no ripple at any period).
MOVING_SHARE = 0.01
#: Most values of a periodic effect's grid (the lowest periods at the record's resolution).
PERIODIC_POINTS = 64
#: Least range of an angle (rad) for gravity (one period per 2 pi): below it sin and cos are a line and a constant.
GRAVITY_MIN_RANGE = 0.5
#: The Stribeck velocity's least value, in noise levels of the measured velocity.
STRIBECK_NOISE = 2.0
#: Least share of the samples on each side of twice the Stribeck velocity.
MIN_SHARE = 0.05
#: Longest delay, as a share of the record's samples, and in samples.
DELAY_SHARE = 0.02
DELAY_MAX = 200
#: Shortest delay, in samples: a reading under it (the taps' centroid, when the undelayed input keeps most of
#: the gain) is a filter of the input between its samples, which a sampled record does not show, not a delay.
DELAY_MIN = 1.0
#: Ratio between neighbouring values of a logarithmic grid.
LOG_STEP = 10 ** 0.5


@dataclass(frozen=True)
class RecordBand:
    """What the nuisance rules read besides the signals.

    Attributes
    ----------
    dt : float or None
        Sample time (None: no Nyquist limit).
    samples : int
        Samples in the record.
    noise : dict
        Noise level (standard deviation) of each measured state, where known.
    ranges : dict
        Peak-to-peak range of each signal.
    visible : dict
        Per position, the highest frequency (Hz) a periodic effect on it may have besides the Nyquist band
        (:func:`visible_band`; a position not named has no such limit).
    measured_ranges : dict
        Peak-to-peak range of each measured signal less four noise levels (what the noise adds at the two
        ends): the plant's range where the model's free run, from which the other figures come, moves less than
        the plant did.
    """

    dt: float | None
    samples: int
    noise: Mapping[str, float] = field(default_factory=dict)
    ranges: Mapping[str, float] = field(default_factory=dict)
    visible: Mapping[str, float] = field(default_factory=dict)
    measured_ranges: Mapping[str, float] = field(default_factory=dict)
    #: Per measured signal, the share of its samples that sit at its lowest and at its highest value (within
    #: two noise levels or 1 % of its range): a state held at a bound lingers there. (Raw samples: their extreme
    #: is a held level's noise peak, and this undercounts a hold, 1.1 % for a tank at its overflow 3.3 % of the
    #: time; smoothed and counting only the samples that sit still, it measured holds right, but states that
    #: only turn at their extremes reached 4-10 %: no threshold told them apart. See docs/issue39_families.md.)
    lingers: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    #: Per measured signal, the share of its samples below zero (a level the plant kept non-negative, whatever a
    #: poor base model's free run does).
    below_zero: Mapping[str, float] = field(default_factory=dict)
    #: Per measured signal, its lowest and highest value smoothed (:func:`smoothed`): how far the plant went, its
    #: noise peaks left out.
    extremes: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    #: Where each record starts in concatenated columns (empty: one record).
    segments: tuple[int, ...] = ()

    @classmethod
    def of(cls, columns: Mapping[str, np.ndarray], dt: float | None = None,
           noise: Mapping[str, float] | None = None, model: Any = None,
           measured: Mapping[str, np.ndarray] | None = None, segments: Sequence[int] | None = None) -> RecordBand:
        """The band of a record (`columns`, sampled at `dt`) with its states' `noise` levels; `model` (an
        :class:`~cosim.identify.model.IdentifiedModel`) gives each position's visible band, `measured` (the
        measured signals, where `columns` is a model's free run) the measured ranges; `segments` the start of each
        record where `columns` concatenates several."""
        arrays = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
        samples = max((a.size for a in arrays.values()), default=0)
        ranges = {k: float(np.ptp(a)) if a.size else 0.0 for k, a in arrays.items()}
        visible = visible_band(model, arrays, dict(noise or {}), dt) if model is not None else {}
        levels = dict(noise or {})
        spans = {k: max(float(np.ptp(v)) - 4.0 * levels.get(k, 0.0), 0.0)
                 for k, v in (measured or {}).items() if np.size(v)}
        lingers, below_zero, extremes = {}, {}, {}
        for k, v in (measured or {}).items():
            v = np.asarray(v, dtype=float)
            if v.size:
                below_zero[k] = float(np.mean(v < 0.0))
            if v.size and np.ptp(v) > 0:
                near = max(2.0 * levels.get(k, 0.0), 0.01 * float(np.ptp(v)))
                lingers[k] = (float(np.mean(v <= v.min() + near)), float(np.mean(v >= v.max() - near)))
            if v.size and np.all(np.isfinite(v)):
                extremes[k] = _extremes(v, dt)
        return cls(dt=float(dt) if dt else None, samples=int(samples), noise=levels, ranges=ranges,
                   visible=visible, measured_ranges=spans, lingers=lingers, below_zero=below_zero,
                   extremes=extremes, segments=tuple(int(k) for k in segments or ()))

    @property
    def duration(self) -> float | None:
        return (self.samples - 1) * self.dt if self.dt else None

    @property
    def nyquist(self) -> float:
        """The Nyquist frequency in Hz (inf without a sample time)."""
        return 0.5 / self.dt if self.dt else math.inf


def visible_band(model: Any, columns: Mapping[str, np.ndarray], noise: Mapping[str, float],
                 dt: float | None) -> dict[str, float]:
    """Per position of `model`, :data:`RESONANCE_FACTOR` times the model's fastest resonance (the largest
    eigenvalue of its linear part with an imaginary part, in Hz): far above it the plant filters a ripple by
    more than 40 dB, and what a periodic term fits there is a function of the position near its reversals, not
    a ripple. Empty when the model has no resonance (a mass with friction): then only the Nyquist band limits.
    (`columns`, `noise` and `dt` are for rules that read the record.)"""
    states, terms = list(model.states), list(model.terms)
    a = np.zeros((len(states), len(states)))
    for j, name in enumerate(states):
        if name in terms:
            a[:, j] = np.asarray(model.coef, dtype=float)[:, terms.index(name)]
    if not a.size or not np.all(np.isfinite(a)):
        return {}
    eig = np.linalg.eigvals(a)
    modes = np.abs(eig[np.abs(eig.imag) > 1e-9 * np.maximum(np.abs(eig), 1e-300)])
    if not modes.size:
        return {}
    top = RESONANCE_FACTOR * float(modes.max()) / (2 * math.pi)
    velocity_of = {p: v for p in states for v in states if p != v and _is_kinematic(model, p, v)}
    return dict.fromkeys(velocity_of, top)


def _is_kinematic(model: Any, p: str, v: str) -> bool:
    row = np.asarray(model.coef, dtype=float)[list(model.states).index(p)]
    terms = list(model.terms)
    return v in terms and row[terms.index(v)] == 1.0 and np.count_nonzero(row) == 1


# ---------------------------------------------------------------------------------------------- signal figures
def speed_of(position: np.ndarray, band: RecordBand) -> np.ndarray:
    """The position's speed (by central differences; per sample without a sample time)."""
    p = np.asarray(position, dtype=float)
    return np.abs(np.gradient(p, band.dt or 1.0)) if p.size > 1 else np.zeros(p.size)


def smoothed(x: np.ndarray, dt: float) -> np.ndarray:
    """`x` smoothed as its derivative is (Savitzky-Golay, the window chosen from its noise and band): the band's
    speeds and extremes are then the motion's, not its noise's (at 1 % noise on a position sampled at 1 kHz,
    central differences gave 15 times the speed, and refused a cogging's periods the record shows)."""
    from scipy.signal import savgol_filter

    from ..data.derivatives import savgol_window

    x = np.asarray(x, dtype=float)
    if x.size < 16 or not np.all(np.isfinite(x)) or not np.ptp(x) > 0:
        return x
    window = min(savgol_window(x, dt), x.size - (x.size % 2 == 0))
    return savgol_filter(x, window, 3) if window > 4 else x


#: Smoothed extremes of measured signals, by content: every screen of a diagnosis has the same measured columns,
#: and smoothing one (choosing its window) takes 0.17 s on 25 000 samples.
_EXTREMES_CACHE: dict[tuple[bytes, float], tuple[float, float]] = {}


def _extremes(v: np.ndarray, dt: float | None) -> tuple[float, float]:
    key = (hashlib.blake2b(np.ascontiguousarray(v).tobytes(), digest_size=16).digest(), float(dt or 0.0))
    if key not in _EXTREMES_CACHE:
        if len(_EXTREMES_CACHE) >= 64:
            _EXTREMES_CACHE.clear()
        motion = smoothed(v, dt) if dt else v
        _EXTREMES_CACHE[key] = (float(motion.min()), float(motion.max()))
    return _EXTREMES_CACHE[key]


def typical_speed(speed: np.ndarray) -> float:
    return float(np.percentile(np.abs(speed), SPEED_PERCENTILE)) if np.size(speed) else 0.0


def reversal_step(velocity: np.ndarray, segments: Sequence[int] = ()) -> float:
    """Median change of the velocity over the sample in which it changes sign (nan without a reversal): the
    finest speed scale the sampled record shows near zero speed. `segments` (the start of each record in
    concatenated columns): the step from one record's last sample into the next one's first is no reversal (two
    records each moving one way, in opposite directions, showed one there, as fast as the motion: the friction's
    switch was held that smooth, and a Stribeck term stood in for the sharpness)."""
    v = np.asarray(velocity, dtype=float)
    sign = np.sign(v)
    turns = sign[1:] * sign[:-1] < 0
    joins = [int(s) - 1 for s in segments if 0 < int(s) <= turns.size]
    turns[joins] = False
    at = np.nonzero(turns)[0]
    return float(np.median(np.abs(np.diff(v)[at]))) if at.size else math.nan


def log_grid(lo: float, hi: float, step: float = LOG_STEP) -> list[float]:
    """Values from `lo` to `hi` spaced by about `step` (both ends included)."""
    if not (0.0 < lo <= hi) or not math.isfinite(hi):
        return []
    if hi / lo < 1.0 + 1e-9:
        return [float(lo)]
    count = max(2, math.ceil(math.log(hi / lo) / math.log(step)) + 1)
    return [float(v) for v in np.geomspace(lo, hi, count)]


# ---------------------------------------------------------------------------------------------- the rules
def periodic_span(position: np.ndarray, band: RecordBand, name: str = "") -> tuple[float, float] | None:
    """Periods per unit of position that the record can show (see the module notes), or None."""
    p = np.asarray(position, dtype=float)
    extent = max(float(np.ptp(p)) if p.size else 0.0, band.measured_ranges.get(name, 0.0))
    if not extent > 0.0:
        return None
    lo = max(1.0, math.ceil(MIN_PERIODS * 2 * math.pi / extent - 1e-9))
    speed = speed_of(p, band)
    top = typical_speed(speed)
    moving = speed[speed > MOVING_SHARE * top]
    hi = min(_periods_below(NYQUIST_SHARE * band.nyquist, top),
             _periods_below(band.visible.get(name, math.inf), float(np.median(moving)) if moving.size else 0.0))
    return (float(lo), float(hi)) if lo <= hi else None


def _periods_below(frequency: float, speed: float) -> float:
    """The most periods per unit of position whose ripple stays below `frequency` (Hz) at `speed`."""
    return math.floor(frequency * 2 * math.pi / speed) if speed > 0 and math.isfinite(frequency) else math.inf


def periodic_grid(lo: float, hi: float, position: np.ndarray) -> list[float]:
    """Whole periods from `lo`, at the record's resolution in periods, at most :data:`PERIODIC_POINTS` values."""
    extent = float(np.ptp(np.asarray(position, dtype=float)))
    step = max(1, int(math.pi / extent)) if extent > 0 else 1
    out, n = [], lo
    while n <= hi and len(out) < PERIODIC_POINTS:
        out.append(float(n))
        n += step
    return out


def gravity_usable(position: np.ndarray, band: RecordBand) -> bool:
    """An angle that turns far enough for sin and cos to differ from a line and a constant, slowly enough to be
    sampled."""
    p = np.asarray(position, dtype=float)
    if not (p.size and float(np.ptp(p)) >= GRAVITY_MIN_RANGE):
        return False
    speed = typical_speed(speed_of(p, band))
    return speed / (2 * math.pi) < NYQUIST_SHARE * band.nyquist


def stribeck_span(velocity: np.ndarray, band: RecordBand, name: str) -> tuple[float, float] | None:
    v = np.abs(np.asarray(velocity, dtype=float))
    vmax = float(v.max()) if v.size else 0.0
    if not vmax > 0.0:
        return None
    step = reversal_step(velocity, band.segments)
    lo = max(STRIBECK_NOISE * float(band.noise.get(name, 0.0)), step if math.isfinite(step) else 0.0, 3e-3 * vmax)
    hi = vmax / 3.0
    return (lo, hi) if lo <= hi else None


def stribeck_shown(vs: float, velocity: np.ndarray) -> bool:
    """Whether the speeds reach twice `vs`, where the Stribeck excess has fallen to 2 % (below that, a
    Stribeck velocity is a Coulomb friction that fades at the top speed: its decay is not in the record)."""
    v = np.abs(np.asarray(velocity, dtype=float))
    return bool(v.size) and float(v.max()) >= 2.0 * vs


def stribeck_grid(lo: float, hi: float, velocity: np.ndarray) -> list[float]:
    """The log grid over the span, less the values with too few samples below or above twice the value."""
    v = np.abs(np.asarray(velocity, dtype=float))
    return [vs for vs in log_grid(lo, hi) if MIN_SHARE <= float(np.mean(v < 2 * vs)) <= 1.0 - MIN_SHARE]


def smoothing_span(velocity: np.ndarray, band: RecordBand, name: str) -> tuple[float, float] | None:
    v = np.asarray(velocity, dtype=float)
    vmax = float(np.abs(v).max()) if v.size else 0.0
    if not vmax > 0.0:
        return None
    step = reversal_step(v, band.segments)
    lo = max(1e-4 * vmax, step if math.isfinite(step) else 0.0)
    hi = min(0.1 * vmax, max(0.03 * vmax, 3.0 * float(band.noise.get(name, 0.0))))
    return (lo, max(hi, lo))


def delay_span(band: RecordBand) -> tuple[float, float] | None:
    top = min(DELAY_MAX, math.floor(DELAY_SHARE * band.samples))
    return (DELAY_MIN, float(top)) if top >= DELAY_MIN else None


def delay_grid(lo: float, hi: float) -> list[float]:
    """Whole samples from `lo` to `hi`, every one up to 6, then about 25 % apart."""
    out, d = [], int(lo)
    while d <= hi:
        out.append(float(d))
        d = max(d + 1, round(d * 1.25))
    return out
