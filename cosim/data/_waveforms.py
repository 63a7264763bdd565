"""The signal classes: :class:`Signal`, its waveforms, and the sums and scalings that arithmetic makes.

Each class is a frozen dataclass that checks and normalises its fields when built and evaluates itself on an
array of sample times; the factories of :mod:`cosim.data.signals` (:func:`~cosim.data.signals.square`...) are
the usual way to build one. Edges that fall within :data:`_EDGE_TOL` of a period (or bit) of a sample time count
as passed (see :mod:`cosim.data.signals`).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from ..errors import InvalidSettingError
from ._multisine import _MULTISINE_MAX_GRID, _unit_multisine_peak
from ._signal_settings import _choice, _integer, _number, _positive, _readonly

__all__ = ["Signal", "SquareWave", "SineWave", "Prbs", "Chirp", "Multisine", "Step", "Constant", "SignalSum",
           "ScaledSignal"]

_EDGE_TOL = 1e-9  # fraction of a period / bit within which an edge counts as passed
_PRBS_ORDERS = (2, 24)


def _jsonable(value: Any) -> Any:
    if isinstance(value, Signal):
        return value.to_dict()
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    return value


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
