"""Library terms as small expressions over state and input names: ``"theta_m"``, ``"omega_m*Tm"``,
``"tanh(omega_m/0.001)"``, ``"sin(theta_L)"``, ``"1"``.

One representation serves every stage: identification evaluates the terms on data (NumPy), simulation
evaluates them on one state (plain floats, generated Python), the FMU export writes them as C, and a saved
model stores them as text. Expressions are parsed with :mod:`ast` and only numbers, names, ``+ - * / **``
and the functions in :data:`FUNCTIONS` are accepted; nothing is ever passed to ``eval`` unchecked. Names may be
written as FMUs write them (``sign(mass.v)*extForce``, ``der(x)``, ``A[1,2]``, ``'my var'``): they are parsed
through their safe names (:func:`cosim.data._names.parse_expression`) and kept as written everywhere else.

Examples
--------
>>> import numpy as np
>>> term = Term("omega_m*Tm")
>>> term.variables
('omega_m', 'Tm')
>>> float(term.evaluate({"omega_m": np.array([2.0]), "Tm": np.array([3.0])})[0])
6.0
>>> Term("tanh(omega_m/0.001)").to_c({"omega_m": "x[1]"})
'tanh((x[1] / 0.001))'
"""

from __future__ import annotations

import ast
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from ..data._names import parse_expression
from ..errors import InvalidSettingError, UnknownVariableError

__all__ = ["Term", "FUNCTIONS", "polynomial_terms", "compile_rhs", "compile_rk4", "compile_rk4_casadi"]

#: Functions a term may call: name -> (NumPy function, math function, C function).
FUNCTIONS = {
    "sin": (np.sin, math.sin, "sin"),
    "cos": (np.cos, math.cos, "cos"),
    "tan": (np.tan, math.tan, "tan"),
    "exp": (np.exp, math.exp, "exp"),
    "log": (np.log, math.log, "log"),
    "sqrt": (np.sqrt, math.sqrt, "sqrt"),
    "abs": (np.abs, abs, "fabs"),
    "tanh": (np.tanh, math.tanh, "tanh"),
    "atan": (np.arctan, math.atan, "atan"),
    "sign": (np.sign, lambda v: float((v > 0) - (v < 0)), "cosim_sign"),
}
_OPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}


def _check(node: ast.AST, text: str) -> None:
    if isinstance(node, ast.Expression):
        _check(node.body, text)
    elif isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        _check(node.left, text)
        _check(node.right, text)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check(node.operand, text)
    elif isinstance(node, ast.Call):
        if not (isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS) or node.keywords or \
                len(node.args) != 1:
            raise InvalidSettingError(f"term {text!r}: only one-argument calls of {', '.join(FUNCTIONS)} are "
                                      "allowed")
        _check(node.args[0], text)
    elif isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and \
            not isinstance(node.value, bool):
        pass
    elif isinstance(node, ast.Name):
        if node.id in FUNCTIONS:
            raise InvalidSettingError(f"term {text!r}: {node.id} is a function; call it, e.g. {node.id}(x)")
    else:
        raise InvalidSettingError(f"term {text!r} is not a valid expression: use names, numbers, + - * / ** and "
                                  f"{', '.join(FUNCTIONS)}")


