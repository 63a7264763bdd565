"""Parse numbers written by people on command lines and in specs: ``0.3``, ``1e-3``, ``1/2257``; and
:func:`check_memory`, which refuses up front an array of numbers the machine cannot hold.

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
import os
from typing import Any

from .errors import InvalidSettingError

__all__ = ["MEMORY_FRACTION", "WrittenNumber", "available_memory", "check_memory", "finite_number", "parse_number"]

#: The share of the machine's available memory one array of results may take (the rest: copies, the OS).
MEMORY_FRACTION = 0.5


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``, else the physical memory), or
    None where neither can be read. ``COSIM_MEMORY_LIMIT`` (bytes) overrides it."""
    if os.environ.get("COSIM_MEMORY_LIMIT"):
        return int(parse_number(os.environ["COSIM_MEMORY_LIMIT"], what="COSIM_MEMORY_LIMIT"))
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(n_values: float, *, what: str, hint: str, fraction: float = MEMORY_FRACTION) -> None:
    """Refuse, before allocating, `n_values` float64 numbers that would take more than `fraction` of the
    available memory: an :class:`~cosim.errors.InvalidSettingError` with both figures and `hint`.

    Examples
    --------
    >>> check_memory(1e3, what="a simulation of 1000 samples", hint="use a larger dt")
    >>> check_memory(1e20, what="a simulation of 1e20 values", hint="use a larger dt")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    cosim.errors.InvalidSettingError: a simulation of 1e20 values needs 8e+11 GB, more than 50% of ...; use a larger dt
    """
    available = available_memory()
    need = 8.0 * float(n_values)
    if available is not None and need > fraction * available:
        raise InvalidSettingError(f"{what} needs {need / 1e9:.3g} GB, more than {fraction:.0%} of the "
                                  f"{available / 1e9:.3g} GB this machine has available; {hint}")


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


class WrittenNumber(float):
    """A number read from text that keeps the text: a float everywhere, and its `text` for a variable that takes
    text, whatever it looks like (a String's value, a Binary's hex digits: ``--set Binary_input=626172``).

    Examples
    --------
    >>> n = WrittenNumber(parse_number("626172"), "626172")
    >>> n + 1, n.text
    (626173.0, '626172')
    """

    text: str

    def __new__(cls, value: float, text: str) -> WrittenNumber:
        number = super().__new__(cls, value)
        number.text = str(text)
        return number

    def __reduce__(self) -> tuple[type, tuple[float, str]]:
        return WrittenNumber, (float(self), self.text)


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
