"""Effects a user brings: an expression of the record's signals with named parameters, searched beside the catalogue.

:func:`candidate` turns ``"orifice: -a*sqrt(abs(h1))"`` (a name, then an expression of the model's states and
inputs) into an :class:`~cosim.diagnose.effects.Effect` that :func:`~cosim.diagnose.diagnosis.diagnose` searches,
scores and reports like a catalogued one (``diagnose(model, data, candidates=[...])``; ``cosim diagnose
--candidate``).

* **Linear in its parameters.** The expression must be a sum of parameter times feature
  (``-a*sqrt(abs(h1)) + b*h1``). It is split with :mod:`ast` into its **features** (``sqrt(abs(h1))``, ``h1``:
  each a cosim term expression, :mod:`cosim.identify.terms`, so the augmented model simulates, saves and exports
  like any other) and the **factor** each parameter is written with (``-1`` for ``-a*...``, ``0.5`` for
  ``a*h1/2``), so that the report gives ``a`` itself, not the fitted coefficient. A parameter written in several
  summands (``a*h1 - 2*a*h2``) multiplies their sum.
* **Which names are parameters.** Given the signals (``signals=``: names, or a model, whose states and inputs
  they are; the CLI always gives them), every other name is a parameter. Without them, a parameter is a name
  that only ever multiplies a summand; where that leaves two (``a*h1``), say which (``parameters=["a"]``).
* **Where it acts.** In the model's dynamic rows (every state's equation but the kinematic ``p' = v``,
  :attr:`Roles.dynamic_rows <cosim.diagnose.effects.Roles>`); the search chooses the row or rows.
* **Parameters in the report.** Per parameter ``p``: ``p`` = the coefficient over its factor in the row of the
  first signal it reads if that row is chosen (the orifice on ``h1`` in ``h1``'s equation), else in the first
  chosen row; ``p_input``, the same over that row's input gain (the parameter in the input's units: a force where
  the input is a force, a flow where it is an inflow), where the row has one; and ``p_ROW`` per row when there
  are several. No nuisance parameter.
* **A Python callable** (``candidate("orifice", lambda h1, a: -a*np.sqrt(np.abs(h1)))``) is called once on
  symbolic placeholders named after its arguments, which record the expression it builds (``+ - * / **``,
  ``abs()``, and NumPy's ufuncs of the term functions: ``np.sqrt``, ``np.abs``, ``np.sin``, ``np.tanh``...), and
  the recorded text is then read as above. The effect holds the expression, never the callable: the augmented
  model is terms only, so it still saves, simulates and exports. A callable may also return the expression text.

Bad input is refused in one line (:class:`~cosim.errors.InvalidSettingError`,
:class:`~cosim.errors.UnknownVariableError` for a signal the model does not have).

Examples
--------
>>> orifice = candidate("orifice: -a*sqrt(abs(h1))", signals=["h1", "h2", "u"])
>>> orifice.features, orifice.parameter_names, orifice.factors
(('sqrt(abs(h1))',), ('a',), (-1.0,))
>>> import numpy as np
>>> candidate("orifice", lambda h1, a: -a * np.sqrt(np.abs(h1))).features
('sqrt(abs(h1))',)
"""

from __future__ import annotations

import ast
import inspect
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data._names import parse_expression
from ..errors import InvalidSettingError, UnknownVariableError
from ..identify.terms import FUNCTIONS, Term
from .effects import ALIASES, EFFECTS, Attachment, Effect, Roles

__all__ = ["UserEffect", "candidate"]

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_EXAMPLE = "e.g. 'orifice: -a*sqrt(abs(h1))'"


@dataclass(frozen=True)
class UserEffect(Effect):
    """An :class:`~cosim.diagnose.effects.Effect` a user brings (built by :func:`candidate`): its features in the
    model's dynamic rows, each multiplied by ``factor * parameter``."""

    expression: str = ""
    features: tuple[str, ...] = ()
    parameter_names: tuple[str, ...] = ()
    factors: tuple[float, ...] = ()
    #: The signals the features read, in order of first appearance.
    signals: tuple[str, ...] = ()

    def attachments(self, roles: Roles) -> list[Attachment]:
        """One place: every dynamic row (the search chooses among them); refused in one line when the model has
        no signal the expression reads."""
        known = (*roles.positions, *roles.dynamic_rows, *roles.inputs)
        for name in self.signals:
            if name not in known:
                raise UnknownVariableError(f"candidate {self.name!r}: {name!r} is not a signal of the model; "
                                           f"signals are {', '.join(known)}")
        return [Attachment(",".join(self.signals) or "constant", self.signals, roles.dynamic_rows)]