@dataclass(frozen=True)
class Term:
    """One library term, an expression of state and input names.

    Parameters
    ----------
    text : str
        The expression, e.g. ``"theta_m"``, ``"omega_m**2"``, ``"sign(omega_m)"``, ``"1"`` (the constant).
    """

    text: str
    _tree: ast.Expression = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        text = str(self.text).strip()
        try:
            tree = parse_expression(text)
        except SyntaxError:
            raise InvalidSettingError(f"term {text!r} is not a valid expression; write e.g. omega_m*Tm or "
                                      "tanh(omega_m/0.01)") from None
        _check(tree, text)
        object.__setattr__(self, "text", text)
        object.__setattr__(self, "_tree", tree)

    @property
    def variables(self) -> tuple[str, ...]:
        """The names the term uses, in order of first appearance."""
        seen: dict[str, None] = {}
        for node in ast.walk(self._tree):
            if isinstance(node, ast.Name) and node.id not in FUNCTIONS:
                seen.setdefault(node.id, None)
        return tuple(seen)

    @property
    def is_constant(self) -> bool:
        return not self.variables

    def check_names(self, names: Sequence[str]) -> None:
        """Raise UnknownVariableError if the term uses a name not in `names`."""
        for name in self.variables:
            if name not in names:
                raise UnknownVariableError(f"term {self.text!r} uses {name!r}, which is not a state or input "
                                           f"({', '.join(names)})")

    def evaluate(self, values: Mapping[str, np.ndarray]) -> np.ndarray:
        """Evaluate on arrays (one per name); a constant term broadcasts to the length of the data."""
        n = len(next(iter(values.values()))) if values else 1
        result = self._eval_np(self._tree.body, values)
        return np.broadcast_to(np.asarray(result, dtype=float), (n,)).copy()

    def _eval_np(self, node: ast.AST, values: Mapping[str, np.ndarray]):
        if isinstance(node, ast.BinOp):
            left, right = self._eval_np(node.left, values), self._eval_np(node.right, values)
            op = type(node.op)
            return (left + right if op is ast.Add else left - right if op is ast.Sub else left * right
                    if op is ast.Mult else left / right if op is ast.Div else np.power(left, right))
        if isinstance(node, ast.UnaryOp):
            value = self._eval_np(node.operand, values)
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.Call):
            return FUNCTIONS[node.func.id][0](self._eval_np(node.args[0], values))
        if isinstance(node, ast.Constant):
            return float(node.value)
        return np.asarray(values[node.id], dtype=float)

    def derivative(self, values: Mapping[str, np.ndarray], name: str) -> np.ndarray | float:
        """The exact partial derivative by `name` on arrays (forward mode over the expression): an array, or
        the float 0.0 where the term does not depend on `name`, or a float constant (``1.0`` for the name itself).

        Exact where a finite difference is not: a step wide as the smoothing velocity of ``tanh(w/eps)`` misses
        its slope. ``sign`` has derivative 0 (and ``abs`` the sign) everywhere.

        Examples
        --------
        >>> import numpy as np
        >>> Term("x**2*sin(y)").derivative({"x": np.array([3.0]), "y": np.array([0.0])}, "y").tolist()
        [9.0]
        """
        if name not in self.variables:
            return 0.0
        return _derivative(self._tree.body, values, name)[1]

    def to_source(self, names: Mapping[str, str], *, language: str = "python") -> str:
        """The term as source code, names replaced by `names` (e.g. ``{"omega_m": "x[1]"}``)."""
        return _emit(self._tree.body, names, language)

    def to_c(self, names: Mapping[str, str]) -> str:
        """The term as a C99 expression (functions of math.h; ``sign`` as ``cosim_sign``)."""
        return self.to_source(names, language="c")

    def __str__(self) -> str:
        return self.text


def _zero(d) -> bool:
    return isinstance(d, float) and d == 0.0


def _derivative(node: ast.AST, values: Mapping[str, np.ndarray], name: str):
    """(value, d value / d name) of a checked expression; a derivative that is identically zero is ``0.0``."""
    if isinstance(node, ast.Constant):
        return float(node.value), 0.0
    if isinstance(node, ast.Name):
        return np.asarray(values[node.id], dtype=float), 1.0 if node.id == name else 0.0
    if isinstance(node, ast.UnaryOp):
        value, d = _derivative(node.operand, values, name)
        return (-value, d if _zero(d) else -d) if isinstance(node.op, ast.USub) else (value, d)
    if isinstance(node, ast.Call):
        a, da = _derivative(node.args[0], values, name)
        func = node.func.id
        value = FUNCTIONS[func][0](a)
        if _zero(da) or func == "sign":
            return value, 0.0
        slope = {"sin": lambda: np.cos(a), "cos": lambda: -np.sin(a), "tan": lambda: 1.0 / np.cos(a) ** 2,
                 "exp": lambda: value, "log": lambda: 1.0 / a, "sqrt": lambda: 0.5 / value,
                 "abs": lambda: np.sign(a), "tanh": lambda: 1.0 - value * value,
                 "atan": lambda: 1.0 / (1.0 + a * a)}[func]()
        return value, slope * da
    a, da = _derivative(node.left, values, name)
    b, db = _derivative(node.right, values, name)
    op = type(node.op)
    if op in (ast.Add, ast.Sub):
        sign = 1.0 if op is ast.Add else -1.0
        d = da if _zero(db) else sign * db if _zero(da) else da + sign * db
        return (a + b if op is ast.Add else a - b), d
    if op is ast.Mult:
        d = 0.0 if _zero(da) and _zero(db) else da * b if _zero(db) else a * db if _zero(da) else da * b + a * db
        return a * b, d
    if op is ast.Div:
        value = a / b
        d = 0.0 if _zero(da) and _zero(db) else da / b if _zero(db) else \
            -value * db / b if _zero(da) else (da - value * db) / b
        return value, d
    value = np.power(a, b)  # a ** b
    if _zero(db):
        return value, 0.0 if _zero(da) else b * np.power(a, b - 1.0) * da
    return value, value * (db * np.log(a) + (0.0 if _zero(da) else b * da / a))


