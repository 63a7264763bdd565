"""Excitation signals for identification experiments, and their text form for the command line.

A :class:`Signal` is a small frozen value that maps time in seconds to the value of one plant input, in that
input's unit. Signals are sampled, never integrated: the simulator evaluates a signal at the communication
points ``t0 + k*dt`` and holds that value over the step ``[t0 + k*dt, t0 + (k+1)*dt)`` (zero-order hold). The
same hold is used everywhere in cosim: data generation, identification, simulation of identified models and
closed loop. A signal therefore only has to be right at the sample times; a square wave or a PRBS whose edges
fall between two samples switches at the next sample.

Edges (square wave, PRBS bits, step) that fall within a billionth of a period (or of a bit) of a sample time
count as already passed, so sampling at ``k*dt`` with ``dt`` a divisor of the period is not at the mercy of
rounding in ``k*dt``.

Build signals with the factories (:func:`square`, :func:`sine`, :func:`prbs`, :func:`chirp`,
:func:`multisine`, :func:`step`, :func:`constant`) or from a command-line spec with :func:`parse_signal`.
Signals add and scale: ``0.5 + 2.0 * sine(0.1, 5.0) - step(0.2, at=1.0)``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from fractions import Fraction
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from scipy.optimize import minimize_scalar

from ..errors import InvalidSettingError, SignalSpecError
from ..numbers import parse_number

__all__ = [
    "Signal",
    "SquareWave",
    "SineWave",
    "Prbs",
    "Chirp",
    "Multisine",
    "Step",
    "Constant",
    "SignalSum",
    "ScaledSignal",
    "square",
    "sine",
    "prbs",
    "chirp",
    "multisine",
    "step",
    "constant",
    "SignalKind",
    "SIGNAL_KINDS",
    "parse_signal",
    "signal_kinds_help",
]

_EDGE_TOL = 1e-9  # fraction of a period / bit within which an edge counts as passed
_PRBS_ORDERS = (2, 24)
_MULTISINE_MAX_GRID = 1 << 22  # samples per period used to place the phases and find the peak


# ---------------------------------------------------------------------------------------------------------
# validation helpers


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidSettingError(f"{name} must be a real number, got {value!r}; pass a float such as 0.5")
    out = float(value)
    if not math.isfinite(out):
        raise InvalidSettingError(f"{name} must be finite, got {out}; pass a finite float")
    return out


def _positive(name: str, value: Any) -> float:
    out = _number(name, value)
    if out <= 0.0:
        raise InvalidSettingError(f"{name} must be > 0, got {out}; pass a positive value")
    return out


def _integer(name: str, value: Any, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidSettingError(f"{name} must be an integer, got {value!r}; pass a whole number")
    out = int(value)
    if out < low or (high is not None and out > high):
        span = f"between {low} and {high}" if high is not None else f">= {low}"
        raise InvalidSettingError(f"{name} must be {span}, got {out}; pass a value in that range")
    return out


def _choice(name: str, value: Any, choices: Mapping[str, str]) -> str:
    key = str(value).strip().lower()
    if key not in choices:
        valid = ", ".join(sorted(set(choices.values())))
        raise InvalidSettingError(f"{name}={value!r} is not known; expected one of: {valid}")
    return choices[key]


def _readonly(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def _jsonable(value: Any) -> Any:
    if isinstance(value, Signal):
        return value.to_dict()
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    return value


# ---------------------------------------------------------------------------------------------------------
# the signal classes


@dataclass(frozen=True)
class Signal:
    """Base class of excitation signals: a frozen value, callable on sample times.

    ``sig(t)`` gives the value at time(s) ``t`` in seconds, a float for a scalar ``t`` and an array of the
    same shape for an array. The simulator holds each sampled value over its step (zero-order hold).
    Signals add (``a + b``, ``a + 1.0``), subtract and scale by numbers (``2.0 * a``, ``a / 2``).

    Examples
    --------
    >>> from cosim.data.signals import sine, step
    >>> u = 1.0 + 2.0 * step(0.5, at=1.0)
    >>> float(u(0.0)), float(u(2.0))
    (1.0, 2.0)
    >>> u(np.array([0.0, 1.0]))
    array([1., 2.])
    """

    kind: ClassVar[str] = "signal"
    __array_ufunc__ = None  # let ``np.float64(2) * sig`` fall back to Signal.__rmul__

    def _coerce(self, **checks: Callable[[str, Any], Any]) -> None:
        """Validate and normalise fields of this frozen dataclass: ``self._coerce(frequency=_positive)``."""
        for name, check in checks.items():
            object.__setattr__(self, name, check(name, getattr(self, name)))

    def __call__(self, t: np.ndarray | float) -> np.ndarray | float:
        times = np.asarray(t, dtype=float)
        out = np.asarray(self._evaluate(np.atleast_1d(times)), dtype=float).reshape(times.shape)
        return float(out) if times.ndim == 0 else out

    def _evaluate(self, t: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description: ``{"kind": ..., <fields>}``, for a trajectory's ``meta``.

        Examples
        --------
        >>> from cosim.data.signals import step
        >>> step(0.5, at=1.0).to_dict()
        {'kind': 'step', 'amplitude': 0.5, 'at': 1.0, 'offset': 0.0}
        """
        out: dict[str, Any] = {"kind": self.kind}
        for f in fields(self):
            if f.init:
                out[f.name] = _jsonable(getattr(self, f.name))
        return out

    # arithmetic -------------------------------------------------------------------------------------
    def __add__(self, other: Any) -> Signal:
        other_signal = _as_signal(other)
        if other_signal is None:
            return NotImplemented
        return SignalSum(_terms(self) + _terms(other_signal))

    def __radd__(self, other: Any) -> Signal:
        other_signal = _as_signal(other)
        if other_signal is None:
            return NotImplemented
        return SignalSum(_terms(other_signal) + _terms(self))

    def __sub__(self, other: Any) -> Signal:
        other_signal = _as_signal(other)
        if other_signal is None:
            return NotImplemented
        return self + (-other_signal)

    def __rsub__(self, other: Any) -> Signal:
        other_signal = _as_signal(other)
        if other_signal is None:
            return NotImplemented
        return other_signal + (-self)

    def __neg__(self) -> Signal:
        return ScaledSignal(-1.0, self)

    def __mul__(self, gain: Any) -> Signal:
        if isinstance(gain, bool) or not isinstance(gain, numbers.Real):
            return NotImplemented
        return ScaledSignal(float(gain), self)

    __rmul__ = __mul__

    def __truediv__(self, divisor: Any) -> Signal:
        if isinstance(divisor, bool) or not isinstance(divisor, numbers.Real):
            return NotImplemented
        return ScaledSignal(1.0 / _positive_or_negative("divisor", divisor), self)