def candidate(spec: str, expression: str | Callable[..., Any] | None = None, *,
              signals: Sequence[str] | Any = None, parameters: Sequence[str] | None = None) -> UserEffect:
    """An effect a user brings, from ``"NAME: EXPRESSION"`` or a name and an expression (text or callable).

    Parameters
    ----------
    spec : str
        ``"orifice: -a*sqrt(abs(h1))"``, or the name alone when `expression` is given.
    expression : str or callable, optional
        The expression, or a function of the signals and parameters by name returning it, e.g.
        ``lambda h1, a: -a*np.sqrt(np.abs(h1))`` (see the module notes).
    signals : sequence of str or IdentifiedModel, optional
        The names the expression may read (a model: its states and inputs); any other name is a parameter.
    parameters : sequence of str, optional
        The parameters' names, where the signals are not given and the expression does not tell them.

    Returns
    -------
    UserEffect
        An :class:`~cosim.diagnose.effects.Effect` for ``diagnose(..., candidates=[...])``.

    Raises
    ------
    InvalidSettingError
        Text that does not parse, a function not in :data:`~cosim.identify.terms.FUNCTIONS`, no parameter, an
        expression not linear in a parameter, a name of the catalogue.
    UnknownVariableError
        A name that is not one of `signals` where a parameter cannot be.

    Examples
    --------
    >>> eff = candidate("leak: -a*sqrt(abs(h1)) + 2*b*h1/3", signals=["h1", "u"])
    >>> eff.features, eff.parameter_names, eff.factors
    (('sqrt(abs(h1))', 'h1'), ('a', 'b'), (-1.0, 0.6666666666666666))
    """
    name, text, shown = _name_and_text(spec, expression)
    known = _signal_names(signals)
    features, names, factors, used = _split(text, shown, known, parameters)
    meaning = f"a user's candidate: {text}"
    return UserEffect(name, meaning, "expression", None, "", lambda a, v, f=features: f,
                      _parameters(names, factors, used), expression=text, features=features,
                      parameter_names=names, factors=factors, signals=used)


# ---------------------------------------------------------------------------------------------- the text
def _name_and_text(spec: Any, expression: str | Callable[..., Any] | None) -> tuple[str, str, str]:
    if not isinstance(spec, str):
        raise InvalidSettingError(f"candidate {spec!r}: give 'NAME: EXPRESSION', {_EXAMPLE}, or a name and a "
                                  "callable")
    if expression is None:
        name, sep, text = spec.partition(":")
        if not sep:
            raise InvalidSettingError(f"candidate {spec!r}: write NAME: EXPRESSION, {_EXAMPLE}")
    else:
        name, text = spec, expression if isinstance(expression, str) else _recorded(spec, expression)
    name, text = name.strip(), str(text).strip()
    shown = f"{name}: {text}"
    if not _NAME.match(name):
        raise InvalidSettingError(f"candidate {shown!r}: the name {name!r} must be a word (letters, digits, _), "
                                  f"{_EXAMPLE}")
    if name in EFFECTS or name in ALIASES:
        raise InvalidSettingError(f"candidate {shown!r}: {name!r} is a catalogue effect's name; give yours another")
    if not text:
        raise InvalidSettingError(f"candidate {shown!r}: no expression after the name, {_EXAMPLE}")
    return name, text, shown


def _signal_names(signals: Sequence[str] | Any) -> tuple[str, ...] | None:
    if signals is None:
        return None
    if hasattr(signals, "states") and hasattr(signals, "inputs"):
        return (*signals.states, *signals.inputs)
    return tuple(str(s) for s in ([signals] if isinstance(signals, str) else signals))


