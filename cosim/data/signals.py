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

This module is the public face of the signals; the code sits in private modules by job:
:mod:`~cosim.data._waveforms` (the classes), :mod:`~cosim.data._signal_factories` (the factories),
:mod:`~cosim.data._multisine` (lines, phases and peak of a multisine), :mod:`~cosim.data._signal_specs` (the
command-line form) and :mod:`~cosim.data._signal_settings` (checks of settings).
"""

from __future__ import annotations

from ._signal_factories import chirp, constant, multisine, prbs, sine, square, step
from ._signal_specs import SIGNAL_KINDS, SignalKind, parse_signal, signal_kinds_help
from ._waveforms import Chirp, Constant, Multisine, Prbs, ScaledSignal, Signal, SignalSum, SineWave, SquareWave, Step

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
