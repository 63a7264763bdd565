"""The columns of :func:`~cosim.data.datafile.load_data`: a file's variable, or a named expression of its
variables such as ``"force=gtau*vir"``.

An expression holds numbers and variables joined by ``+ - * /``, unary minus and parentheses. It is parsed with
:mod:`ast` and every node checked against that list (:func:`_check_node`); :func:`_evaluate` walks the checked
tree over numpy arrays and scalars. Nothing is passed to ``eval``.

A variable of a MATLAB ``.mat`` file may be a matrix holding several channels; an expression then reads one of
them by index (a :class:`_Ref`):

``data[:,k]``
    column ``k`` of ``data`` (channels as columns, one row per time), e.g. ``"pos=data[:,2]"``;
``data[k,:]``
    row ``k`` of ``data`` (channels as rows, one column per time), e.g. ``"pos=data[2,:]"``.

A variable may be named as FMUs write it (``"force=2*mass.f"``, ``"x[2]"``, ``"der(x)"``, ``"'my var'"``: see
:mod:`._names`); brackets that hold a ``:`` or a ``0`` are a ``.mat`` index, never part of a name.

Indices are 0-based, as in Python and NumPy: ``data[:,0]`` is the first column (MATLAB's ``data(:,1)``). ``k`` is
a whole number written in the text; spaces are free (``data[:, 2]``), and an indexed variable may stand wherever a
variable may (``"force=35.15*data[:,3]"``). Nothing else is accepted inside the brackets (no ranges, steps or
single indices). Whether ``k`` fits the variable's shape is checked when the file is read
(:func:`~cosim.data._measurement_files._values`); a vector accepts index 0 either way.

Examples
--------
>>> column = _parse_columns(["force=35.15*data[:, 3] + offset"])[0]
>>> column.variables, [ref.key for ref in column.references]
(('data', 'offset'), ['data[:,3]', 'offset'])
>>> import numpy as np
>>> float(_evaluate(column.tree, {"data[:,3]": np.float64(2.0), "offset": 1.0}))
71.3
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidSettingError
from ._names import is_name, parse_expression

_OPS: dict[type, Callable[[Any, Any], Any]] = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
                                               ast.Div: np.divide}
_EXPRESSION_HELP = ("write numbers and the file's variables joined by + - * /, e.g. force=gtau*vir or "
                    "force=35.15*vir+pulses_N")
_INDEX_HELP = ("index a .mat matrix as data[:,k] (its column k) or data[k,:] (its row k), k a whole number; "
               "indices are 0-based, as in NumPy")


@dataclass(frozen=True)
class _Ref:
    """A value a column reads: a whole variable of the file, or one column or row of a ``.mat`` matrix.

    Parameters
    ----------
    variable : str
        The file's variable.
    axis : {None, 0, 1}
        ``None``: the whole variable; ``1``: its column ``index`` (``data[:,k]``); ``0``: its row ``index``
        (``data[k,:]``).
    index : int
        The 0-based column or row; as written, so it may be out of range (checked against the file).

    Examples
    --------
    >>> _Ref("data", 1, 2).key, _Ref("data", 0, 2).key, _Ref("qm").key
    ('data[:,2]', 'data[2,:]', 'qm')
    """

    variable: str
    axis: int | None = None
    index: int = 0

    @property
    def key(self) -> str:
        """The reference as written, without spaces: ``"qm"``, ``"data[:,2]"`` or ``"data[2,:]"``."""
        if self.axis is None:
            return self.variable
        return f"{self.variable}[:,{self.index}]" if self.axis == 1 else f"{self.variable}[{self.index},:]"

    @property
    def what(self) -> str:
        """``"column"`` or ``"row"`` (``"variable"`` for a whole variable)."""
        return {None: "variable", 1: "column", 0: "row"}[self.axis]


def _index(node: ast.AST) -> int | None:
    """The whole number `node` writes (``2``, ``-1``), else None."""
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        inner = _index(node.operand)
        return None if inner is None else -inner
    if isinstance(node, ast.Constant) and type(node.value) is int:
        return node.value
    return None


def _is_colon(node: ast.AST) -> bool:
    return isinstance(node, ast.Slice) and node.lower is None and node.upper is None and node.step is None


def _subscript_ref(node: ast.Subscript, where: str) -> _Ref:
    """``data[:,k]`` or ``data[k,:]`` as a :class:`_Ref`; anything else in brackets is refused."""
    index = node.slice
    if isinstance(node.value, ast.Name) and isinstance(index, ast.Tuple) and len(index.elts) == 2:
        first, second = index.elts
        column, row = _index(second), _index(first)
        if _is_colon(first) and column is not None:
            return _Ref(node.value.id, 1, column)
        if _is_colon(second) and row is not None:
            return _Ref(node.value.id, 0, row)
    raise InvalidSettingError(f"{where}: {ast.unparse(node)!r} is not allowed; {_INDEX_HELP}")


def _references(node: ast.AST) -> Iterator[_Ref]:
    """The variables and indexed variables `node` reads, left to right."""
    if isinstance(node, ast.Subscript):
        yield _subscript_ref(node, repr(ast.unparse(node)))
    elif isinstance(node, ast.Name):
        yield _Ref(node.id)
    else:
        for child in ast.iter_child_nodes(node):
            yield from _references(child)


def _parse_reference(text: str, where: str) -> _Ref | None:
    """`text` as an indexed variable (``"data[:,0]"``, spaces allowed), or None when it is not one.

    Raises
    ------
    InvalidSettingError
        Brackets that are not ``[:,k]`` or ``[k,:]`` (``"data[0]"``, ``"data[:,1:3]"``).

    Examples
    --------
    >>> _parse_reference("data[:, 0]", "time"), _parse_reference("t", "time")
    (_Ref(variable='data', axis=1, index=0), None)
    """
    try:
        body = parse_expression(str(text).strip()).body
    except SyntaxError:
        return None
    return _subscript_ref(body, where) if isinstance(body, ast.Subscript) else None


@dataclass(frozen=True)
class _Column:
    name: str
    text: str
    tree: ast.Expression

    @property
    def references(self) -> tuple[_Ref, ...]:
        """The values the column reads (a variable, or a column or row of one), each once, left to right."""
        return tuple(dict.fromkeys(_references(self.tree.body)))

    @property
    def variables(self) -> tuple[str, ...]:
        """The file's variables the column reads (``data`` for ``data[:,2]``), each once."""
        return tuple(dict.fromkeys(ref.variable for ref in self.references))

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
    elif isinstance(node, ast.Subscript):
        _subscript_ref(node, f"column {spec!r}")
    else:
        raise InvalidSettingError(f"column {spec!r}: {ast.unparse(node)!r} is not allowed; {_EXPRESSION_HELP}")


def _parse_column(name: str, text: str, spec: str) -> _Column:
    name, text = str(name).strip(), str(text).strip()
    if not is_name(name) or name == "time":
        raise InvalidSettingError(f"column {spec!r}: {name!r} is not a usable name; use letters, digits and _ "
                                  "(not 'time'), or a name as FMUs write it (mass.s), e.g. force=gtau*vir")
    try:
        tree = parse_expression(text)
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
    if isinstance(node, ast.Subscript):
        return env[_subscript_ref(node, "").key]
    return env[node.id]  # type: ignore[attr-defined]  # names only, checked by _check_node
