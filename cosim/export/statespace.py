"""The state-space form of an :class:`~cosim.identify.model.IdentifiedModel`, which the file exports build on.

* :func:`to_statespace` - a named ``control.StateSpace`` (continuous, or discrete by exact zero-order hold),
  outputs = the states. A nonlinear model is linearised at an operating point (analytic Jacobian,
  :mod:`~cosim.export.jacobian`).
* :func:`operating_point` - an equilibrium of the model (states, and inputs where the states alone cannot
  balance the constant term).

The constant term
-----------------
A constant the regression found (``c`` in ``dx/dt = A x + B u + c``) is never dropped silently. The
`constant` option of :func:`to_statespace` and :func:`~cosim.export.matlab.export_mat` says what becomes of it:

``"input"`` (default)
    An extra input named ``"const"`` (:data:`CONSTANT_INPUT`) with B column ``c``: **feed 1 on it**.
``"operating_point"``
    The model about its equilibrium (:func:`operating_point`): states and inputs are deviations from the
    equilibrium, stored as ``sys.operating_point``; no constant remains.
``"ignore"``
    Drop it; only when asked for by name.

A model whose constant is zero gets nothing extra, whatever the mode.

Inputs are held between samples (zero-order hold) everywhere, as in the rest of cosim.

Signal names as FMUs write them
-------------------------------
States keep their names (``mass.s``). python-control refuses a ``.`` in an input or output name (it means
``system.signal`` there), so their dots are written ``:`` (``mass:s``): :func:`control_label` gives a name's
label and :func:`label_name` the name of a label (the controllers read the names back so).

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

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import control
import numpy as np
from scipy.linalg import expm

from ..data._names import control_label, label_name
from ..errors import InvalidSettingError, UnknownVariableError
from ..identify.model import IdentifiedModel
from .jacobian import _jacobian

__all__ = ["CONSTANT_INPUT", "CONSTANT_MODES", "OperatingPoint", "control_label", "label_name", "operating_point",
           "to_statespace"]


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

    The states keep the model's names; an input or output name's dots are written ``:`` (``mass.s`` ->
    ``mass:s``, :func:`control_label`), as python-control refuses them there.

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
    options: dict[str, Any] = {"states": [control_label(s, keep_dots=True) for s in model.states],
                               "inputs": [control_label(u) for u in inputs],
                               "outputs": [control_label(s) for s in model.states]}
    if name is not None:
        options["name"] = str(name)
    args = (a, b, np.eye(n), np.zeros((n, len(inputs))))
    sys = control.ss(*args, dt, **options) if dt is not None else control.ss(*args, **options)
    sys.operating_point = point
    return sys