def _parse(text: str, shown: str) -> ast.expr:
    try:
        tree = parse_expression(text)
    except SyntaxError:
        raise InvalidSettingError(f"candidate {shown!r}: {text!r} is not an expression; {_EXAMPLE}") from None
    calls = {id(n.func) for n in ast.walk(tree.body) if isinstance(n, ast.Call)}
    for node in ast.walk(tree.body):
        if isinstance(node, ast.Call):
            func = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
            if func not in FUNCTIONS:
                raise InvalidSettingError(f"candidate {shown!r}: {func}() is not a term function; use "
                                          f"{', '.join(FUNCTIONS)}")
            if node.keywords or len(node.args) != 1:
                raise InvalidSettingError(f"candidate {shown!r}: {func}() takes one argument")
        elif isinstance(node, ast.Name):
            if node.id in FUNCTIONS and id(node) not in calls:
                raise InvalidSettingError(f"candidate {shown!r}: {node.id} is a function; call it, e.g. {node.id}(x)")
        elif not (isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow))
                  or isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd))
                  or isinstance(node, ast.Constant) and type(node.value) in (int, float)
                  or isinstance(node, (ast.operator, ast.unaryop, ast.expr_context))):
            raise InvalidSettingError(f"candidate {shown!r}: use names, numbers, + - * / ** and "
                                      f"{', '.join(FUNCTIONS)}")
    return tree.body


def _names(node: ast.AST) -> list[str]:
    """The names `node` reads (not the functions it calls), in order of first appearance."""
    calls = {id(n.func) for n in ast.walk(node) if isinstance(n, ast.Call)}
    return list(dict.fromkeys(n.id for n in ast.walk(node) if isinstance(n, ast.Name) and id(n) not in calls))


# ---------------------------------------------------------------------------------------------- the split
def _summands(node: ast.expr, sign: float = 1.0) -> list[tuple[float, ast.expr]]:
    """The expression as a signed sum: (sign, summand) pairs."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
        return _summands(node.left, sign) + _summands(node.right, sign if isinstance(node.op, ast.Add) else -sign)
    if isinstance(node, ast.UnaryOp):
        return _summands(node.operand, -sign if isinstance(node.op, ast.USub) else sign)
    return [(sign, node)]


def _factors(node: ast.expr, up: bool = True) -> list[tuple[ast.expr, bool]]:
    """A product as its factors, each with whether it multiplies (True) or divides."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
        return _factors(node.left, up) + _factors(node.right, up)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
        return _factors(node.left, up) + _factors(node.right, not up)
    if isinstance(node, ast.UnaryOp):
        return ([(ast.Constant(-1.0), True)] if isinstance(node.op, ast.USub) else []) + _factors(node.operand, up)
    return [(node, up)]


def _product(nodes: list[ast.expr]) -> ast.expr | None:
    out = None
    for n in nodes:
        out = n if out is None else ast.BinOp(out, ast.Mult(), n)
    return out


def _split(text: str, shown: str, known: tuple[str, ...] | None, given: Sequence[str] | None,
           ) -> tuple[tuple[str, ...], tuple[str, ...], tuple[float, ...], tuple[str, ...]]:
    """(features, parameters, factors, signals read) of a linear-in-parameters expression (see the module)."""
    body = _parse(text, shown)
    summands = [(sign, _factors(node)) for sign, node in _summands(body)]
    every = _names(body)
    bare = {n for _, fs in summands for f, up in fs if up and isinstance(f, ast.Name) for n in [f.id]}
    elsewhere = {n for _, fs in summands for f, up in fs if not (up and isinstance(f, ast.Name)) for n in _names(f)}
    counts = [[f.id for f, up in fs if up and isinstance(f, ast.Name)] for _, fs in summands]
    signals_of = f"; signals are {', '.join(known)}" if known is not None else ""
    if given is not None:
        params = [str(p) for p in given]
        for p in params:
            if p not in every:
                raise InvalidSettingError(f"candidate {shown!r}: parameter {p!r} is not in the expression")
    elif known is not None:
        params = [n for n in every if n not in known]
    else:
        params = [n for n in every if n in bare and n not in elsewhere]
        for names in counts:
            two = [n for n in names if n in params]
            if len(two) > 1:
                raise InvalidSettingError(f"candidate {shown!r}: {' or '.join(two)} could each be the parameter; "
                                          "give the signals (signals=model) or parameters=[...]")
    if not params:
        raise InvalidSettingError(f"candidate {shown!r}: no parameter; write a named parameter times each "
                                  f"feature, {_EXAMPLE}{signals_of}")
    if known is not None:
        for n in every:
            if n not in params and n not in known:
                raise UnknownVariableError(f"candidate {shown!r}: {n!r} is not a signal{signals_of}")
    terms: dict[str, list[tuple[float, str]]] = {}  # per parameter, in order of appearance: (factor, feature)
    for (sign, fs), names in zip(summands, counts, strict=True):
        linear = [n for n in names if n in params]
        inside = [n for f, up in fs if not (up and isinstance(f, ast.Name)) for n in _names(f) if n in params]
        if inside:
            bad = inside[0]
            if known is not None and given is None and bad not in bare and [n for n in linear if n != bad]:
                raise UnknownVariableError(f"candidate {shown!r}: {bad!r} is not a signal{signals_of}")
            raise InvalidSettingError(f"candidate {shown!r}: not linear in {bad!r}; write a sum of parameter times "
                                      f"feature, {_EXAMPLE}{signals_of}")
        if len(linear) > 1:
            raise InvalidSettingError(f"candidate {shown!r}: {' and '.join(linear)} multiply each other, which is "
                                      f"not linear; one parameter per summand{signals_of}")
        summand = ast.unparse(_product([f for f, _ in fs]) or ast.Constant(1))
        if not linear:
            raise InvalidSettingError(f"candidate {shown!r}: {summand!r} has no parameter; each summand needs one, "
                                      f"{_EXAMPLE}{signals_of}")
        factor, up_nodes, down_nodes = sign, [], []
        for f, up in fs:
            if isinstance(f, ast.Name) and f.id == linear[0] and up:
                continue
            if not _names(f):  # a number
                value = float(Term(ast.unparse(f)).evaluate({})[0])
                if not (math.isfinite(value) and value != 0.0):
                    raise InvalidSettingError(f"candidate {shown!r}: {ast.unparse(f)!r} is not a usable number")
                factor = factor * value if up else factor / value
            else:
                (up_nodes if up else down_nodes).append(f)
        feature = _product(up_nodes) or ast.Constant(1)
        if down_nodes:
            feature = ast.BinOp(feature, ast.Div(), _product(down_nodes))
        terms.setdefault(linear[0], []).append((factor, ast.unparse(feature)))
    return _features(terms, shown, known)