def _emit(node: ast.AST, names: Mapping[str, str], language: str, numbers: list[float] | None = None) -> str:
    """Source of a checked expression; with `numbers`, each number is written ``k[i]`` and appended to it."""
    if isinstance(node, ast.BinOp):
        left, right = _emit(node.left, names, language, numbers), _emit(node.right, names, language, numbers)
        if isinstance(node.op, ast.Pow):
            if language == "c":
                return f"pow({left}, {right})"
            return f"({left} ** {right})"
        return f"({left} {_OPS[type(node.op)]} {right})"
    if isinstance(node, ast.UnaryOp):
        operand = _emit(node.operand, names, language, numbers)
        return f"(-{operand})" if isinstance(node.op, ast.USub) else operand
    if isinstance(node, ast.Call):
        func = FUNCTIONS[node.func.id][2] if language == "c" else f"_f_{node.func.id}"
        return f"{func}({_emit(node.args[0], names, language, numbers)})"
    if isinstance(node, ast.Constant):
        if numbers is not None:
            numbers.append(float(node.value))
            return f"k[{len(numbers) - 1}]"
        return repr(float(node.value))
    return names[node.id]


def polynomial_terms(names: Sequence[str], degree: int, *, include_bias: bool = True) -> list[str]:
    """All monomials of `names` up to `degree`, as term texts: ``["1", "a", "b", "a**2", "a*b", "b**2"]``.

    Examples
    --------
    >>> polynomial_terms(["x", "u"], 2)
    ['1', 'x', 'u', 'x**2', 'x*u', 'u**2']
    """
    from itertools import combinations_with_replacement

    if degree < 1:
        raise InvalidSettingError(f"polynomial degree must be at least 1, got {degree}")
    terms = ["1"] if include_bias else []
    for d in range(1, degree + 1):
        for combo in combinations_with_replacement(names, d):
            parts = []
            for name in dict.fromkeys(combo):
                power = combo.count(name)
                parts.append(name if power == 1 else f"{name}**{power}")
            terms.append("*".join(parts))
    return terms


def compile_rhs(states: Sequence[str], inputs: Sequence[str], terms: Sequence[Term], coef: np.ndarray):
    """Generate a fast Python function ``f(x, u) -> list`` computing ``coef @ terms(x, u)`` for one state.

    Terms with all-zero coefficients are skipped and coefficients are inlined, so that a simulation step of
    a small model costs a few microseconds instead of dozens of NumPy calls.
    """
    names = {name: f"x[{i}]" for i, name in enumerate(states)}
    names.update({name: f"u[{j}]" for j, name in enumerate(inputs)})
    lines = ["def rhs(x, u):"]
    used = [k for k in range(len(terms)) if np.any(coef[:, k] != 0.0)]
    for k in used:
        lines.append(f"    t{k} = {terms[k].to_source(names)}")
    rows = []
    for i in range(len(states)):
        parts = [f"{float(coef[i, k])!r}*t{k}" for k in used if coef[i, k] != 0.0]
        rows.append(" + ".join(parts) if parts else "0.0")
    lines.append(f"    return [{', '.join(rows)}]")
    namespace = {f"_f_{name}": funcs[1] for name, funcs in FUNCTIONS.items()}
    exec(compile("\n".join(lines), "<cosim rhs>", "exec"), namespace)  # source built from checked ASTs only
    return namespace["rhs"]


