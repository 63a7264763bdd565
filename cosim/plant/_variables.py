"""An FMU's variables as the signals cosim drives and records: scalars by name, FMI 3 arrays element by element.

* :func:`kind_of` - ``"float"``, ``"int"``, ``"bool"``, ``"string"`` or ``"binary"`` for an FMI type (FMI 2
  Real/Integer/Boolean/String/Enumeration; FMI 3 Float32/Float64, Int8-Int64, UInt8-UInt64, Boolean, String,
  Binary, Enumeration);
* :class:`Signal` - one named value: a scalar variable, or one element of an array variable (``A[1,2]``,
  row-major, indices from 1 as the FMU's dimensions and Modelica count them);
* :func:`expand_signals` - every signal of a model description, in its order;
* :func:`array_value` - a whole array given as nested lists (``[[1, 0], [0, 1]]``) checked against its shape
  and flattened row-major, as FMI 3 passes array values.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidSettingError, UnknownVariableError

__all__ = ["Signal", "array_value", "element_name", "expand_signals", "kind_of"]

_KINDS = {"Real": "float", "Float64": "float", "Float32": "float", "Boolean": "bool", "String": "string",
          "Binary": "binary", "Integer": "int", "Enumeration": "int"}
NUMERIC = ("float", "int", "bool")


def kind_of(fmi_type: str) -> str:
    """What a value of the FMI type `fmi_type` is in Python: float, int, bool, string or binary.

    Examples
    --------
    >>> kind_of("UInt16"), kind_of("Real"), kind_of("Boolean")
    ('int', 'float', 'bool')
    """
    if fmi_type in _KINDS:
        return _KINDS[fmi_type]
    if fmi_type.startswith(("Int", "UInt")):
        return "int"
    return "other"  # a Clock: neither set nor recorded


@dataclass(frozen=True)
class Signal:
    """One value of an FMU: a scalar variable (``offset`` None) or one element of an array variable."""

    name: str
    var: Any  # fmpy's ModelVariable
    offset: int | None = None  # row-major position in the array
    shape: tuple[int, ...] = ()  # the array's shape, () for a scalar

    @property
    def kind(self) -> str:
        return kind_of(self.var.type)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape)) if self.shape else 1


def element_name(name: str, index: tuple[int, ...]) -> str:
    """``A`` and (0, 1) -> ``A[1,2]`` (indices from 1, as in the FMU's model description and Modelica).

    Examples
    --------
    >>> element_name("A", (0, 1)), element_name("u", (2,))
    ('A[1,2]', 'u[3]')
    """
    return f"{name}[{','.join(str(i + 1) for i in index)}]"


def shape_of(var: Any, values: dict[str, Any]) -> tuple[int, ...]:
    """The shape of an FMI 3 array variable: each dimension's fixed start, or its structural parameter's value."""
    shape = []
    for dim in var.dimensions:
        if dim.start is not None:
            shape.append(int(dim.start))
            continue
        size = values.get(dim.variable.name, dim.variable.start)
        shape.append(int(float(size)))
    return tuple(shape)


def expand_signals(model_variables: list[Any]) -> dict[str, Signal]:
    """Name -> :class:`Signal` for every variable, arrays expanded into their elements (row-major).

    An array variable is also listed under its own name (``A``, offset None, its shape), so that a whole array
    can be set by name; its elements are the signals recorded and driven.
    """
    values = {v.name: v.start for v in model_variables}
    out: dict[str, Signal] = {}
    for var in model_variables:
        if not getattr(var, "dimensions", None):
            out[var.name] = Signal(var.name, var)
            continue
        shape = shape_of(var, values)
        out[var.name] = Signal(var.name, var, None, shape)
        for offset, index in enumerate(np.ndindex(*shape)):
            name = element_name(var.name, index)
            out[name] = Signal(name, var, offset, shape)
    return out


def array_value(signal: Signal, value: Any) -> list[Any]:
    """A whole array's value (nested lists, or a flat list of its size) flattened row-major, shape checked.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> a = Signal("A", SimpleNamespace(name="A", type="Float64"), None, (2, 2))
    >>> array_value(a, [[1, 2], [3, 4]])
    [1, 2, 3, 4]
    """
    array = np.asarray(value, dtype=object)
    if array.shape != signal.shape and array.shape != (signal.size,):
        dims = "x".join(map(str, signal.shape))
        raise InvalidSettingError(f"{signal.name} is a {dims} array; got a value of shape "
                                  f"{'x'.join(map(str, array.shape)) or 'scalar'} (write e.g. "
                                  f"{signal.name}=[[...],[...]] row by row, or set one element {signal.name}"
                                  f"[{','.join(['1'] * len(signal.shape))}]=...)")
    return array.ravel().tolist()


def unknown_element(name: str, signals: dict[str, Signal]) -> UnknownVariableError | None:
    """The error for an array element out of range (``A[4,1]`` of a 3x3 ``A``), else None."""
    base, bracket, _ = name.partition("[")
    array = signals.get(base)
    if not bracket or array is None or not array.shape:
        return None
    dims = "x".join(map(str, array.shape))
    return UnknownVariableError(f"{name} is out of range: {base} is a {dims} array, its elements are "
                                f"{element_name(base, (0,) * len(array.shape))} to "
                                f"{element_name(base, tuple(s - 1 for s in array.shape))} (indices from 1)")