def _features(terms: Mapping[str, list[tuple[float, str]]], shown: str, known: tuple[str, ...] | None,
              ) -> tuple[tuple[str, ...], tuple[str, ...], tuple[float, ...], tuple[str, ...]]:
    """One feature per parameter (several summands of one parameter: their sum over the first one's factor)."""
    features, factors, seen = [], [], {}
    for p, parts in terms.items():
        first = parts[0][0]
        text = parts[0][1]
        for factor, feature in parts[1:]:
            ratio = factor / first
            size = "" if abs(ratio) == 1.0 else f"{abs(ratio)!r}*"
            text += f" {'-' if ratio < 0 else '+'} {size}({feature})"
        term = Term(text)
        if term.text in seen:
            raise InvalidSettingError(f"candidate {shown!r}: {seen[term.text]} and {p} multiply the same feature "
                                      f"{term.text}; the data cannot tell them apart")
        seen[term.text] = p
        features.append(term.text)
        factors.append(float(first))
    used: dict[str, None] = {}
    for f in features:
        for n in Term(f).variables:
            used.setdefault(n, None)
    return tuple(features), tuple(terms), tuple(factors), tuple(used)


def _parameters(names: tuple[str, ...], factors: tuple[float, ...], signals: tuple[str, ...]) -> Callable:
    def params(coef: dict[str, np.ndarray], value: float | None, roles: Roles,
               attachment: Attachment) -> dict[str, float]:
        rows = list(coef)
        if not rows:
            return {}
        own = next((r for r in rows if r in signals), rows[0])
        gain = roles.gain(own)
        out: dict[str, float] = {}
        for k, p in enumerate(names):
            out[p] = float(coef[own][k]) / factors[k]
            if gain:
                out[f"{p}_input"] = out[p] / gain
            if len(rows) > 1:
                out.update({f"{p}_{r}": float(coef[r][k]) / factors[k] for r in rows})
        return out
    return params


