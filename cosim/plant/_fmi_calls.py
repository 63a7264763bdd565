"""One variable's value through the FMI calls of its type, FMI 2.0 or 3.0, and the names of the calls' statuses.

* :data:`REAL_TYPES`, :data:`INT_TYPES` - the FMI variable types cosim reads and writes as floats and ints
  (booleans too);
* :func:`coerce` - a value checked and converted for a variable's type, before it is set;
* :func:`write_value`, :func:`read_value` - through ``setReal``/``setFloat64``, ``getInteger``/``getInt32``...;
* :func:`status_name` - ``"ok"``, ``"warning"``... for the status an FMI call returns.
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import InvalidSettingError

STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
REAL_TYPES = ("Real", "Float64")
INT_TYPES = ("Integer", "Enumeration", "Int32", "Int64", "Int16", "Int8", "UInt8", "UInt16", "UInt32",
             "UInt64")


def status_name(status: int) -> str:
    """The name of an FMI status code, e.g. ``"error"`` for 3."""
    return STATUS[status] if 0 <= status < len(STATUS) else f"illegal status {status}"


def coerce(var: Any, value: Any) -> Any:
    """`value` as the Python type of `var` (an FMPy ``ModelVariable``), or InvalidSettingError saying why not."""
    if var.type in REAL_TYPES or var.type == "Float32":
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"{var.name} takes a number, got {value!r}") from None
        if not math.isfinite(value):
            raise InvalidSettingError(f"{var.name} must be finite, got {value}")
        return value
    if var.type in INT_TYPES:
        if isinstance(value, bool) or float(value) != int(float(value)):
            raise InvalidSettingError(f"{var.name} takes a whole number, got {value!r}")
        return int(float(value))
    if var.type == "Boolean":
        if value not in (0, 1, True, False):
            raise InvalidSettingError(f"{var.name} takes true/false or 0/1, got {value!r}")
        return bool(value)
    raise InvalidSettingError(f"{var.name} is of type {var.type}, which cosim does not set; "
                              "only real, integer and boolean variables can be set")


def write_value(fmu: Any, fmi_version: str, var: Any, value: Any) -> None:
    """Set one variable of the FMPy slave `fmu` through the FMI call of its type."""
    vr = [var.valueReference]
    if var.type in REAL_TYPES:
        (fmu.setReal if fmi_version == "2.0" else fmu.setFloat64)(vr, [value])
    elif var.type == "Float32":
        fmu.setFloat32(vr, [value])
    elif var.type in INT_TYPES:
        if fmi_version == "2.0":
            fmu.setInteger(vr, [value])
        else:
            getattr(fmu, "set" + ("Int64" if var.type == "Enumeration" else var.type))(vr, [value])
    else:
        fmu.setBoolean(vr, [value])


def read_value(fmu: Any, fmi_version: str, var: Any) -> Any:
    """The current value of one variable of the FMPy slave `fmu`, through the FMI call of its type."""
    vr = [var.valueReference]
    if var.type in REAL_TYPES:
        return (fmu.getReal if fmi_version == "2.0" else fmu.getFloat64)(vr)[0]
    if var.type == "Float32":
        return fmu.getFloat32(vr)[0]
    if var.type in INT_TYPES:
        getter = fmu.getInteger if fmi_version == "2.0" else getattr(
            fmu, "get" + ("Int64" if var.type == "Enumeration" else var.type))
        return int(getter(vr)[0])
    if var.type == "Boolean":
        return bool(fmu.getBoolean(vr)[0])
    raise InvalidSettingError(f"{var.name} is of type {var.type}, which cosim does not read")
