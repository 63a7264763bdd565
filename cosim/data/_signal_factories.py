"""The factories of excitation signals: :func:`square`, :func:`sine`, :func:`prbs`, :func:`chirp`,
:func:`multisine`, :func:`step` and :func:`constant`, each documented with its units and an example.

They are the public way to build the classes of :mod:`~cosim.data._waveforms`; :func:`multisine` also places the
lines and chooses the phases (:mod:`~cosim.data._multisine`). Import them from :mod:`cosim.data.signals`.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType

import numpy as np

from ..errors import InvalidSettingError
from ._multisine import _MULTISINE_MAX_GRID, _band_harmonics, _common_period, _low_crest_phases, _schroeder_phases
from ._signal_settings import _choice, _integer, _positive
from ._waveforms import Chirp, Constant, Multisine, Prbs, SineWave, SquareWave, Step

__all__ = ["square", "sine", "prbs", "chirp", "multisine", "step", "constant"]


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