def compile_rk4(states: Sequence[str], inputs: Sequence[str], terms: Sequence[Term], coef: np.ndarray):
    """Generate ``run(x0, rows, h, nsub, limit) -> (status, k, states)``: classic RK4 over held inputs.

    The same arithmetic as RK4 on :func:`compile_rhs` (same expressions, same order, so bit-identical
    results), unrolled into one function of local variables: no lists and no calls per stage, several times
    faster. ``rows`` holds one input row per step (held over it, `nsub` substeps of `h`); the run stops at
    the first step whose state leaves ``|x| < limit`` (or raises an arithmetic error): status
    ``"diverged"`` and that step's index, with the states of the steps before it.

    Examples
    --------
    >>> import math, numpy as np
    >>> run = compile_rk4(["x"], ["u"], [Term("x"), Term("u")], np.array([[-1.0, 1.0]]))
    >>> status, k, out = run([0.0], [[1.0]] * 10, 0.1, 1, 1e12)
    >>> status, k, abs(out[-1][0] - (1 - math.exp(-1.0))) < 1e-6   # x(1) of dx/dt = 1 - x from rest
    ('ok', 10, True)
    """
    n, m = len(states), len(inputs)
    used = [k for k in range(len(terms)) if np.any(coef[:, k] != 0.0)]

    def stage(args: Sequence[str], out: str) -> list[str]:
        names = dict(zip(states, args, strict=True))
        names.update({name: f"u{j}" for j, name in enumerate(inputs)})
        lines = [f"t{k} = {terms[k].to_source(names)}" for k in used]
        for i in range(n):
            parts = [f"{float(coef[i, k])!r}*t{k}" for k in used if coef[i, k] != 0.0]
            lines.append(f"{out}{i} = {' + '.join(parts) if parts else '0.0'}")
        return lines

    s = [f"s{i}" for i in range(n)]
    y = [f"y{i}" for i in range(n)]
    body = stage(s, "a")
    body += [f"y{i} = s{i} + 0.5 * h * a{i}" for i in range(n)] + stage(y, "b")
    body += [f"y{i} = s{i} + 0.5 * h * b{i}" for i in range(n)] + stage(y, "c")
    body += [f"y{i} = s{i} + h * c{i}" for i in range(n)] + stage(y, "d")
    body += [f"s{i} = s{i} + h / 6.0 * (a{i} + 2.0 * b{i} + 2.0 * c{i} + d{i})" for i in range(n)]
    unpack_u = f"    {', '.join(f'u{j}' for j in range(m))}, = row" if m else "    pass"
    inside = " and ".join(f"abs(s{i}) < limit" for i in range(n)) or "True"
    state = f"({', '.join(s)},)"
    lines = [
        "def run(x0, rows, h, nsub, limit):",
        f"  {', '.join(s)}, = x0" if n else "  pass",
        "  out = []",
        "  for k, row in enumerate(rows):",
        unpack_u.replace("    ", "    ", 1),
        "    try:",
        "      for _ in range(nsub):",
        *[f"        {line}" for line in body],
        "    except (OverflowError, ValueError, ZeroDivisionError):",
        "      return 'diverged', k, out",
        f"    if not ({inside}):  # also catches NaN",
        "      return 'diverged', k, out",
        f"    out.append({state})",
        "  return 'ok', len(rows), out",
    ]
    namespace = {f"_f_{name}": funcs[1] for name, funcs in FUNCTIONS.items()}
    exec(compile("\n".join(lines), "<cosim rk4>", "exec"), namespace)  # source built from checked ASTs only
    return namespace["run"]


#: Steps of one call of a CasADi run (the last call is padded with held inputs; its extra steps are dropped).
_CASADI_CHUNK = 1024
#: Records of at least this many steps are run by the chunk compiled to machine code (:mod:`._jit`, through the
#: system C compiler: 5.5 times faster a call than CasADi's interpreter, the same bits; 0.2 s to compile a
#: model structure the first time on a machine, then loaded from the cache); shorter ones by the interpreter.
#: One chunk: a decimated long record (4000 samples or more) is run compiled too; at 8 chunks its runs took
#: half of the timing record's diagnosis (benchmarks/bench_diagnosis.py, 16.3 -> 10.4 s).
_JIT_MIN_STEPS = _CASADI_CHUNK


