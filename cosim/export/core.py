"""Export an :class:`~cosim.identify.model.IdentifiedModel` to python-control, MATLAB and FMI.

* :func:`to_statespace` - a named ``control.StateSpace`` (continuous, or discrete by exact zero-order hold),
  outputs = the states. A nonlinear model is linearised at an operating point (analytic Jacobian).
* :func:`operating_point` - an equilibrium of the model (states, and inputs where the states alone cannot
  balance the constant term).
* :func:`export_mat` - a MATLAB ``.mat`` file with ``A, B, C, D, dt`` and the signal names as cell arrays.
* :func:`export_fmu` - an FMI 2.0 co-simulation FMU generated as C from the model and compiled, stepping
  exactly like :meth:`IdentifiedModel.simulate <cosim.identify.model.IdentifiedModel.simulate>`.
* :func:`export` - one of the above (or the model's JSON) chosen by the file suffix.

The constant term
-----------------
A constant the regression found (``c`` in ``dx/dt = A x + B u + c``) is never dropped silently. The
`constant` option of :func:`to_statespace` and :func:`export_mat` says what becomes of it:

``"input"`` (default)
    An extra input named ``"const"`` (:data:`CONSTANT_INPUT`) with B column ``c``: **feed 1 on it**.
``"operating_point"``
    The model about its equilibrium (:func:`operating_point`): states and inputs are deviations from the
    equilibrium, stored as ``sys.operating_point``; no constant remains.
``"ignore"``
    Drop it; only when asked for by name.

A model whose constant is zero gets nothing extra, whatever the mode.

Inputs are held between samples (zero-order hold) everywhere, as in the rest of cosim.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 2.0]]))
>>> sys = to_statespace(model)
>>> sys.A.tolist(), sys.B.tolist(), sys.input_labels, sys.output_labels
([[-1.0]], [[2.0]], ['u'], ['x'])
"""

from __future__ import annotations

import ast
import math
import os
import re
import tempfile
import uuid
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import control
import numpy as np
from scipy.linalg import expm

from ..errors import InvalidSettingError, UnknownVariableError
from ..files import atomic_output
from ..identify.model import DIVERGENCE_LIMIT, IdentifiedModel
from ..identify.terms import FUNCTIONS, Term
from ..plant.toolchain import compile_library, find_compiler, platform_info, write_zip

__all__ = [
    "CONSTANT_INPUT",
    "CONSTANT_MODES",
    "OperatingPoint",
    "export",
    "export_fmu",
    "export_mat",
    "operating_point",
    "to_statespace",
]

#: Name of the extra input that carries the constant term (``constant="input"``): hold it at 1.
CONSTANT_INPUT = "const"
#: What :func:`to_statespace` can do with a non-zero constant term.
CONSTANT_MODES = ("input", "operating_point", "ignore")
#: A residual below this fraction of the size of the terms that cancel counts as zero.
_EQUILIBRIUM_RTOL = 1e-10


# ---------------------------------------------------------------------------------------------- operating point
@dataclass(frozen=True)
class OperatingPoint:
    """A point ``(x, u)`` of a model and its derivative there (zero at an equilibrium).

    Attributes
    ----------
    states, inputs : mapping of str to float
        State and input values by name.
    derivatives : mapping of str to float
        ``dx/dt`` at the point, by state name.
    """

    states: Mapping[str, float]
    inputs: Mapping[str, float]
    derivatives: Mapping[str, float] = field(default_factory=dict)

    @property
    def x(self) -> np.ndarray:
        """The states as an array, in the model's order."""
        return np.array(list(self.states.values()), dtype=float)

    @property
    def u(self) -> np.ndarray:
        """The inputs as an array, in the model's order."""
        return np.array(list(self.inputs.values()), dtype=float)

    def to_dict(self) -> dict[str, dict[str, float]]:
        """Plain dictionaries (JSON-ready)."""
        return {"states": dict(self.states), "inputs": dict(self.inputs), "derivatives": dict(self.derivatives)}


def _point(model: IdentifiedModel, x: np.ndarray, u: np.ndarray) -> OperatingPoint:
    dx = model.rhs(x, u)
    return OperatingPoint(dict(zip(model.states, map(float, x), strict=True)),
                          dict(zip(model.inputs, map(float, u), strict=True)),
                          dict(zip(model.states, map(float, dx), strict=True)))


def _vector(values: Any, names: Sequence[str], role: str) -> np.ndarray:
    """A mapping by name or an array -> array in the order of `names`."""
    if isinstance(values, Mapping):
        unknown = [k for k in values if k not in names]
        if unknown:
            raise UnknownVariableError(f"operating point: {unknown[0]!r} is not a {role} of the model "
                                       f"({', '.join(names) or 'none'})")
        missing = [k for k in names if k not in values]
        if missing:
            raise InvalidSettingError(f"operating point: no value for the {role} {', '.join(missing)}; give every "
                                      f"{role} ({', '.join(names)})")
        values = [values[k] for k in names]
    try:
        array = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InvalidSettingError(f"operating point: the {role}s must be numbers, got {values!r}") from None
    if array.shape != (len(names),) or not np.all(np.isfinite(array)):
        raise InvalidSettingError(f"operating point: expected {len(names)} finite {role} values "
                                  f"({', '.join(names)}), got {array.tolist()}")
    return array