def _positive_or_negative(name: str, value: Any) -> float:
    out = _number(name, value)
    if out == 0.0:
        raise InvalidSettingError(f"{name} must not be zero; divide by a non-zero number")
    return out


def _as_signal(value: Any) -> Signal | None:
    if isinstance(value, Signal):
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return Constant(float(value))
    return None


def _terms(sig: Signal) -> tuple[Signal, ...]:
    return sig.terms if isinstance(sig, SignalSum) else (sig,)


@dataclass(frozen=True)
class SquareWave(Signal):
    """Square wave ``offset ± amplitude``: ``+amplitude`` for the first ``duty`` of each period.

    The cycle position is ``frequency*t + phase/(2*pi)``, so with ``phase=0`` the wave rises at ``t=0`` and,
    for ``duty=0.5``, has the sign of ``sine(amplitude, frequency, phase=phase)``. Build with :func:`square`.
    """

    kind: ClassVar[str] = "square"
    amplitude: float
    frequency: float
    offset: float = 0.0
    duty: float = 0.5
    phase: float = 0.0

    def __post_init__(self) -> None:
        self._coerce(amplitude=_number, frequency=_positive, offset=_number, phase=_number)
        duty = _number("duty", self.duty)
        if not 0.0 < duty < 1.0:
            raise InvalidSettingError(f"duty must be strictly between 0 and 1, got {duty}; e.g. duty=0.5")
        object.__setattr__(self, "duty", duty)

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        position = np.mod(self.frequency * t + self.phase / (2.0 * np.pi) + _EDGE_TOL, 1.0)
        return np.where(position < self.duty, self.offset + self.amplitude, self.offset - self.amplitude)


@dataclass(frozen=True)
class SineWave(Signal):
    """Sine ``offset + amplitude*sin(2*pi*frequency*t + phase)``. Build with :func:`sine`."""

    kind: ClassVar[str] = "sine"
    amplitude: float
    frequency: float
    offset: float = 0.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        self._coerce(amplitude=_number, frequency=_positive, offset=_number, phase=_number)

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        cycles = self.frequency * t
        cycles = cycles - np.floor(cycles)  # keeps the phase exact for long records
        return self.offset + self.amplitude * np.sin(2.0 * np.pi * cycles + self.phase)