# ---------------------------------------------------------------------------------------------- the callable
class _Symbol:
    """A placeholder for a callable's argument: arithmetic on it records the expression's text."""

    __slots__ = ("text",)
    _UFUNCS = {"sqrt": "sqrt", "sin": "sin", "cos": "cos", "tan": "tan", "exp": "exp", "log": "log",
               "tanh": "tanh", "arctan": "atan", "absolute": "abs", "fabs": "abs", "sign": "sign"}
    _BINARY = {"add": "+", "subtract": "-", "multiply": "*", "true_divide": "/", "divide": "/", "power": "**"}

    def __init__(self, text: str) -> None:
        self.text = text

    @staticmethod
    def _of(value: Any) -> str:
        if isinstance(value, _Symbol):
            return value.text
        if isinstance(value, (int, float, np.number)) and not isinstance(value, (bool, np.bool_)):
            return repr(float(value))
        raise InvalidSettingError(f"a candidate callable combined its arguments with {value!r}; use numbers, "
                                  "+ - * / ** and numpy's functions")

    def _op(self, op: str, other: Any, right: bool = False) -> _Symbol:
        a, b = (self._of(other), self.text) if right else (self.text, self._of(other))
        return _Symbol(f"({a} {op} {b})")

    def __add__(self, o): return self._op("+", o)  # noqa: E704
    def __radd__(self, o): return self._op("+", o, True)  # noqa: E704
    def __sub__(self, o): return self._op("-", o)  # noqa: E704
    def __rsub__(self, o): return self._op("-", o, True)  # noqa: E704
    def __mul__(self, o): return self._op("*", o)  # noqa: E704
    def __rmul__(self, o): return self._op("*", o, True)  # noqa: E704
    def __truediv__(self, o): return self._op("/", o)  # noqa: E704
    def __rtruediv__(self, o): return self._op("/", o, True)  # noqa: E704
    def __pow__(self, o): return self._op("**", o)  # noqa: E704
    def __rpow__(self, o): return self._op("**", o, True)  # noqa: E704
    def __neg__(self): return _Symbol(f"(-{self.text})")  # noqa: E704
    def __pos__(self): return self  # noqa: E704
    def __abs__(self): return _Symbol(f"abs({self.text})")  # noqa: E704

    def __array_ufunc__(self, ufunc: np.ufunc, method: str, *inputs: Any, **kwargs: Any) -> _Symbol:
        if method == "__call__" and not kwargs and ufunc.__name__ in self._UFUNCS and len(inputs) == 1:
            return _Symbol(f"{self._UFUNCS[ufunc.__name__]}({self._of(inputs[0])})")
        if method == "__call__" and not kwargs and ufunc.__name__ in self._BINARY and len(inputs) == 2:
            return _Symbol(f"({self._of(inputs[0])} {self._BINARY[ufunc.__name__]} {self._of(inputs[1])})")
        if method == "__call__" and ufunc.__name__ == "negative":
            return -_Symbol(self._of(inputs[0]))
        raise InvalidSettingError(f"a candidate callable used numpy's {ufunc.__name__}, which is no term function; "
                                  f"use {', '.join(FUNCTIONS)} (np.arctan for atan, np.abs for abs)")

    def __bool__(self) -> bool:
        raise InvalidSettingError("a candidate callable cannot branch on its arguments (if, max, comparisons); "
                                  "write a one-sided term with abs: 0.5*(x-b)+0.5*abs(x-b)")

    def __float__(self) -> float:
        raise InvalidSettingError("a candidate callable called a function of plain numbers (math.*) on its "
                                  "arguments; use numpy's (np.sqrt, np.abs...)")

    __lt__ = __le__ = __gt__ = __ge__ = lambda self, other: self.__bool__()  # noqa: E731


def _recorded(name: str, func: Callable[..., Any]) -> str:
    """The expression `func` builds, recorded by calling it on placeholders named after its arguments."""
    if not callable(func):
        raise InvalidSettingError(f"candidate {name!r}: the expression must be text or a callable, got "
                                  f"{type(func).__name__}")
    try:
        names = [p.name for p in inspect.signature(func).parameters.values()
                 if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    except (TypeError, ValueError):
        raise InvalidSettingError(f"candidate {name!r}: cannot read the callable's arguments; use a def or "
                                  "lambda whose arguments are the signals and parameters") from None
    positional = [n for n, p in inspect.signature(func).parameters.items() if p.kind != p.KEYWORD_ONLY]
    keywords = {n: _Symbol(n) for n in names if n not in positional}
    try:
        result = func(*[_Symbol(n) for n in positional], **keywords)
    except InvalidSettingError as exc:
        raise InvalidSettingError(f"candidate {name!r}: {exc}") from None
    except Exception as exc:  # the user's code: say what it raised, in one line
        raise InvalidSettingError(f"candidate {name!r}: the callable raised {type(exc).__name__}: {exc} on "
                                  "symbolic arguments; use + - * / ** and numpy's functions") from None
    if isinstance(result, _Symbol):
        return ast.unparse(parse_expression(result.text))
    if isinstance(result, str):
        return result
    raise InvalidSettingError(f"candidate {name!r}: the callable returned {result!r}, not an expression of its "
                              "arguments")
