"""The command-line form of a signal, ``kind:key=value,...``: :func:`parse_signal`, :data:`SIGNAL_KINDS`
(:class:`SignalKind`) and :func:`signal_kinds_help`.

Amplitudes are given in the input's unit (``amp=``, or ``value=``) or as a fraction of the input's maximum
(``frac=``); numbers are floats or fractions, parsed and never evaluated. Before cosim 0.2 ``amp=`` was the
fraction: an ``amp`` within -1..1 on an input whose maximum is known still reads so, with a
:class:`~cosim.errors.CosimDeprecationWarning` (write ``frac=`` for it, ``value=`` for a small amplitude).
Errors are :class:`~cosim.errors.SignalSpecError` naming the spec and what to write instead. Import these from
:mod:`cosim.data.signals`.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from ..errors import CosimDeprecationWarning, InvalidSettingError, SignalSpecError
from ..numbers import parse_number
from ._signal_factories import chirp, constant, multisine, prbs, sine, square, step
from ._waveforms import Constant, Signal

__all__ = ["SignalKind", "SIGNAL_KINDS", "parse_signal", "signal_kinds_help"]


@dataclass(frozen=True)
class SignalKind:
    """One kind of signal the CLI spec knows: its factory, its keys and an example.

    Attributes
    ----------
    name : str
        The spec's kind, before the colon.
    factory : callable
        The factory of :mod:`cosim.data.signals` that builds it.
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
        "amp": "amplitude in the input's unit",
        "frac": "amplitude as a fraction of the input's maximum, -1..1 (its declared max, or max=)",
        "value": "amplitude (for const: the value) in the input's unit, as amp",
        "max": "the input's maximum in its unit, for frac; overrides the maximum the FMU declares",
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
_AMPLITUDE_KEYS = frozenset({"amp", "frac", "value", "max"})
_INT_KEYS = frozenset({"order", "seed", "n"})
_TEXT_KEYS = frozenset({"method", "crest", "spacing"})  # checked by the factory


def _kind(name: str, factory: Callable[..., Signal], summary: str, keys: str, required: str, example: str
          ) -> SignalKind:
    names = ("amp", "frac", "value", "max", *keys.split())  # the amplitude keys first
    return SignalKind(name, factory, summary, MappingProxyType({k: _KEY_MEANINGS[k] for k in names}),
                      tuple(required.split()), example)


