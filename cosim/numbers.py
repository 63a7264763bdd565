"""Parse numbers written by people on command lines and in specs: ``0.3``, ``1e-3``, ``1/2257``.

No ``eval``: a number, or a fraction of two numbers.

Examples
--------
>>> parse_number("1/2257") == 1 / 2257
True
>>> parse_number("-2.5e3")
-2500.0
"""

from __future__ import annotations

import math
from typing import Any

from .errors import InvalidSettingError

__all__ = ["finite_number", "parse_number"]


def parse_number(text: str | float, *, what: str = "value") -> float:
    """Return the finite float that `text` writes (a number or ``a/b``).

    Raises
    ------
    InvalidSettingError
        Naming `what` and the text, when it is not a finite number or fraction.
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        value = float(text)
    else:
        parts = str(text).strip().split("/")
        try:
            if len(parts) == 1:
                value = float(parts[0])
            elif len(parts) == 2:
                value = float(parts[0]) / float(parts[1])
            else:
                raise ValueError
        except (ValueError, ZeroDivisionError):
            raise InvalidSettingError(f"{what}: {text!r} is not a number; write e.g. 0.5, 1e-3 or 1/2257") from None
    if not math.isfinite(value):
        raise InvalidSettingError(f"{what}: {text!r} is not a finite number")
    return value


def finite_number(value: Any, name: str, *, low: float | None = None, strict: bool = False) -> float:
    """`value` as a finite float, at least (or, with `strict`, above) `low`; InvalidSettingError otherwise.

    Examples
    --------
    >>> finite_number("2.5", "kp", low=0.0)
    2.5
    >>> finite_number(-1, "kp", low=0.0)
    Traceback (most recent call last):
    cosim.errors.InvalidSettingError: kp must be >= 0, got -1
    """
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InvalidSettingError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise InvalidSettingError(f"{name} must be finite, got {value!r}")
    if low is not None and (x <= low if strict else x < low):
        raise InvalidSettingError(f"{name} must be {'>' if strict else '>='} {low:g}, got {x:g}")
    return x
