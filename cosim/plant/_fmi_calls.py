"""One variable's value through the FMI calls of its type, FMI 2.0 or 3.0, and the names of the calls' statuses.

* :data:`REAL_TYPES` - the FMI types of the 64-bit floats that FmuPlant's fast path steps;
* :func:`coerce` - a value checked and converted for a variable's type, before it is set;
* :func:`write_value`, :func:`read_value` - through ``setReal``/``setFloat64``, ``getInteger``/``getInt32``...;
* :func:`status_name` - ``"ok"``, ``"warning"``... for the status an FMI call returns.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import InvalidSettingError
from ..numbers import WrittenNumber
from ._variables import kind_of

STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
REAL_TYPES = ("Real", "Float64")


def status_name(status: int) -> str:
    """The name of an FMI status code, e.g. ``"error"`` for 3."""
    return STATUS[status] if 0 <= status < len(STATUS) else f"illegal status {status}"


def coerce(var: Any, value: Any) -> Any:
    """`value` as the Python type of `var` (an FMPy ``ModelVariable``), or InvalidSettingError saying why not.

    Numbers for Float and integer variables (a whole number for an integer, within its type's range), true/false
    or 0/1 for a Boolean, text for a String, bytes or their hex digits as text for a Binary (a number is refused:
    ``626172`` could be hex digits or not; a :class:`~cosim.numbers.WrittenNumber`, read from a command line,
    gives its text to a String or a Binary).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> coerce(SimpleNamespace(name="n", type="UInt8"), 7.0), coerce(SimpleNamespace(name="b", type="Boolean"), 1)
    (7, True)
    """
    kind = kind_of(var.type)
    if kind == "float":
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"{var.name} takes a number, got {value!r}") from None
        if not math.isfinite(value):
            raise InvalidSettingError(f"{var.name} must be finite, got {value}")
        return value
    if kind == "int":
        try:
            whole = isinstance(value, (int, np.integer)) or float(value) == int(float(value))
        except (TypeError, ValueError, OverflowError):
            whole = False
        if isinstance(value, bool) or not whole:
            raise InvalidSettingError(f"{var.name} takes a whole number, got {value!r}")
        number = int(value) if isinstance(value, (int, np.integer)) else int(float(value))
        low, high = _int_range(var.type)
        if not low <= number <= high:
            raise InvalidSettingError(f"{var.name} is {var.type}: {number} is outside {low}..{high}")
        return number
    if kind == "bool":
        if isinstance(value, str) and value.strip().lower() in ("true", "false"):
            return value.strip().lower() == "true"
        if value not in (0, 1, True, False):
            raise InvalidSettingError(f"{var.name} takes true/false or 0/1, got {value!r}")
        return bool(value)
    if isinstance(value, WrittenNumber):  # a number read from text (--set): a String or a Binary takes the text
        value = value.text
    if kind == "string":
        if not isinstance(value, str):
            raise InvalidSettingError(f"{var.name} is a String variable: it takes text, got {value!r}")
        return value
    if kind == "binary":
        if isinstance(value, (bytes, bytearray)):
            return bytes(value)
        if not isinstance(value, str):
            raise InvalidSettingError(f"{var.name} is a Binary variable: give bytes (b'bar') or their hex digits as "
                                      f"text ('626172'), got the {type(value).__name__} {value!r}")
        try:
            return bytes.fromhex(value)
        except ValueError:
            raise InvalidSettingError(f"{var.name} is a Binary variable: give bytes or their hex digits "
                                      f"(e.g. 666f6f), got {value!r}") from None
    raise InvalidSettingError(f"{var.name} is of type {var.type}, which cosim does not set")


def _int_range(fmi_type: str) -> tuple[int, int]:
    """The range of an FMI integer type (FMI 2 Integer and Enumeration are 32-bit; FMI 3 Enumeration 64-bit)."""
    if fmi_type in ("Integer", "Enumeration"):
        fmi_type = "Int32" if fmi_type == "Integer" else "Int64"
    info = np.iinfo(fmi_type.lower())
    return int(info.min), int(info.max)


def _call(fmi_version: str, var: Any) -> str:
    """The suffix of the FMI call for `var`'s type: ``Real``, ``Float64``, ``Integer``, ``Int16``..."""
    kind = kind_of(var.type)
    if fmi_version == "2.0":
        return {"float": "Real", "int": "Integer", "bool": "Boolean", "string": "String"}[kind]
    return "Int64" if var.type == "Enumeration" else var.type


def write_value(fmu: Any, fmi_version: str, var: Any, value: Any) -> None:
    """Set one variable of the FMPy slave `fmu` through the FMI call of its type (an array: its flat values)."""
    values = list(value) if isinstance(value, (list, tuple)) else [value]  # FMPy encodes strings itself
    getattr(fmu, "set" + _call(fmi_version, var))([var.valueReference], values)


def read_value(fmu: Any, fmi_version: str, var: Any, size: int | None = None) -> Any:
    """The current value of one variable of the FMPy slave `fmu`: a scalar, or the list of an array's `size`."""
    kind = kind_of(var.type)
    if kind == "other":
        raise InvalidSettingError(f"{var.name} is of type {var.type}, which cosim does not read")
    getter = getattr(fmu, "get" + _call(fmi_version, var))
    values = getter([var.valueReference]) if size is None else getter([var.valueReference], nValues=size)
    cast = {"float": float, "int": int, "bool": bool,
            "string": lambda v: v.decode("utf-8") if isinstance(v, bytes) else v, "binary": bytes}[kind]
    values = [cast(v) for v in values]
    return values if size is not None else values[0]