@dataclass(frozen=True)
class Prbs(Signal):
    """Maximum-length pseudo-random binary sequence ``offset ± amplitude``. Build with :func:`prbs`.

    Bit ``k`` (from :func:`scipy.signal.max_len_seq`, 1 -> ``+amplitude``, 0 -> ``-amplitude``) is held over
    ``[k*clock, (k+1)*clock)``; the sequence repeats every ``2**order - 1`` bits and holds one more ``+`` bit
    than ``-`` bits. ``seed`` picks the register's initial state, i.e. a cyclic shift of the sequence.
    """

    kind: ClassVar[str] = "prbs"
    amplitude: float
    clock: float
    order: int = 10
    seed: int = 0
    offset: float = 0.0
    _bits: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._coerce(amplitude=_number, clock=_positive, offset=_number)
        object.__setattr__(self, "order", _integer("order", self.order, *_PRBS_ORDERS))
        object.__setattr__(self, "seed", _integer("seed", self.seed, 0))
        state = np.random.default_rng(self.seed).integers(0, 2, self.order, dtype=np.int8)
        if not state.any():
            state[0] = 1  # the all-zero state would lock the register
        from scipy.signal import max_len_seq  # scipy.signal costs 0.7 s to import: only when used

        sequence, _ = max_len_seq(self.order, state=state)
        object.__setattr__(self, "_bits", _readonly((2 * sequence.astype(np.int8) - 1).astype(np.int8)))

    @property
    def period(self) -> float:
        """Length of one full sequence in seconds, ``(2**order - 1) * clock``."""
        return (2**self.order - 1) * self.clock

    @property
    def bits(self) -> np.ndarray:
        """One period of the sequence as ``+1``/``-1`` (read-only int8 array)."""
        assert self._bits is not None
        return self._bits

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        index = np.floor(t / self.clock + _EDGE_TOL).astype(np.int64) % len(self.bits)
        return self.offset + self.amplitude * self.bits[index]


_CHIRP_METHODS = MappingProxyType(
    {"linear": "linear", "lin": "linear", "logarithmic": "logarithmic", "log": "logarithmic"}
)


@dataclass(frozen=True)
class Chirp(Signal):
    """Frequency sweep from ``f0`` to ``f1`` over ``[0, duration)``, ``offset`` outside; see :func:`chirp`.

    Inside the sweep the value is ``offset + amplitude*sin(phase(t))`` with ``phase(0) = 0`` and instantaneous
    frequency ``f0 + (f1 - f0)*t/duration`` (linear) or ``f0*(f1/f0)**(t/duration)`` (logarithmic), computed
    by :func:`scipy.signal.chirp`.
    """

    kind: ClassVar[str] = "chirp"
    amplitude: float
    f0: float
    f1: float
    duration: float
    method: str = "linear"
    offset: float = 0.0

    def __post_init__(self) -> None:
        self._coerce(amplitude=_number, duration=_positive, offset=_number)
        method = _choice("method", self.method, _CHIRP_METHODS)
        object.__setattr__(self, "method", method)
        check = _positive if method == "logarithmic" else _number
        for name in ("f0", "f1"):
            value = check(name, getattr(self, name))
            if value < 0.0:
                raise InvalidSettingError(f"{name} must be >= 0 Hz, got {value}; pass a frequency >= 0")
            object.__setattr__(self, name, value)

    def frequency_at(self, t: np.ndarray | float) -> np.ndarray | float:
        """Instantaneous frequency in Hz during the sweep (the design law, not a measurement)."""
        frac = np.asarray(t, dtype=float) / self.duration
        if self.method == "linear":
            out = self.f0 + (self.f1 - self.f0) * frac
        else:
            out = self.f0 * (self.f1 / self.f0) ** frac
        return float(out) if np.ndim(out) == 0 else out

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        inside = (t >= 0.0) & (t < self.duration)
        t_in = np.where(inside, t, 0.0)
        from scipy.signal import chirp as _chirp  # see Prbs: imported when used

        sweep = _chirp(t_in, self.f0, self.duration, self.f1, method=self.method, phi=-90)
        return self.offset + np.where(inside, self.amplitude * sweep, 0.0)


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

    for index in np.argsort(grid)[-5:]:
        result = minimize_scalar(
            negative_magnitude,
            bounds=((index - 1) / size, (index + 1) / size),
            method="bounded",
            options={"xatol": 1e-13},
        )
        peak = max(peak, -float(result.fun))
    return peak


