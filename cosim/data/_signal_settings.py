"""Checks of excitation signals' settings: each returns the normalised value or raises.

The signal classes (:mod:`~cosim.data._waveforms`), the multisine design (:mod:`~cosim.data._multisine`) and the
factories (:mod:`~cosim.data._signal_factories`) check their settings with these; a message names the setting,
what it got and what to pass instead (:class:`~cosim.errors.InvalidSettingError`).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import InvalidSettingError


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
