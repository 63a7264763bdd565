"""The columns of :func:`~cosim.data.datafile.load_data`: a file's variable, or a named expression of its
variables such as ``"force=gtau*vir"``.

An expression holds numbers and variables joined by ``+ - * /``, unary minus and parentheses. It is parsed with
:mod:`ast` and every node checked against that list (:func:`_check_node`); :func:`_evaluate` walks the checked
tree over numpy arrays and scalars. Nothing is passed to ``eval``.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidSettingError

_OPS: dict[type, Callable[[Any, Any], Any]] = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
                                               ast.Div: np.divide}
_EXPRESSION_HELP = ("write numbers and the file's variables joined by + - * /, e.g. force=gtau*vir or "
                    "force=35.15*vir+pulses_N")


@dataclass(frozen=True)
class _Column:
    name: str
    text: str
    tree: ast.Expression

    @property
    def variables(self) -> tuple[str, ...]:
        seen: dict[str, None] = {}
        for node in ast.walk(self.tree):
            if isinstance(node, ast.Name):
                seen.setdefault(node.id, None)
        return tuple(seen)

    @property
    def plain(self) -> bool:
        """The column is a variable of the file, not an expression."""
        return isinstance(self.tree.body, ast.Name)

    def describe(self) -> str:
        return self.name if self.plain and self.text == self.name else f"{self.name}={self.text}"


def _check_node(node: ast.AST, spec: str) -> None:
    if isinstance(node, ast.Expression):
        _check_node(node.body, spec)
    elif isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        _check_node(node.left, spec)
        _check_node(node.right, spec)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check_node(node.operand, spec)
    elif isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        pass
    elif isinstance(node, ast.Name):
        pass
    else:
        raise InvalidSettingError(f"column {spec!r}: {ast.unparse(node)!r} is not allowed; {_EXPRESSION_HELP}")


def _parse_column(name: str, text: str, spec: str) -> _Column:
    name, text = str(name).strip(), str(text).strip()
    if not name.isidentifier() or name == "time":
        raise InvalidSettingError(f"column {spec!r}: {name!r} is not a usable name; use letters, digits and _ "
                                  "(not 'time'), e.g. force=gtau*vir")
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError:
        raise InvalidSettingError(f"column {spec!r}: {text!r} is not an expression; {_EXPRESSION_HELP}") from None
    _check_node(tree, spec)
    return _Column(name, text, tree)


def _plain_column(name: str) -> _Column:
    """A column that is a variable of the file, whatever its name (a CSV header may say "motor speed")."""
    name = str(name).strip()
    if not name or name == "time":
        raise InvalidSettingError(f"column {name!r} is not a usable name; 'time' and '' are reserved, rename it "
                                  "with new_name=variable")
    return _Column(name, name, ast.Expression(body=ast.Name(id=name, ctx=ast.Load())))


def _parse_columns(columns: Mapping[str, str] | Sequence[str] | str) -> list[_Column]:
    if isinstance(columns, Mapping):
        parsed = [_plain_column(name) if str(text).strip() == str(name).strip() else
                  _parse_column(name, text, f"{name}={text}") for name, text in columns.items()]
    else:
        items = [columns] if isinstance(columns, str) else list(columns)
        parsed = []
        for item in items:
            if not isinstance(item, str):
                raise InvalidSettingError(f"columns must be names or 'name=expression' strings, got {item!r}")
            name, sep, text = item.partition("=")
            parsed.append(_parse_column(name, text, item) if sep else _plain_column(item))
    if not parsed:
        raise InvalidSettingError("columns is empty; name at least one column, e.g. columns=['qm', 'force=gtau*vir']")
    names = [c.name for c in parsed]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InvalidSettingError(f"column name {repeated[0]!r} is given twice; give each column one name")
    return parsed


def _evaluate(node: ast.AST, env: Mapping[str, float | np.ndarray]) -> float | np.ndarray:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, env)
    if isinstance(node, ast.BinOp):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return _OPS[type(node.op)](_evaluate(node.left, env), _evaluate(node.right, env))
    if isinstance(node, ast.UnaryOp):
        value = _evaluate(node.operand, env)
        return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, ast.Constant):
        return float(node.value)
    return env[node.id]  # type: ignore[attr-defined]  # names only, checked by _check_node