@dataclass(frozen=True)
class Multisine(Signal):
    """Periodic sum of cosines ``offset + c*sum_k cos(2*pi*f_k*t + phi_k)`` whose peak is ``amplitude``.

    Every frequency is a whole multiple of ``1/period``, so over a whole number of periods the spectrum holds
    energy at these lines only, all of equal amplitude ``c = line_amplitude``; ``c`` is chosen so that the
    largest ``|value - offset|`` over a period is exactly ``|amplitude|``. Build with :func:`multisine`, which
    also chooses low-crest-factor phases.
    """

    kind: ClassVar[str] = "multisine"
    amplitude: float
    frequencies: tuple[float, ...]
    phases: tuple[float, ...]
    period: float
    offset: float = 0.0
    line_amplitude: float = field(default=0.0, init=False)
    _crest: float = field(default=0.0, init=False, repr=False, compare=False)
    _harmonics: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._coerce(amplitude=_number, period=_positive, offset=_number)
        freqs = tuple(_positive("frequency", f) for f in self.frequencies)
        phases = tuple(_number("phase", p) for p in self.phases)
        if not freqs or len(freqs) != len(phases):
            raise InvalidSettingError(
                f"multisine needs one phase per frequency, got {len(freqs)} frequencies and {len(phases)} "
                "phases; build it with multisine()"
            )
        harmonics = np.rint(np.array(freqs) * self.period).astype(np.int64)
        mismatch = np.abs(np.array(freqs) * self.period - harmonics)
        off_grid = [f for f, k, e in zip(freqs, harmonics, mismatch, strict=True) if k < 1 or e > 1e-6 * k]
        if off_grid:
            raise InvalidSettingError(
                f"frequencies {off_grid} are not whole multiples of 1/period = {1.0 / self.period:g} Hz; "
                "choose a period such that every frequency is a whole multiple of 1/period"
            )
        if len(set(harmonics.tolist())) != len(harmonics):
            raise InvalidSettingError("multisine frequencies must be distinct; remove the repeated ones")
        if 16 * harmonics.max() > _MULTISINE_MAX_GRID:
            raise InvalidSettingError(
                f"highest frequency x period = {harmonics.max()} periods per cycle is too many; "
                "use a shorter period or a lower highest frequency"
            )
        object.__setattr__(self, "frequencies", freqs)
        object.__setattr__(self, "phases", phases)
        object.__setattr__(self, "_harmonics", _readonly(harmonics))
        peak = _unit_multisine_peak(harmonics, np.array(phases))
        object.__setattr__(self, "line_amplitude", self.amplitude / peak)
        object.__setattr__(self, "_crest", peak / math.sqrt(len(freqs) / 2.0))

    @property
    def crest_factor(self) -> float:
        """Peak over RMS of the zero-mean part, ``|amplitude| / (|line_amplitude| * sqrt(n_lines/2))``."""
        return self._crest

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        assert self._harmonics is not None
        cycle = np.mod(t, self.period) / self.period
        total = np.zeros_like(t)
        for k, phi in zip(self._harmonics, self.phases, strict=True):
            total += np.cos(2.0 * np.pi * k * cycle + phi)
        return self.offset + self.line_amplitude * total


@dataclass(frozen=True)
class Step(Signal):
    """``offset`` before ``at``, ``offset + amplitude`` from ``at`` on. Build with :func:`step`."""

    kind: ClassVar[str] = "step"
    amplitude: float
    at: float = 0.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        self._coerce(amplitude=_number, at=_number, offset=_number)

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        edge = self.at - _EDGE_TOL * max(1.0, abs(self.at))
        return np.where(t >= edge, self.offset + self.amplitude, self.offset)


@dataclass(frozen=True)
class Constant(Signal):
    """The same value at every time. Build with :func:`constant`."""

    kind: ClassVar[str] = "const"
    value: float

    def __post_init__(self) -> None:
        self._coerce(value=_number)

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        return np.full(t.shape, self.value)


@dataclass(frozen=True)
class SignalSum(Signal):
    """Sum of signals, made by ``a + b``."""

    kind: ClassVar[str] = "sum"
    terms: tuple[Signal, ...]

    def __post_init__(self) -> None:
        terms = tuple(self.terms)
        if not terms or not all(isinstance(term, Signal) for term in terms):
            raise InvalidSettingError("a signal sum needs one or more Signal terms; add signals with +")
        object.__setattr__(self, "terms", terms)

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        total = np.zeros_like(t)
        for term in self.terms:
            total += term._evaluate(t)
        return total


@dataclass(frozen=True)
class ScaledSignal(Signal):
    """A signal times a number, made by ``gain * sig``."""

    kind: ClassVar[str] = "scaled"
    gain: float
    signal: Signal

    def __post_init__(self) -> None:
        self._coerce(gain=_number)
        if not isinstance(self.signal, Signal):
            raise InvalidSettingError(f"signal must be a Signal, got {type(self.signal).__name__}")

    def _evaluate(self, t: np.ndarray) -> np.ndarray:
        return self.gain * self.signal._evaluate(t)


# ---------------------------------------------------------------------------------------------------------
# factories


def square(
    amplitude: float, frequency: float, *, offset: float = 0.0, duty: float = 0.5, phase: float = 0.0
) -> SquareWave:
    """Square wave switching between ``offset + amplitude`` and ``offset - amplitude``.

    Parameters
    ----------
    amplitude : float
        Half the peak-to-peak swing, in the input's unit.
    frequency : float
        Repetitions per second, Hz (> 0).
    offset : float, optional
        Middle value, in the input's unit.
    duty : float, optional
        Fraction of each period spent at ``+amplitude``, in (0, 1).
    phase : float, optional
        Phase in radians; the cycle position is ``frequency*t + phase/(2*pi)`` and each cycle starts high.

    Returns
    -------
    SquareWave
        Sampled at the communication points and held over each step (zero-order hold).

    Examples
    --------
    >>> from cosim.data.signals import square
    >>> u = square(0.1, 2.0)  # period 0.5 s: high on [0, 0.25), low on [0.25, 0.5)
    >>> u(np.array([0.0, 0.2, 0.25, 0.5]))
    array([ 0.1,  0.1, -0.1,  0.1])
    """
    return SquareWave(amplitude, frequency, offset=offset, duty=duty, phase=phase)