def _parse_point(model: IdentifiedModel, point: Any) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(point, OperatingPoint):
        return _vector(point.states, model.states, "state"), _vector(point.inputs, model.inputs, "input")
    if not (isinstance(point, Sequence) and not isinstance(point, str) and len(point) == 2):
        raise InvalidSettingError("operating_point must be (x_op, u_op), each a mapping by name or an array, or an "
                                  f"OperatingPoint; got {point!r}")
    return _vector(point[0], model.states, "state"), _vector(point[1], model.inputs, "input")


def _term_scale(model: IdentifiedModel, x: np.ndarray, u: np.ndarray) -> float:
    """Size of the terms whose sum is dx/dt: a residual is judged against it."""
    theta = model.features(x[None, :], u[None, :] if len(u) else np.zeros((1, 0)))[0]
    return float(np.linalg.norm(np.abs(model.coef) @ np.abs(theta)))


def _negligible(model: IdentifiedModel, f: np.ndarray, x: np.ndarray, u: np.ndarray, scale0: float = 0.0) -> bool:
    return bool(np.linalg.norm(f) <= _EQUILIBRIUM_RTOL * max(_term_scale(model, x, u), scale0))


def _newton(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, free: np.ndarray,
            scale0: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """Solve rhs(x, u) = 0 for the variables flagged in `free`: minimum-norm Newton steps with backtracking,
    until the residual stops falling; success if it is negligible (:func:`_negligible`)."""
    n = len(x)
    z = np.concatenate([x, u])
    f = model.rhs(z[:n], z[n:])
    for _ in range(100):
        norm = np.linalg.norm(f)
        if norm <= 1e-15 * max(_term_scale(model, z[:n], z[n:]), scale0):
            break
        jac = np.hstack(_jacobian(model, z[:n], z[n:]))[:, free]
        step = np.linalg.lstsq(jac, -f, rcond=None)[0]
        t = 1.0
        for _ in range(40):  # backtrack while the residual grows (steep friction terms)
            trial = z.copy()
            trial[free] += t * step
            f_trial = model.rhs(trial[:n], trial[n:])
            if np.all(np.isfinite(f_trial)) and np.linalg.norm(f_trial) < norm:
                break
            t *= 0.5
        else:
            break  # no further progress: roundoff, or no solution
        z, f = trial, f_trial
    return z[:n], z[n:], _negligible(model, f, z[:n], z[n:], scale0)


def operating_point(model: IdentifiedModel, *, near: Any = None,
                    free_inputs: Sequence[str] | None = None) -> OperatingPoint:
    """An equilibrium ``dx/dt = 0`` of the model: states first, inputs only where the states cannot do it.

    The states are solved for first (minimum-norm Newton steps from `near`; for a linear model one step, the
    least-squares solution of ``A x = -c``). If the states alone cannot balance the model - a singular ``A``
    such as a rigid-body mode under a constant torque offset - the states and one input are solved for,
    trying the `free_inputs` one at a time in the model's order, then all of them together (minimum norm over
    states and inputs, in their own units). Pass `free_inputs` to choose which input trims the model.

    Parameters
    ----------
    model : IdentifiedModel
    near : (x, u) or OperatingPoint, optional
        Where to start (each a mapping by name or an array); default all zero. Among many equilibria (a
        singular ``A``) the one found is the closest to `near` in the minimum-norm sense.
    free_inputs : sequence of str, optional
        The inputs that may move if the states cannot balance the model; default all.

    Returns
    -------
    OperatingPoint
        With ``derivatives`` (the residual dx/dt) below 1e-10 of the size of the terms that cancel.

    Raises
    ------
    InvalidSettingError
        If no equilibrium is found (the constant cannot be balanced): keep the constant as an input instead.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("1", "x", "u"),
    ...                         coef=np.array([[2.0, -1.0, 1.0]]))
    >>> operating_point(model).states   # -x + 2 = 0
    {'x': 2.0}
    """
    x0, u0 = (np.zeros(len(model.states)), np.zeros(len(model.inputs))) if near is None else \
        _parse_point(model, near)
    free_inputs = model.inputs if free_inputs is None else tuple(free_inputs)
    for name in free_inputs:
        if name not in model.inputs:
            raise UnknownVariableError(f"free_inputs: {name!r} is not an input of the model "
                                       f"({', '.join(model.inputs) or 'none'})")
    n = len(model.states)
    scale0 = _term_scale(model, x0, u0)
    _jacobian(model, x0, u0)  # a term that cannot be evaluated at `near` fails here, with its name
    only_states = np.arange(n + len(model.inputs)) < n
    x, u, ok = _newton(model, x0, u0, only_states, scale0)
    trims = [[name] for name in model.inputs if name in free_inputs]
    trims += [list(free_inputs)] if len(trims) > 1 else []
    for trim in trims:
        if ok:
            break
        free = only_states | np.array([False] * n + [name in trim for name in model.inputs])
        x, u, ok = _newton(model, x0, u0, free, scale0)
    if not ok:
        residual = float(np.linalg.norm(model.rhs(x, u)))
        movable = f"states and the inputs {', '.join(free_inputs)}" if free_inputs else "states"
        raise InvalidSettingError(f"the model has no equilibrium near the start point: the {movable} cannot balance "
                                  f"it (residual |dx/dt| = {residual:.3g}); keep the constant as an input with "
                                  "constant='input'")
    return _point(model, x, u)


# ---------------------------------------------------------------------------------------------- Jacobian
def _derivative_of(name: str, v: float) -> float:
    """d/dv of the term function `name` at `v`."""
    if name == "sin":
        return math.cos(v)
    if name == "cos":
        return -math.sin(v)
    if name == "tan":
        return 1.0 + math.tan(v) ** 2
    if name == "exp":
        return math.exp(v)
    if name == "log":
        return 1.0 / v
    if name == "sqrt":
        return 0.5 / math.sqrt(v)
    if name == "abs":
        return float((v > 0) - (v < 0))
    if name == "tanh":
        return 1.0 - math.tanh(v) ** 2
    if name == "atan":
        return 1.0 / (1.0 + v * v)
    if name == "sign":
        return 0.0
    f, h = FUNCTIONS[name][1], 1e-6 * max(1.0, abs(v))  # a function added later: central difference
    return (f(v + h) - f(v - h)) / (2.0 * h)


def _dual(node: ast.AST, values: Mapping[str, float], index: Mapping[str, int], size: int):
    """Value and gradient of an expression (forward-mode differentiation over the checked term AST)."""
    if isinstance(node, ast.Constant):
        return float(node.value), np.zeros(size)
    if isinstance(node, ast.Name):
        grad = np.zeros(size)
        grad[index[node.id]] = 1.0
        return float(values[node.id]), grad
    if isinstance(node, ast.UnaryOp):
        v, g = _dual(node.operand, values, index, size)
        return (-v, -g) if isinstance(node.op, ast.USub) else (v, g)
    if isinstance(node, ast.Call):
        name = node.func.id  # type: ignore[attr-defined]
        v, g = _dual(node.args[0], values, index, size)
        return FUNCTIONS[name][1](v), _derivative_of(name, v) * g
    if isinstance(node, ast.BinOp):
        a, ga = _dual(node.left, values, index, size)
        b, gb = _dual(node.right, values, index, size)
        if isinstance(node.op, ast.Add):
            return a + b, ga + gb
        if isinstance(node.op, ast.Sub):
            return a - b, ga - gb
        if isinstance(node.op, ast.Mult):
            return a * b, b * ga + a * gb
        if isinstance(node.op, ast.Div):
            return a / b, ga / b - (a / (b * b)) * gb
        value = a ** b
        grad = (b * a ** (b - 1.0)) * ga if np.any(ga) else np.zeros(size)
        if np.any(gb):
            grad = grad + value * math.log(a) * gb
        return value, grad
    raise InvalidSettingError(f"cannot differentiate {ast.dump(node)}")  # unreachable: terms are checked


def _jacobian(model: IdentifiedModel, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(d rhs/dx, d rhs/du)`` at (x, u), analytic: forward-mode differentiation of every term."""
    names = model.states + model.inputs
    index = {name: i for i, name in enumerate(names)}
    values = dict(zip(names, [*map(float, x), *map(float, u)], strict=True))
    jac = np.zeros((len(model.states), len(names)))
    for k, text in enumerate(model.terms):
        if not np.any(model.coef[:, k]):
            continue
        try:
            _, grad = _dual(ast.parse(text, mode="eval").body, values, index, len(names))
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise InvalidSettingError(f"term {text!r} cannot be differentiated at the operating point ({exc}); "
                                      "choose another operating point") from None
        jac += np.outer(model.coef[:, k], grad)
    n = len(model.states)
    return jac[:, :n], jac[:, n:]


# ---------------------------------------------------------------------------------------------- state space
def _check_dt(dt: Any, what: str = "dt") -> float:
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not (math.isfinite(dt) and dt > 0):
        raise InvalidSettingError(f"{what} must be a positive number of seconds, got {dt!r}")
    return float(dt)


def _zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: the matrix exponential of ``[[A, B], [0, 0]]*dt`` (as
    :meth:`IdentifiedModel.discretize`, whose ``cd`` is the column of the constant input)."""
    n, m = a.shape[0], b.shape[1]
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = a, b
    phi = expm(big * dt)
    return phi[:n, :n], phi[:n, n:]


def _linearize(model: IdentifiedModel, point_arg: Any, constant: str):
    """A, B, the constant column (or None) and the point the signals are measured from."""
    if constant not in CONSTANT_MODES:
        raise InvalidSettingError(f"constant={constant!r} is not one of {', '.join(map(repr, CONSTANT_MODES))}; "
                                  "'input' keeps the constant as an input held at 1")
    n, m = len(model.states), len(model.inputs)
    if point_arg is None:
        if not model.is_linear:
            nonlinear = [t for k, t in enumerate(model.terms)
                         if t not in {"1", *model.states, *model.inputs} and np.any(model.coef[:, k])]
            raise InvalidSettingError(f"the model is nonlinear (terms {', '.join(nonlinear)}); pass "
                                      "operating_point=(x_op, u_op) to linearise it there")
        a, b, c = model.linear_matrices()
        x_op, u_op, scale = np.zeros(n), np.zeros(m), 0.0
    else:
        x_op, u_op = _parse_point(model, point_arg)
        if model.is_linear:
            a, b, _ = model.linear_matrices()
        else:
            a, b = _jacobian(model, x_op, u_op)
        c = model.rhs(x_op, u_op)
        scale = _term_scale(model, x_op, u_op)
    zero = not np.any(c) or (point_arg is not None and np.linalg.norm(c) <= _EQUILIBRIUM_RTOL * scale)
    if zero or constant == "ignore":
        return a, b, None, _point(model, x_op, u_op)
    if constant == "input":
        if CONSTANT_INPUT in model.inputs:
            raise InvalidSettingError(f"the model already has an input named {CONSTANT_INPUT!r}; rename it, or use "
                                      "constant='operating_point'")
        return a, b, c, _point(model, x_op, u_op)
    point = operating_point(model, near=None if point_arg is None else (x_op, u_op))
    if not model.is_linear:
        a, b = _jacobian(model, point.x, point.u)
    return a, b, None, point


def to_statespace(model: IdentifiedModel, *, dt: float | None = None, operating_point: Any = None,
                  constant: str = "input", name: str | None = None) -> control.StateSpace:
    """The model as a python-control ``StateSpace`` with named signals; outputs = the states (C = I, D = 0).

    Parameters
    ----------
    model : IdentifiedModel
    dt : float, optional
        Omit for the continuous system. With `dt`, the exact zero-order-hold discretisation, computed like
        :meth:`IdentifiedModel.discretize` (matrix exponential of the augmented matrix; equal to
        ``control.c2d(sys, dt, "zoh")``), so that it steps exactly like :meth:`IdentifiedModel.simulate`.
    operating_point : (x_op, u_op) or OperatingPoint, optional
        Where to linearise (each a mapping by name or an array). Required for a nonlinear model, optional for a
        linear one. With it, states and inputs are deviations from it, and the constant is ``rhs(x_op, u_op)``.
        The Jacobian is analytic (forward-mode differentiation of the terms).
    constant : {"input", "operating_point", "ignore"}
        What to do with a non-zero constant term ``c`` (see the module notes): ``"input"`` adds the input
        ``"const"`` (feed 1 on it) with B column ``c``; ``"operating_point"`` returns the deviation model about
        the equilibrium (:func:`operating_point`, started from `operating_point` if given; a nonlinear model is
        then linearised at the equilibrium); ``"ignore"`` drops it. To choose which input trims the model,
        pass ``operating_point=operating_point(model, free_inputs=[...])``: an equilibrium is kept as it is.
    name : str, optional
        The system's name (python-control's default otherwise).

    Returns
    -------
    control.StateSpace
        With an attribute ``operating_point`` (:class:`OperatingPoint`): the point its states and inputs are
        measured from (zero for a linear model without `operating_point` and constant "input"/"ignore").
        python-control's operations return new systems without it.

    Raises
    ------
    InvalidSettingError
        Nonlinear model without `operating_point`; unknown `constant`; no equilibrium for "operating_point".

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("1", "x", "u"),
    ...                         coef=np.array([[2.0, -1.0, 1.0]]))
    >>> sys = to_statespace(model, dt=0.1)
    >>> sys.input_labels, sys.dt
    (['u', 'const'], 0.1)
    >>> dev = to_statespace(model, constant="operating_point")
    >>> dev.input_labels, dev.operating_point.states
    (['u'], {'x': 2.0})
    """
    a, b, c, point = _linearize(model, operating_point, constant)
    inputs = list(model.inputs)
    if c is not None:
        b = np.column_stack([b, c])
        inputs.append(CONSTANT_INPUT)
    n = len(model.states)
    b = b.reshape(n, len(inputs))
    if dt is not None:
        a, b = _zoh(a, b, _check_dt(dt))
    options: dict[str, Any] = {"states": list(model.states), "inputs": inputs, "outputs": list(model.states)}
    if name is not None:
        options["name"] = str(name)
    args = (a, b, np.eye(n), np.zeros((n, len(inputs))))
    sys = control.ss(*args, dt, **options) if dt is not None else control.ss(*args, **options)
    sys.operating_point = point
    return sys


# ---------------------------------------------------------------------------------------------- MATLAB
def _cell(strings: Sequence[str]) -> np.ndarray:
    cell = np.empty((len(strings), 1), dtype=object)
    for i, s in enumerate(strings):
        cell[i, 0] = str(s)
    return cell


def export_mat(model: IdentifiedModel, path: str | os.PathLike, *, dt: float | None = None,
               operating_point: Any = None, constant: str = "input", name: str | None = None) -> Path:
    """Write the state-space model to a MATLAB ``.mat`` file (atomically).

    Variables: ``A, B, C, D``; ``dt`` (0 for continuous); ``StateName, InputName, OutputName`` (cell arrays of
    char: ``ss(A, B, C, D, dt, 'StateName', StateName, 'InputName', InputName, 'OutputName', OutputName)``
    builds it in MATLAB; use ``ss(A, B, C, D)`` for dt = 0); ``x_op, u_op`` (the point the signals are
    deviations from); ``Equations`` (cell of char, the identified equations); ``ConstantInput`` (``'const'``
    when the constant is an input held at 1, else empty); ``Notes`` (char).

    Parameters
    ----------
    model : IdentifiedModel
    path : path-like
        The ``.mat`` file.
    dt, operating_point, constant, name
        As in :func:`to_statespace`.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib, scipy.io
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 2.0]]))
    >>> path = export_mat(model, pathlib.Path(tempfile.mkdtemp()) / "model.mat")
    >>> scipy.io.loadmat(path)["B"].tolist()
    [[2.0]]
    """
    import scipy.io

    sys = to_statespace(model, dt=dt, operating_point=operating_point, constant=constant, name=name)
    has_const = CONSTANT_INPUT in sys.input_labels and CONSTANT_INPUT not in model.inputs
    notes = ("dx/dt = A x + B u" if sys.dt == 0 else "x[k+1] = A x[k] + B u[k] (zero-order hold)") + \
        ", y = C x + D u; y are the states; states and inputs are deviations from x_op, u_op" + \
        ("; hold the input 'const' at 1 (it carries the constant term)" if has_const else "")
    data = {
        "A": sys.A, "B": sys.B, "C": sys.C, "D": sys.D, "dt": float(sys.dt),
        "StateName": _cell(sys.state_labels), "InputName": _cell(sys.input_labels),
        "OutputName": _cell(sys.output_labels),
        "x_op": sys.operating_point.x.reshape(-1, 1), "u_op": sys.operating_point.u.reshape(-1, 1),
        "Equations": _cell(model.equations(precision=10)),
        "ConstantInput": CONSTANT_INPUT if has_const else "",
        "Notes": notes,
    }
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        scipy.io.savemat(fh, data, do_compression=True)
    return Path(path)


# ---------------------------------------------------------------------------------------------- FMU
_RESERVED = ("time", "nsub", "dt")
_WRAPPER = Path(__file__).with_name("templates") / "fmi2_wrapper.c"


def _fmi2_wrapper() -> str:
    """The generic FMI 2.0 co-simulation wrapper of every exported model (templates/fmi2_wrapper.c)."""
    return _WRAPPER.read_text(encoding="utf-8").replace("DIVERGENCE_LIMIT_VALUE", repr(float(DIVERGENCE_LIMIT)))
#: C functions the generated source can call (math.h, plus cosim_sign defined in model.c).
_C_FUNCTIONS = ("sin", "cos", "tan", "exp", "log", "sqrt", "fabs", "tanh", "atan", "cosim_sign")
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _check_fmu_names(model: IdentifiedModel) -> None:
    for role, names in (("state", model.states), ("input", model.inputs)):
        for name in names:
            why = ""
            if not name.strip():
                why = "is blank"
            elif any(ord(ch) < 32 or ord(ch) == 127 for ch in name):
                why = "holds a control character"
            elif name in _RESERVED or name.startswith("der("):
                why = f"is reserved in the exported FMU ({', '.join(_RESERVED)}, der(...))"
            if why:
                raise InvalidSettingError(f"cannot export to FMU: the {role} name {name!r} {why}; rename the {role} "
                                          "in the model")


def _check_fmu_terms(model: IdentifiedModel) -> None:
    for k, text in enumerate(model.terms):
        if not np.any(model.coef[:, k]):
            continue
        for node in ast.walk(ast.parse(text, mode="eval")):
            if isinstance(node, ast.Call):
                fname = node.func.id  # type: ignore[attr-defined]
                c_name = FUNCTIONS.get(fname, (None, None, None))[2]
                if c_name not in _C_FUNCTIONS:
                    supported = sorted(f for f, funcs in FUNCTIONS.items() if funcs[2] in _C_FUNCTIONS)
                    raise InvalidSettingError(f"cannot export to FMU: term {text!r} uses {fname}, which the generated "
                                              f"C cannot express (it knows {', '.join(supported)}); drop the term "
                                              "or export to .mat/.json instead")


def _c_string(text: str) -> str:
    out = []
    for byte in text.encode("utf-8"):
        ch = chr(byte)
        out.append(ch if 32 <= byte < 127 and ch not in '"\\?' else f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def _c_comment(text: str) -> str:
    return text.replace("*/", "* /")


def _identifier(path: Path, name: str | None) -> str:
    if name is not None:
        if not isinstance(name, str) or not _IDENTIFIER.fullmatch(name):
            raise InvalidSettingError(f"name={name!r} is not a valid FMU model identifier: use letters, digits and "
                                      "_ (not starting with a digit), e.g. 'servo_model'")
        return name
    stem = re.sub(r"[^A-Za-z0-9_]", "_", path.stem) or "model"
    return stem if _IDENTIFIER.fullmatch(stem) else "m_" + stem


def _model_sources(model: IdentifiedModel, identifier: str, guid: str, dt: float | None,
                   nsub: int) -> tuple[str, str]:
    """model.h and model.c of the exported FMU."""
    n, m = len(model.states), len(model.inputs)
    linear = model.is_linear
    header = "\n".join([
        f"/* {_c_comment(identifier)}: generated by cosim.export from an identified model; do not edit. */",
        "#ifndef COSIM_EXPORTED_MODEL_H",
        "#define COSIM_EXPORTED_MODEL_H",
        "",
        f"#define MODEL_IDENTIFIER {_c_string(identifier)}",
        f"#define MODEL_GUID {_c_string(guid)}",
        f"#define NX {n}",
        f"#define NU {m}",
        f"#define MODEL_LINEAR {int(linear)}",
        "/* linear: the step the exact zero-order-hold matrices were computed for; else the default step (0: none) */",
        f"#define MODEL_DT {float(dt or 0.0)!r}",
        f"#define MODEL_NSUB {int(nsub)}",
        "",
        "extern const char *const model_state_names[NX];",
        "/* dx/dt = f(x, u) */",
        "void model_rhs(const double x[], const double u[], double dx[]);",
        "#if MODEL_LINEAR",
        "/* x <- Ad x + Bd u + cd: one exact zero-order-hold step of MODEL_DT */",
        "void model_zoh_step(double x[], const double u[]);",
        "#endif",
        "",
        "#endif",
        "",
    ])
    names = {s: f"x[{i}]" for i, s in enumerate(model.states)}
    names.update({s: f"u[{j}]" for j, s in enumerate(model.inputs)})
    used = [k for k in range(len(model.terms)) if np.any(model.coef[:, k] != 0.0)]
    body = [f"    const double t{k} = {Term(model.terms[k]).to_c(names)};" for k in used]
    for i in range(n):
        parts = [f"{float(model.coef[i, k])!r}*t{k}" for k in used if model.coef[i, k] != 0.0]
        body.append(f"    dx[{i}] = {' + '.join(parts) if parts else '0.0'};")
    lines = [
        f"/* {_c_comment(identifier)}: generated by cosim.export; do not edit.",
        " *",
        " * dx/dt = coef @ theta(x, u), inputs held over each step (zero-order hold):",
        *[f" *   {_c_comment(eq)}" for eq in model.equations(precision=10)],
        " *",
        " * " + ("Linear: each step of MODEL_DT is the exact zero-order-hold map x <- Ad x + Bd u + cd, computed "
                 "in Python" if linear else "Nonlinear: classical RK4, nsub substeps per communication step"),
        " * (the same arithmetic as cosim's IdentifiedModel.simulate).",
        " */",
        "#include <math.h>",
        "",
        '#include "model.h"',
        "",
        "static double cosim_sign(double v) { return (double)((v > 0.0) - (v < 0.0)); }",
        "",
        "const char *const model_state_names[NX] = {" + ", ".join(_c_string(s) for s in model.states) + "};",
        "",
        "void model_rhs(const double x[], const double u[], double dx[]) {",
        "    (void)x;",
        "    (void)u;",
        "    (void)cosim_sign;",
        *body,
        "}",
        "",
    ]
    if linear:
        ad, bd, cd = model.discretize(float(dt))
        step = ["void model_zoh_step(double x[], const double u[]) {", "    double d[NX], y[NX];", "    int i;",
                "    (void)u;"]
        for i in range(n):
            drive = [f"{float(bd[i, j])!r}*u[{j}]" for j in range(m)] + [f"{float(cd[i])!r}"]
            step.append(f"    d[{i}] = {' + '.join(drive)};")
        for i in range(n):
            row = [f"{float(ad[i, j])!r}*x[{j}]" for j in range(n) if ad[i, j] != 0.0] + [f"d[{i}]"]
            step.append(f"    y[{i}] = {' + '.join(row)};")
        step += ["    for (i = 0; i < NX; ++i) x[i] = y[i];", "}", ""]
        lines += step
    return header, "\n".join(lines)


def _model_description(model: IdentifiedModel, identifier: str, guid: str, dt: float | None, nsub: int) -> bytes:
    from .. import __version__

    n, m = len(model.states), len(model.inputs)
    linear = model.is_linear
    how = (f"exact zero-order-hold steps of dt = {dt!r} s (doStep takes multiples of dt)" if linear
           else "classical RK4 with nsub substeps per communication step")
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier,
        "description": f"Identified model dx/dt = coef @ theta(x, u) exported by cosim; {how}",
        "guid": guid, "version": "1.0", "generationTool": f"cosim {__version__} (cosim.export)",
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier,
        "canHandleVariableCommunicationStepSize": "false" if linear else "true",
        "canInterpolateInputs": "false", "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "false", "canSerializeFMUstate": "false", "providesDirectionalDerivative": "false"})
    files = ET.SubElement(cs, "SourceFiles")
    for name in ("model.c", "fmi2.c"):
        ET.SubElement(files, "File", {"name": name})
    units = {str(model.units.get(s, "")) for s in model.states + model.inputs} - {""}
    units |= {f"{model.units[s]}/s" for s in model.states if model.units.get(s)} | {"s"}
    definitions = ET.SubElement(root, "UnitDefinitions")
    for unit in sorted(units):
        ET.SubElement(definitions, "Unit", {"name": unit})
    categories = ET.SubElement(root, "LogCategories")
    ET.SubElement(categories, "Category", {"name": "logStatusError", "description": "Errors (always logged)"})
    ET.SubElement(categories, "Category", {"name": "logCalls", "description": "Life-cycle calls (with loggingOn)"})
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0", **({"stepSize": repr(float(dt))} if dt else {})})
    variables = ET.SubElement(root, "ModelVariables")

    def real(name: str, vr: int, description: str, attrs: dict[str, str], real_attrs: dict[str, str]) -> None:
        var = ET.SubElement(variables, "ScalarVariable", {"name": name, "valueReference": str(vr),
                                                          "description": description, **attrs})
        ET.SubElement(var, "Real", real_attrs)

    def unit_of(name: str, suffix: str = "") -> dict[str, str]:
        unit = model.units.get(name)
        return {"unit": f"{unit}{suffix}"} if unit else {}

    real("time", 0, "Simulation time", {"causality": "independent", "variability": "continuous"}, {"unit": "s"})
    for j, name in enumerate(model.inputs):
        real(name, 1 + j, "Input, held over a communication step",
             {"causality": "input", "variability": "continuous"}, {**unit_of(name), "start": "0"})
    for i, name in enumerate(model.states):
        real(name, 1 + m + i, "State (the start value sets the initial state)",
             {"causality": "output", "variability": "continuous", "initial": "exact"}, {**unit_of(name), "start": "0"})
    for i, name in enumerate(model.states):
        real(f"der({name})", 1 + m + n + i, f"Derivative of {name}",
             {"causality": "local", "variability": "continuous"}, {"derivative": str(2 + m + i), **unit_of(name, "/s")})
    if linear:
        real("dt", 1 + m + 2 * n, "Step the exact zero-order-hold discretisation was computed for",
             {"causality": "local", "variability": "constant", "initial": "exact"},
             {"unit": "s", "start": repr(float(dt))})
    else:
        var = ET.SubElement(variables, "ScalarVariable", {
            "name": "nsub", "valueReference": str(2 + m + 2 * n), "description": "RK4 substeps per communication "
            "step, >= 1", "causality": "parameter", "variability": "fixed", "initial": "exact"})
        ET.SubElement(var, "Integer", {"start": str(int(nsub))})
    structure = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(structure, "Outputs")
    for i in range(n):
        ET.SubElement(outputs, "Unknown", {"index": str(2 + m + i), "dependencies": ""})
    derivatives = ET.SubElement(structure, "Derivatives")
    initial = ET.SubElement(structure, "InitialUnknowns")
    for i in range(n):
        ET.SubElement(derivatives, "Unknown", {"index": str(2 + m + n + i)})
        ET.SubElement(initial, "Unknown", {"index": str(2 + m + n + i)})
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def export_fmu(model: IdentifiedModel, path: str | os.PathLike, *, dt: float | None = None, nsub: int = 1,
               name: str | None = None) -> Path:
    """Generate, compile and pack an FMI 2.0 co-simulation FMU of the model (written atomically).

    The FMU steps exactly like :meth:`IdentifiedModel.simulate`, inputs held over each step:

    * a **linear** model (see :attr:`IdentifiedModel.is_linear`) with its exact zero-order-hold matrices
      ``Ad, Bd, cd`` for `dt`, computed in Python (:meth:`IdentifiedModel.discretize`) and embedded as double
      literals. ``doStep`` then accepts step sizes that are whole multiples of `dt` (1e-9 relative), one exact
      step per `dt`, and returns an error for others (export again with the step you need);
    * a **nonlinear** model with classical RK4, ``nsub`` substeps per communication step of any size (the
      parameter ``nsub``, default from `nsub`).

    Variables: the model's inputs (causality input, start 0), its states as outputs (``initial="exact"``:
    set their start values to set the initial state), ``der(<state>)`` (the right-hand side, declared with the
    ``derivative`` attribute so importers see the states), ``time``, and ``dt`` (a constant, linear) or
    ``nsub`` (a parameter, nonlinear). The terms are written as C with :meth:`Term.to_c
    <cosim.identify.terms.Term.to_c>` and the coefficients as double literals with ``repr`` precision. A state that
    passes 1e12 in magnitude or turns non-finite makes ``doStep`` fail (as the model's simulation diverges).
    The sources (``model.h``, ``model.c``, ``fmi2.c``) are in the FMU's ``sources/``; they are compiled with the
    same compiler and flags as the bundled plant (:mod:`cosim.plant.build`).

    Parameters
    ----------
    model : IdentifiedModel
    path : path-like
        The ``.fmu`` file to write; its stem becomes the model identifier unless `name` is given.
    dt : float, optional
        The step; default ``model.dt``. Required for a linear model; for a nonlinear one it is only the
        default step of the FMU.
    nsub : int
        RK4 substeps per step (nonlinear models; a linear one is exact).
    name : str, optional
        Model identifier (a C identifier), default from the file name.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    InvalidSettingError
        No `dt` for a linear model, ``nsub < 1``, or a name or term the FMU cannot express.
    BuildError
        No C compiler, or it failed.

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> from cosim import simulate
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 1.0]]))
    >>> fmu = export_fmu(model, pathlib.Path(tempfile.mkdtemp()) / "first_order.fmu", dt=0.01)
    >>> traj = simulate(fmu, {"u": 1.0}, duration=1.0, dt=0.01)
    >>> round(float(traj["x"][-1]), 6)   # 1 - exp(-1)
    0.632121
    """
    path = Path(path)
    dt = model.dt if dt is None else dt
    if dt is not None:
        dt = _check_dt(dt)
    elif model.is_linear:
        raise InvalidSettingError("export_fmu: a linear model is exported with its exact discretisation for one "
                                  "step; pass dt=... (the model has no dt of its own)")
    if isinstance(nsub, bool) or not isinstance(nsub, (int, np.integer)) or nsub < 1:
        raise InvalidSettingError(f"nsub must be a whole number >= 1, got {nsub!r}")
    identifier = _identifier(path, name)
    _check_fmu_names(model)
    _check_fmu_terms(model)
    wrapper = _fmi2_wrapper()
    fingerprint = f"{identifier}\n{dt!r}\n{int(nsub)}\n{model.to_json()}\n{wrapper}"
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "cosim-export:" + fingerprint)) + "}"
    header, source = _model_sources(model, identifier, guid, dt, int(nsub))
    description = _model_description(model, identifier, guid, dt, int(nsub))
    platform = platform_info(2)
    compiler = find_compiler()
    with tempfile.TemporaryDirectory(prefix="cosim-export-") as tmp:
        folder = Path(tmp)
        sources = {"model.h": header, "model.c": source, "fmi2.c": wrapper}
        for file_name, text in sources.items():
            (folder / file_name).write_text(text, encoding="utf-8")
        library = folder / (identifier + platform.extension)
        compile_library(compiler, [folder / "model.c", folder / "fmi2.c"], [folder], platform, library,
                        what=f"the exported model {identifier} (FMI 2)")
        members = [("modelDescription.xml", description, 0o644),
                   (f"binaries/{platform.folder}/{library.name}", library.read_bytes(), 0o755)]
        members += [(f"sources/{file_name}", text.encode("utf-8"), 0o644) for file_name, text in sources.items()]
        with atomic_output(path) as out, open(out, "wb") as fh:
            write_zip(fh, members)
    return path


# ---------------------------------------------------------------------------------------------- dispatch
_EXPORTERS = (".mat", ".fmu", ".json")


def export(model: IdentifiedModel, path: str | os.PathLike, **options: Any) -> Path:
    """Export by file suffix: ``.mat`` (:func:`export_mat`), ``.fmu`` (:func:`export_fmu`), ``.json``
    (:meth:`IdentifiedModel.save`, no options).

    Parameters
    ----------
    model : IdentifiedModel
    path : path-like
    **options
        Keyword options of the chosen exporter.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-1.0]]))
    >>> export(model, pathlib.Path(tempfile.mkdtemp()) / "model.json").suffix
    '.json'
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return export_mat(model, path, **options)
    if suffix == ".fmu":
        return export_fmu(model, path, **options)
    if suffix == ".json":
        if options:
            raise InvalidSettingError(f"a .json export takes no options, got {', '.join(options)}; it saves the "
                                      "model as it is")
        return model.save(path)
    raise InvalidSettingError(f"cannot export to {path.name!r}: unknown suffix {path.suffix or '(none)'!r}; "
                              f"use one of {', '.join(_EXPORTERS)}")