def compile_rk4_casadi(states: Sequence[str], inputs: Sequence[str], terms: Sequence[Term], coef: np.ndarray):
    """:func:`compile_rk4` evaluated by CasADi: the same ``run(x0, rows, h, nsub, limit)``, several times faster.

    The RK4 step is built as a CasADi expression of the state, the input, the step, the non-zero coefficients
    and the numbers inside the terms (the last two as parameters, so that a model whose coefficients or
    nuisance values change reuses the built function: it is cached by structure), in the same order as
    :func:`compile_rk4` (the results are the same to the last bit on the models tried), and stepped
    :data:`_CASADI_CHUNK` samples a call (``mapaccum``). Where the Python step raises an arithmetic error
    CasADi yields inf or NaN, which the divergence check catches at the same step. ``rows`` may be an
    array (no list round trip).
    """
    numbers: list[float] = []
    used = [k for k in range(len(terms)) if np.any(coef[:, k] != 0.0)]
    sources = tuple(_emit(terms[k]._tree.body, {**{name: f"x[{i}]" for i, name in enumerate(states)},
                                                **{name: f"u[{j}]" for j, name in enumerate(inputs)}},
                          "python", numbers) for k in used)
    pattern = coef[:, used] != 0.0
    chunk = _casadi_step(len(states), len(inputs), sources, len(numbers), pattern.tobytes(), pattern.shape)
    params = np.concatenate([coef[:, used][pattern], np.asarray(numbers, dtype=float)])

    def run(x0, rows, h, nsub, limit):
        rows = np.asarray(rows, dtype=float).reshape(len(rows), len(inputs))
        runner = chunk(nsub, len(rows) >= _JIT_MIN_STEPS)
        return _chunked_run(runner, (h, params), x0, rows, limit)

    return run


def _chunked_run(function, tail: Sequence[Any], x0, rows: np.ndarray, limit: float):
    """Step a CasADi chunk ``function(state, rows, *tail)`` (:data:`_CASADI_CHUNK` steps, the rows as a
    (n_rows, chunk) matrix) over `rows` from `x0`, the last call padded with the last row held (its extra steps
    dropped); stop at the first state at or beyond `limit` (or NaN). Returns ``(status, steps done, states
    after each step)``.

    The function is evaluated on NumPy memory through CasADi's buffer interface (``Function.buffer``): a
    call with arrays converts each to a DM and back, 0.25 ms a call against 8 us, which was most of the
    time of a 20 000-sample run (20 calls). CasADi matrices are column-major, so a C-ordered (chunk, k) array
    is the (k, chunk) matrix the function takes and gives.
    """
    steps, n = len(rows), len(x0)
    state = np.array(x0, dtype=float).ravel()
    held = np.empty((_CASADI_CHUNK, rows.shape[1]))
    result = np.empty((_CASADI_CHUNK, n))
    fixed = [np.ascontiguousarray(np.atleast_1d(value), dtype=float) for value in tail]
    buffer, evaluate = function.buffer()
    for i, array in enumerate([state, held, *fixed]):
        buffer.set_arg(i, memoryview(array))
    buffer.set_res(0, memoryview(result))
    out = np.empty((steps, n))
    for first in range(0, steps, _CASADI_CHUNK):
        block = rows[first:first + _CASADI_CHUNK]
        k = len(block)
        held[:k] = block
        held[k:] = block[-1]
        evaluate()
        bad = ~np.all(np.abs(result[:k]) < limit, axis=1)  # also catches NaN
        if bad.any():
            j = int(np.argmax(bad))
            out[first:first + j] = result[:j]
            return "diverged", first + j, out[:first + j]
        out[first:first + k] = result[:k]
        state[:] = result[k - 1]
    return "ok", steps, out