def sine(amplitude: float, frequency: float, *, offset: float = 0.0, phase: float = 0.0) -> SineWave:
    """Sine ``offset + amplitude*sin(2*pi*frequency*t + phase)``.

    Parameters
    ----------
    amplitude : float
        Peak deviation from ``offset``, in the input's unit.
    frequency : float
        Hz (> 0).
    offset : float, optional
        Mean value, in the input's unit.
    phase : float, optional
        Radians.

    Returns
    -------
    SineWave
        Sampled at the communication points and held over each step (zero-order hold).

    Examples
    --------
    >>> from cosim.data.signals import sine
    >>> u = sine(0.05, 5.0)
    >>> round(u(0.05), 12)  # a quarter period
    0.05
    """
    return SineWave(amplitude, frequency, offset=offset, phase=phase)


def prbs(amplitude: float, *, clock: float, order: int = 10, seed: int = 0, offset: float = 0.0) -> Prbs:
    """Maximum-length pseudo-random binary sequence, ``offset ± amplitude``, one bit every ``clock`` s.

    Parameters
    ----------
    amplitude : float
        Deviation from ``offset`` of both levels, in the input's unit.
    clock : float
        Seconds each bit is held (> 0); the spectrum is roughly flat up to about ``0.4/clock`` Hz.
    order : int, optional
        Shift-register length, 2 to 24; the sequence repeats every ``2**order - 1`` bits.
    seed : int, optional
        Picks the register's initial state (>= 0), which shifts the sequence in time.
    offset : float, optional
        Middle value, in the input's unit.

    Returns
    -------
    Prbs
        Bit ``k`` covers ``[k*clock, (k+1)*clock)``; sampled and held like every signal (zero-order hold).

    Examples
    --------
    >>> from cosim.data.signals import prbs
    >>> u = prbs(0.1, clock=0.01, order=9, seed=1)
    >>> len(u.bits), int(u.bits.sum())  # 511 bits, one more +1 than -1
    (511, 1)
    >>> sorted(set(u(np.arange(0, 5.11, 0.01)).tolist()))
    [-0.1, 0.1]
    """
    return Prbs(amplitude, clock=clock, order=order, seed=seed, offset=offset)


def chirp(
    amplitude: float, f0: float, f1: float, duration: float, *, method: str = "linear", offset: float = 0.0
) -> Chirp:
    """Sine sweep from ``f0`` to ``f1`` Hz over ``[0, duration)`` s; ``offset`` before and after.

    Parameters
    ----------
    amplitude : float
        Peak deviation from ``offset``, in the input's unit.
    f0, f1 : float
        Start and end frequency in Hz (>= 0; > 0 for ``"logarithmic"``).
    duration : float
        Sweep length in s (> 0).
    method : {"linear", "logarithmic"}, optional
        How the instantaneous frequency moves from ``f0`` to ``f1`` (``"lin"`` and ``"log"`` also work).
    offset : float, optional
        Value before and after the sweep and its mean during it, in the input's unit.

    Returns
    -------
    Chirp
        ``offset + amplitude*sin(phase(t))`` with ``phase(0) = 0``, via :func:`scipy.signal.chirp`;
        sampled and held like every signal (zero-order hold).

    Examples
    --------
    >>> from cosim.data.signals import chirp
    >>> u = chirp(0.1, 0.1, 20.0, 4.0)
    >>> round(u(0.0), 12), u(5.0), u.frequency_at(4.0)
    (0.0, 0.0, 20.0)
    """
    return Chirp(amplitude, f0, f1, duration, method=method, offset=offset)


_CREST_METHODS = MappingProxyType({"low": "low", "schroeder": "schroeder", "random": "random"})
_SPACINGS = MappingProxyType({"log": "log", "logarithmic": "log", "linear": "linear", "lin": "linear"})


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


