"""The analytic Jacobian of an identified model's right-hand side, for linearising it and finding equilibria.

``_jacobian(model, x, u)`` gives ``(d rhs/dx, d rhs/du)`` by forward-mode differentiation of every term's
checked expression (:mod:`cosim.identify.terms`): each node carries its value and its gradient in the states
and inputs (``_dual``), a term function its own derivative (``_derivative_of``; a central difference for a
function added to the catalogue later).
"""

from __future__ import annotations

import ast
import math
from collections.abc import Mapping

import numpy as np

from ..errors import InvalidSettingError
from ..identify.model import IdentifiedModel
from ..identify.terms import FUNCTIONS, Term


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
            _, grad = _dual(Term(text)._tree.body, values, index, len(names))
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise InvalidSettingError(f"term {text!r} cannot be differentiated at the operating point ({exc}); "
                                      "choose another operating point") from None
        jac += np.outer(model.coef[:, k], grad)
    n = len(model.states)
    return jac[:, :n], jac[:, n:]