#: Signal kinds of the spec form, by name: factory, keys with their meaning, required keys, an example.
SIGNAL_KINDS: Mapping[str, SignalKind] = MappingProxyType({kind.name: kind for kind in (
    _kind("square", square, "square wave offset ± amplitude", "freq duty phase offset", "freq",
          "square:amp=500,freq=2"),
    _kind("sine", sine, "sine offset + amplitude*sin(2*pi*freq*t + phase)", "freq phase offset", "freq",
          "sine:amp=5,freq=5"),
    _kind("prbs", prbs, "maximum-length pseudo-random binary sequence offset ± amplitude",
          "clock order seed offset", "clock", "prbs:amp=200,clock=0.01,order=9,seed=1"),
    _kind("chirp", chirp, "sine sweep from f0 to f1 Hz over [0, duration), offset afterwards",
          "f0 f1 duration method offset", "f0 f1 duration", "chirp:amp=2.5,f0=0.1,f1=20,duration=4"),
    _kind("multisine", multisine, "periodic low-crest-factor multisine, peak scaled to the amplitude",
          "fmin fmax n period spacing freqs crest seed offset", "",
          "multisine:frac=0.1,fmin=0.1,fmax=20,n=30"),
    _kind("step", step, "step of height amplitude at time at", "at offset", "", "step:amp=10,at=0.5"),
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

    ``amp`` (or ``value``) is the amplitude in the input's unit; ``frac`` is a fraction of the input's maximum:
    the ``max=`` key of the spec if present, else `maximum` (which the caller takes from the FMU's declared
    maximum of that input). ``offset`` is always in the input's unit. An ``amp`` within -1..1 on an input whose
    maximum is known is read as the fraction it meant before cosim 0.2, with a
    :class:`~cosim.errors.CosimDeprecationWarning` saying what to write. Numbers are floats or fractions such
    as ``1/2257`` (parsed, never evaluated). A bare number is a constant in the input's unit. The kinds and
    their keys are in :data:`SIGNAL_KINDS`; :func:`signal_kinds_help` lists them.

    Parameters
    ----------
    spec : str
        E.g. ``"square:amp=500,freq=2"``, ``"prbs:frac=0.1,clock=1/2257,order=9"``, ``"3.5"``.
    maximum : float, optional
        The input's maximum in its unit, for ``frac``.

    Returns
    -------
    Signal

    Raises
    ------
    SignalSpecError
        Unknown kind or key, missing or repeated key, malformed number, out-of-range setting, or ``frac``
        without a known maximum.

    Examples
    --------
    >>> from cosim.data.signals import parse_signal
    >>> parse_signal("square:amp=500,freq=2", maximum=5000.0)
    SquareWave(amplitude=500.0, frequency=2.0, offset=0.0, duty=0.5, phase=0.0)
    >>> parse_signal("square:frac=0.1,freq=2", maximum=5000.0)
    SquareWave(amplitude=500.0, frequency=2.0, offset=0.0, duty=0.5, phase=0.0)
    >>> parse_signal("sine:amp=0.05,freq=5,offset=1")
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
    """Pop amp/frac/value/max from `params` and return the amplitude in the input's unit."""
    given = {key: params.pop(key) for key in ("amp", "frac", "value") if key in params}
    top = params.pop("max", maximum)
    if len(given) > 1:
        raise _spec_error(spec, f"give one of amp= (in the input's unit) or frac= (a fraction of its maximum), "
                          f"not {' and '.join(f'{k}=' for k in given)}")
    if not given:
        raise _spec_error(spec, "missing amplitude: add amp= (in the input's unit) or frac= (a fraction of the "
                          f"input's maximum); e.g. {kind.example}")
    [(key, number)] = given.items()
    known = top is not None and not isinstance(top, bool) and isinstance(top, numbers.Real) and \
        0.0 < float(top) < math.inf
    if key == "amp" and known and -1.0 <= number <= 1.0 and float(top) != 1.0:
        # cosim < 0.2 read amp as a fraction of the maximum: an old script's amp=0.1 keeps meaning 10 % of it
        warnings.warn(f"signal spec {spec!r}: amp={number:g} is read as a fraction of the input's maximum "
                      f"{float(top):g} ({number * float(top):g} in its unit), as before cosim 0.2; amp is now in "
                      f"the input's unit: write frac={number:g} for this, or value={number:g} for {number:g} in "
                      "its unit", CosimDeprecationWarning, stacklevel=4)
        key = "frac"
    if key != "frac":
        return number
    if not -1.0 <= number <= 1.0:
        raise _spec_error(spec, f"frac={number:g} is outside -1..1; frac is a fraction of the input's maximum, "
                          "use amp= for an amplitude in the input's unit")
    if top is None:
        raise _spec_error(spec, f"frac={number:g} is a fraction of the input's maximum but the input declares no "
                          "maximum; add max=VALUE to the spec or give the amplitude in the input's unit with amp=")
    if not known:
        raise _spec_error(spec, f"the input's maximum is {top!r} but frac= needs a positive finite maximum; "
                          "add max=VALUE or use amp=")
    return number * float(top)


def signal_kinds_help() -> str:
    """Text listing every signal kind with its keys and an example, for ``--help``.

    Examples
    --------
    >>> from cosim.data.signals import signal_kinds_help
    >>> print(signal_kinds_help().splitlines()[1])
      square: square wave offset ± amplitude; e.g. square:amp=500,freq=2
    """
    lines = ["Signal specs kind:key=value,...: amp= in the input's unit, frac= a fraction of its maximum"]
    for kind in SIGNAL_KINDS.values():
        lines.append(f"  {kind.name}: {kind.summary}; e.g. {kind.example}")
        own = [f"{key}: {meaning}" for key, meaning in kind.keys.items() if key not in _AMPLITUDE_KEYS]
        if own:
            lines.append("      " + "; ".join(own))
    lines.append("  a bare number, e.g. 3.5: a constant in the input's unit")
    return "\n".join(lines)