def multisine(
    amplitude: float,
    frequencies: Sequence[float] | None = None,
    *,
    band: tuple[float, float] | None = None,
    n: int | None = None,
    period: float | None = None,
    spacing: str = "log",
    seed: int = 0,
    crest: str = "low",
    offset: float = 0.0,
) -> Multisine:
    """Periodic multisine with equal line amplitudes, low crest factor, and peak value ``amplitude``.

    Give either the lines (``frequencies``) or a ``band`` to fill. All lines are whole multiples of
    ``1/period`` so the signal repeats exactly every ``period`` seconds and, over whole periods, has energy
    at the chosen lines only.

    Parameters
    ----------
    amplitude : float
        Largest deviation from ``offset`` over a period, in the input's unit (the signal is scaled to it).
    frequencies : sequence of float, optional
        The lines in Hz. ``period`` defaults to the shortest common period of them.
    band : (float, float), optional
        ``(f_lo, f_hi)`` in Hz; ``period`` defaults to ``1/f_lo`` and the lines are multiples of ``1/period``.
    n : int, optional
        With ``band``: number of lines, spread by ``spacing``; default every multiple of ``1/period`` in band.
    period : float, optional
        Signal period in s; the frequency resolution is ``1/period``.
    spacing : {"log", "linear"}, optional
        With ``band`` and ``n``: lines spread evenly on a log axis (default, even coverage per decade) or on a
        linear axis.
    seed : int, optional
        Seed of the phases for ``crest="random"``.
    crest : {"low", "schroeder", "random"}, optional
        Phases: ``"low"`` starts from Schroeder phases and lowers the crest factor by clipping iterations
        (typically 1.4-1.6 for evenly spaced lines, about 2 for log-spaced ones); ``"schroeder"`` is
        Schroeder's closed form alone; ``"random"`` draws uniform phases from ``seed``.
    offset : float, optional
        Mean value, in the input's unit.

    Returns
    -------
    Multisine
        Sampled and held like every signal (zero-order hold).

    Examples
    --------
    >>> from cosim.data.signals import multisine
    >>> u = multisine(0.1, band=(1.0, 10.0))  # lines 1, 2, ..., 10 Hz, period 1 s
    >>> len(u.frequencies), u.period
    (10, 1.0)
    >>> bool(np.abs(u(np.linspace(0.0, 1.0, 20001))).max() <= 0.1 + 1e-12), bool(u.crest_factor < 1.7)
    (True, True)
    """
    spacing = _choice("spacing", spacing, _SPACINGS)
    crest = _choice("crest", crest, _CREST_METHODS)
    if (frequencies is None) == (band is None):
        raise InvalidSettingError(
            "multisine needs exactly one of frequencies=[...] or band=(f_lo, f_hi); give one of them"
        )
    if frequencies is not None:
        if n is not None:
            raise InvalidSettingError("n= only applies with band=; with frequencies= every line is given")
        freqs = sorted(_positive("frequency", f) for f in frequencies)
        if not freqs:
            raise InvalidSettingError("frequencies is empty; give at least one frequency in Hz")
        the_period = _positive("period", period) if period is not None else _common_period(freqs)
        harmonics = np.rint(np.array(freqs) * the_period).astype(np.int64)
    else:
        assert band is not None
        the_period = _positive("period", period) if period is not None else 1.0 / _positive("f_lo", band[0])
        harmonics = _band_harmonics(band, the_period, n, spacing)
        freqs = list(harmonics / the_period)
    if len(set(harmonics.tolist())) == len(harmonics) and 16 * harmonics.max() <= _MULTISINE_MAX_GRID:
        if crest == "low":
            phases = _low_crest_phases(harmonics)
        elif crest == "schroeder":
            phases = _schroeder_phases(harmonics)
        else:
            phases = np.random.default_rng(_integer("seed", seed, 0)).uniform(0.0, 2.0 * np.pi, len(freqs))
    else:
        phases = np.zeros(len(freqs))  # Multisine's own validation reports the problem
    return Multisine(amplitude, tuple(freqs), tuple(float(p) for p in phases), the_period, offset=offset)


def step(amplitude: float, *, at: float = 0.0, offset: float = 0.0) -> Step:
    """Step of height ``amplitude`` at time ``at``: ``offset`` before, ``offset + amplitude`` from ``at`` on.

    Parameters
    ----------
    amplitude : float
        Height of the step, in the input's unit (negative steps down).
    at : float, optional
        Time of the step, s.
    offset : float, optional
        Value before the step, in the input's unit.

    Returns
    -------
    Step
        Sampled and held like every signal (zero-order hold).

    Examples
    --------
    >>> from cosim.data.signals import step
    >>> step(0.1, at=0.5)(np.array([0.49, 0.5, 1.0]))
    array([0. , 0.1, 0.1])
    """
    return Step(amplitude, at=at, offset=offset)


def constant(value: float) -> Constant:
    """The same ``value`` (in the input's unit) at every time.

    Examples
    --------
    >>> from cosim.data.signals import constant
    >>> constant(3.0)(np.array([0.0, 10.0]))
    array([3., 3.])
    """
    return Constant(value)


# ---------------------------------------------------------------------------------------------------------
# the command-line form


@dataclass(frozen=True)
class SignalKind:
    """One kind of signal the CLI spec knows: its factory, its keys and an example.

    Attributes
    ----------
    name : str
        The spec's kind, before the colon.
    factory : callable
        The factory in this module that builds it.
    summary : str
        One line for help texts.
    keys : Mapping[str, str]
        Every key the spec accepts, with its meaning.
    required : tuple of str
        Keys that must be present besides the amplitude (``amp`` or ``value``).
    example : str
        A spec that works.
    """

    name: str
    factory: Callable[..., Signal]
    summary: str
    keys: Mapping[str, str]
    required: tuple[str, ...]
    example: str