@lru_cache(maxsize=64)
def _casadi_step(n: int, m: int, sources: tuple[str, ...], n_numbers: int, pattern_bytes: bytes,
                 shape: tuple[int, int]):
    """The chunked RK4 run of a model structure, per number of substeps (built once, then cached)."""
    import casadi as ca

    pattern = np.frombuffer(pattern_bytes, dtype=bool).reshape(shape)
    x, u, h = ca.SX.sym("x", n), ca.SX.sym("u", m), ca.SX.sym("h")
    n_coef = int(pattern.sum())
    p = ca.SX.sym("p", n_coef + n_numbers)
    namespace = {f"_f_{name}": getattr(ca, {"abs": "fabs"}.get(name, name)) for name in FUNCTIONS}
    rows, c = [], 0
    for i in range(n):
        row = []
        for t in range(shape[1]):
            if pattern[i, t]:
                row.append((p[c], t))
                c += 1
        rows.append(row)
    code = [compile(src, "<cosim term>", "eval") for src in sources]

    def rhs(s):
        local = {"x": s, "u": [u[j] for j in range(m)], "k": [p[n_coef + q] for q in range(n_numbers)]}
        t = [eval(c_, namespace, local) for c_ in code]  # source built from checked ASTs only
        out = []
        for row in rows:
            acc = None
            for coefficient, term in row:
                acc = coefficient * t[term] if acc is None else acc + coefficient * t[term]
            out.append(ca.SX(0.0) if acc is None else acc)
        return out

    @lru_cache(maxsize=8)
    def chunk(nsub: int, jit: bool = False):
        if jit:
            from ._jit import compiled  # machine code, or None where no C compiler works

            return compiled(chunk(nsub), "cosim_rk4") or chunk(nsub)
        return _whole_chunk(steps(nsub), n, m, n_coef + n_numbers)

    def steps(nsub: int):
        s = [x[i] for i in range(n)]
        for _ in range(nsub):  # the arithmetic of compile_rk4, in its order
            a = rhs(s)
            b = rhs([s[i] + 0.5 * h * a[i] for i in range(n)])
            c_ = rhs([s[i] + 0.5 * h * b[i] for i in range(n)])
            d = rhs([s[i] + h * c_[i] for i in range(n)])
            s = [s[i] + h / 6.0 * (a[i] + 2.0 * b[i] + 2.0 * c_[i] + d[i]) for i in range(n)]
        step = ca.Function("rk4_step", [x, u, h, p], [ca.vertcat(*s)])
        return step.mapaccum("rk4_run", _CASADI_CHUNK, [0], [0])

    return chunk


def _whole_chunk(mapped, n: int, m: int, n_params: int):
    """The mapped RK4 steps `mapped` (their step and parameters repeated per column) as one function of the
    state, the (m, chunk) inputs, one step and one parameter vector: the arguments :func:`_chunked_run` gives
    through CasADi's buffer interface, which does not repeat a column as a call does."""
    import casadi as ca

    x, u, h, p = ca.MX.sym("x", n), ca.MX.sym("u", m, _CASADI_CHUNK), ca.MX.sym("h"), ca.MX.sym("p", n_params)
    return ca.Function("cosim_rk4", [x, u, h, p], [mapped(x, u, h, p)])


def compile_linear_run(ad: np.ndarray):
    """A compiled run of ``x[k+1] = ad @ x[k] + d[k]`` with the arithmetic of the Python step of a linear model
    (``a_i0*x0 + a_i1*x1 + ... + d_i``, non-zero entries, in that order: the same bits), as
    ``run(x0, drive, limit) -> (status, k, states)`` like :func:`compile_rk4_casadi`'s; None where nothing can
    be compiled. For long records: a Python loop costs 50 ms a 20 000-sample run, this one 2 ms."""
    pattern = np.asarray(ad) != 0.0
    chunk = _linear_chunk(pattern.shape[0], pattern.tobytes())
    if chunk is None:
        return None
    params = np.asarray(ad, dtype=float)[pattern]

    def run(x0, drive, limit):
        return _chunked_run(chunk, (params,), x0, np.asarray(drive, dtype=float), limit)

    return run


@lru_cache(maxsize=32)
def _linear_chunk(n: int, pattern_bytes: bytes):
    """The compiled chunk of a linear step with this sparsity (coefficients as parameters), or None."""
    import casadi as ca

    from ._jit import compiled

    pattern = np.frombuffer(pattern_bytes, dtype=bool).reshape(n, n)
    s, d, p = ca.SX.sym("s", n), ca.SX.sym("d", n), ca.SX.sym("p", int(pattern.sum()))
    rows, c = [], 0
    for i in range(n):
        acc = None
        for j in range(n):
            if pattern[i, j]:
                acc = p[c] * s[j] if acc is None else acc + p[c] * s[j]
                c += 1
        rows.append(d[i] if acc is None else acc + d[i])
    run = ca.Function("linear_step", [s, d, p], [ca.vertcat(*rows)]).mapaccum("linear_run", _CASADI_CHUNK, [0], [0])
    x, u, q = ca.MX.sym("x", n), ca.MX.sym("d", n, _CASADI_CHUNK), ca.MX.sym("p", int(pattern.sum()))
    return compiled(ca.Function("cosim_linear", [x, u, q], [run(x, u, q)]), "cosim_linear")