_KEY_MEANINGS = MappingProxyType(
    {
        "amp": "amplitude as a fraction of the input's maximum, -1..1 (needs its declared max or max=)",
        "value": "amplitude (for const: the value) in the input's unit, instead of amp",
        "max": "the input's maximum in its unit; overrides the maximum the FMU declares",
        "offset": "offset in the input's unit (default 0)",
        "freq": "frequency in Hz",
        "duty": "fraction of the period at +amp (default 0.5)",
        "phase": "phase in rad (default 0)",
        "clock": "seconds each bit is held",
        "order": "register length 2..24, period 2^order-1 bits (default 10)",
        "seed": "random seed (default 0)",
        "f0": "start frequency in Hz",
        "f1": "end frequency in Hz",
        "duration": "sweep length in s",
        "method": "linear or logarithmic (default linear)",
        "fmin": "lowest frequency in Hz",
        "fmax": "highest frequency in Hz",
        "n": "number of lines (default: every multiple of 1/period in the band)",
        "period": "period in s (default 1/fmin)",
        "spacing": "log or linear spread of the n lines (default log)",
        "freqs": "explicit lines in Hz separated by ';', instead of fmin/fmax (quote the spec)",
        "crest": "phases: low, schroeder or random (default low)",
        "at": "time of the step in s (default 0)",
    }
)
_ARGUMENTS = MappingProxyType({"freq": "frequency", "freqs": "frequencies"})  # spec key -> factory argument
_AMPLITUDE_KEYS = frozenset({"amp", "value", "max"})
_INT_KEYS = frozenset({"order", "seed", "n"})
_TEXT_KEYS = frozenset({"method", "crest", "spacing"})  # checked by the factory


def _kind(name: str, factory: Callable[..., Signal], summary: str, keys: str, required: str, example: str
          ) -> SignalKind:
    names = ("amp", "value", "max", *keys.split())  # the amplitude keys first
    return SignalKind(name, factory, summary, MappingProxyType({k: _KEY_MEANINGS[k] for k in names}),
                      tuple(required.split()), example)


#: Signal kinds of the spec form, by name: factory, keys with their meaning, required keys, an example.
SIGNAL_KINDS: Mapping[str, SignalKind] = MappingProxyType({kind.name: kind for kind in (
    _kind("square", square, "square wave offset ± amplitude", "freq duty phase offset", "freq",
          "square:amp=0.1,freq=2"),
    _kind("sine", sine, "sine offset + amplitude*sin(2*pi*freq*t + phase)", "freq phase offset", "freq",
          "sine:amp=0.05,freq=5"),
    _kind("prbs", prbs, "maximum-length pseudo-random binary sequence offset ± amplitude",
          "clock order seed offset", "clock", "prbs:amp=0.1,clock=0.01,order=9,seed=1"),
    _kind("chirp", chirp, "sine sweep from f0 to f1 Hz over [0, duration), offset afterwards",
          "f0 f1 duration method offset", "f0 f1 duration", "chirp:amp=0.1,f0=0.1,f1=20,duration=4"),
    _kind("multisine", multisine, "periodic low-crest-factor multisine, peak scaled to the amplitude",
          "fmin fmax n period spacing freqs crest seed offset", "",
          "multisine:amp=0.1,fmin=0.1,fmax=20,n=30"),
    _kind("step", step, "step of height amplitude at time at", "at offset", "", "step:amp=0.1,at=0.5"),
    _kind("const", constant, "constant value", "", "", "const:value=3.0"),
)})


def _spec_error(spec: str, problem: str) -> SignalSpecError:
    return SignalSpecError(f"signal spec {spec!r}: {problem}")


def _number_of(spec: str, key: str, text: str) -> float:
    try:
        return parse_number(text)
    except (InvalidSettingError, OverflowError):
        raise _spec_error(spec, f"{key}={text.strip()!r} is not a number; write e.g. 0.5, 1e-3 or 1/2257"
                          ) from None


def _convert(spec: str, key: str, text: str) -> Any:
    if key in _TEXT_KEYS:
        return text.strip()
    if key == "freqs":
        return [_number_of(spec, key, part) for part in text.split(";")]
    value = _number_of(spec, key, text)
    if key in _INT_KEYS:
        if not value.is_integer():
            raise _spec_error(spec, f"{key}={text.strip()!r} must be a whole number; e.g. {key}=9")
        return int(value)
    return value


def parse_signal(spec: str, *, maximum: float | None = None) -> Signal:
    """Build a signal from its command-line form ``kind:key=value,key=value`` or a bare number.

    ``amp`` is a fraction of the input's maximum: the ``max=`` key of the spec if present, else `maximum`
    (which the caller takes from the FMU's declared maximum of that input). ``value`` gives the amplitude in
    the input's unit instead; ``offset`` is always in the input's unit. Numbers are floats or fractions such
    as ``1/2257`` (parsed, never evaluated). A bare number is a constant in the input's unit. The kinds and
    their keys are in :data:`SIGNAL_KINDS`; :func:`signal_kinds_help` lists them.

    Parameters
    ----------
    spec : str
        E.g. ``"square:amp=0.1,freq=2"``, ``"prbs:value=0.5,clock=1/2257,order=9"``, ``"3.5"``.
    maximum : float, optional
        The input's maximum in its unit, for ``amp``.

    Returns
    -------
    Signal

    Raises
    ------
    SignalSpecError
        Unknown kind or key, missing or repeated key, malformed number, out-of-range setting, or ``amp``
        without a known maximum.

    Examples
    --------
    >>> from cosim.data.signals import parse_signal
    >>> parse_signal("square:amp=0.1,freq=2", maximum=10.0)
    SquareWave(amplitude=1.0, frequency=2.0, offset=0.0, duty=0.5, phase=0.0)
    >>> parse_signal("sine:value=0.05,freq=5,offset=1")
    SineWave(amplitude=0.05, frequency=5.0, offset=1.0, phase=0.0)
    >>> parse_signal("3.5")
    Constant(value=3.5)
    """
    kinds = ", ".join(SIGNAL_KINDS)
    if not isinstance(spec, str) or not spec.strip():
        raise SignalSpecError(f"empty signal spec {spec!r}; expected kind:key=value,... or a number; "
                              f"kinds: {kinds}")
    text = spec.strip()
    if ":" not in text and (text[0].isdigit() or text[0] in "+-."):
        return Constant(_number_of(spec, "value", text))
    name, _, body = text.partition(":")
    name = name.strip().lower()
    kind = SIGNAL_KINDS.get(name)
    if kind is None:
        raise _spec_error(spec, f"unknown kind {name!r}; expected one of: {kinds}, or a bare number")
    params: dict[str, Any] = {}
    for item in filter(str.strip, body.split(",")):
        key, eq, value = (part.strip() for part in item.partition("="))
        key = key.lower()
        if not eq or not value:
            raise _spec_error(spec, f"{item.strip()!r} is not key=value; e.g. {kind.example}")
        if key not in kind.keys:
            raise _spec_error(spec, f"unknown key {key!r} for {name}; valid keys: {', '.join(kind.keys)}")
        if key in params:
            raise _spec_error(spec, f"key {key!r} is given twice; give each key once")
        params[key] = _convert(spec, key, value)
    missing = [key for key in kind.required if key not in params]
    if missing:
        raise _spec_error(spec, f"missing required key(s) {', '.join(missing)}; e.g. {kind.example}")
    amplitude = _amplitude(spec, params, maximum, kind)
    if "fmin" in params or "fmax" in params:
        if "fmin" not in params or "fmax" not in params or "freqs" in params:
            raise _spec_error(spec, "a multisine needs both fmin= and fmax=, or freqs=f1;f2;... instead")
        params["band"] = (params.pop("fmin"), params.pop("fmax"))
    elif kind.name == "multisine" and "freqs" not in params:
        raise _spec_error(spec, "missing required keys fmin and fmax (or freqs=f1;f2;...); "
                          f"e.g. {kind.example}")
    arguments = {_ARGUMENTS.get(key, key): value for key, value in params.items()}
    try:
        return kind.factory(amplitude, **arguments)
    except InvalidSettingError as exc:
        raise _spec_error(spec, str(exc)) from None


def _amplitude(spec: str, params: dict[str, Any], maximum: float | None, kind: SignalKind) -> float:
    """Pop amp/value/max from `params` and return the amplitude in the input's unit."""
    fraction, value, top = params.pop("amp", None), params.pop("value", None), params.pop("max", maximum)
    if fraction is not None and value is not None:
        raise _spec_error(spec, "give amp= (fraction of the maximum) or value= (in the input's unit), "
                          "not both")
    if value is not None:
        return value
    if fraction is None:
        raise _spec_error(spec, "missing amplitude: add amp= (fraction of the input's maximum) or value= (in "
                          f"the input's unit); e.g. {kind.example}")
    if not -1.0 <= fraction <= 1.0:
        raise _spec_error(spec, f"amp={fraction:g} is outside -1..1; amp is a fraction of the input's "
                          "maximum, use value= for an amplitude in the input's unit")
    if top is None:
        raise _spec_error(spec, f"amp={fraction:g} is a fraction of the input's maximum but the input "
                          "declares no maximum; add max=VALUE to the spec or give the amplitude in the "
                          "input's unit with value=")
    if isinstance(top, bool) or not isinstance(top, numbers.Real) or not 0.0 < float(top) < math.inf:
        raise _spec_error(spec, f"the input's maximum is {top!r} but amp= needs a positive finite maximum; "
                          "add max=VALUE or use value=")
    return fraction * float(top)


def signal_kinds_help() -> str:
    """Text listing every signal kind with its keys and an example, for ``--help``.

    Examples
    --------
    >>> from cosim.data.signals import signal_kinds_help
    >>> print(signal_kinds_help().splitlines()[1])
      square: square wave offset ± amplitude; e.g. square:amp=0.1,freq=2
    """
    lines = ["Signal specs kind:key=value,...: amp= is a fraction of the input's maximum, value= in its unit"]
    for kind in SIGNAL_KINDS.values():
        lines.append(f"  {kind.name}: {kind.summary}; e.g. {kind.example}")
        own = [f"{key}: {meaning}" for key, meaning in kind.keys.items() if key not in _AMPLITUDE_KEYS]
        if own:
            lines.append("      " + "; ".join(own))
    lines.append("  a bare number, e.g. 3.5: a constant in the input's unit")
    return "\n".join(lines)
