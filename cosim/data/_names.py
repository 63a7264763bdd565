"""Signal names as FMUs write them, inside expressions: the one place where a name becomes an identifier.

Modelica tools export FMUs whose variables are dotted (``mass.s``), indexed (``x[2]``, an FMI 3 array element
``A[1,2]``), derivatives (``der(x)``, ``der(mass.s, 2)``) or quoted (FMI 2's ``'my var'``). Such a name is no
Python identifier, so an expression written over it (a library term ``sign(mass.v)*extForce``, a column
``force=2*mass.f``) cannot be parsed by :mod:`ast` as it is. :func:`safe_name` maps every name that is not
already a plain identifier to one (reversibly, :func:`real_name` maps it back); :func:`parse_expression` parses
a text with its names mapped and puts the real names back into the tree's :class:`ast.Name` nodes, so that the
code walking the tree (evaluation, derivatives, code generation) sees the names as written.

A plain identifier (``omega_m``) is its own safe name: models, terms and files written before stay as they were.
python-control keeps ``.`` for ``system.signal`` and refuses it in an input or output name: there a name's dots
are written :data:`CONTROL_DOT` (:func:`control_label`, reversed by :func:`label_name`); a state keeps its name.

Index brackets holding ``:`` (``data[:,2]``, a ``.mat`` matrix's column) or a ``0`` (Modelica indices start
at 1) are not part of a name: they stay Python subscripts, for :mod:`._column_expressions`.

Examples
--------
>>> safe_name("mass.s")
'_m_mass_2e_s'
>>> real_name(safe_name("der(mass.s)"))
'der(mass.s)'
>>> safe_name("omega_m")
'omega_m'
>>> import ast
>>> ast.dump(parse_expression("sign(mass.v)*u").body.left.args[0])
"Name(id='mass.v', ctx=Load())"
>>> expression_names("sign(mass.v)*extForce + x[2] - 'my var'")
('sign', 'mass.v', 'extForce', 'x[2]', "'my var'")
"""

from __future__ import annotations

import ast
import keyword
import re

from ..errors import InvalidSettingError

__all__ = ["CONTROL_DOT", "control_label", "expression_names", "is_name", "is_plain", "label_name", "parse_expression",
           "real_name", "safe_name", "with_safe_names"]

#: The start of every mapped name; a plain name starting so is mapped too, so that the mapping stays reversible.
PREFIX = "_m_"

#: A name's part: letters (any alphabet), digits, ``_`` and ``$`` (OpenModelica's ``$PRE``), not starting with a
#: digit; or a quoted Modelica identifier (``'my var'``, ``\'`` escaping a quote).
_IDENT = r"(?:(?:[^\W\d]|\$)(?:\w|\$)*|'(?:[^'\\]|\\.)+')"
_INDEX = r"[1-9][0-9]*"
_SUBSCRIPT = rf"(?:\[\s*{_INDEX}(?:\s*,\s*{_INDEX})*\s*\])"
_PART = rf"{_IDENT}{_SUBSCRIPT}?"
_NAME = rf"{_PART}(?:\.{_PART})*"
#: A derivative ``der(NAME)`` or ``der(NAME, k)``, tried before a name; then a name; a number is skipped whole
#: (so that the ``e5`` of ``1e5`` or the ``.5`` of ``1.5`` is no name).
_TOKEN = re.compile(rf"(?P<number>(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)"
                    rf"|(?P<name>der\(\s*{_NAME}(?:\s*,\s*{_INDEX})?\s*\)|{_NAME})")


def is_name(text: str) -> bool:
    """`text` is one name, as FMUs write it (``mass.s``, ``x[2]``, ``der(x)``, ``'my var'``, ``omega_m``).

    Examples
    --------
    >>> is_name("der(mass.s)"), is_name("2*x"), is_name("data[:,2]")
    (True, False, False)
    """
    match = _TOKEN.fullmatch(str(text))
    return bool(match and match.group("name"))


def is_plain(name: str) -> bool:
    """`name` is its own safe name: a Python identifier, no keyword, not starting with :data:`PREFIX`."""
    return name.isidentifier() and not keyword.iskeyword(name) and not name.startswith(PREFIX)


def safe_name(name: str) -> str:
    """`name` as an identifier of Python and C: itself when plain (:func:`is_plain`), else :data:`PREFIX` and
    its characters, letters and digits as they are and any other as ``_<hex code>_``.

    Examples
    --------
    >>> safe_name("x[2]"), safe_name("'my var'")
    ('_m_x_5b_2_5d_', '_m__27_my_20_var_27_')
    """
    name = str(name)
    if is_plain(name):
        return name
    return PREFIX + "".join(c if c.isascii() and c.isalnum() else f"_{ord(c):x}_" for c in name)


def real_name(safe: str) -> str:
    """The name :func:`safe_name` mapped to `safe` (`safe` itself when it is not a mapped name).

    Examples
    --------
    >>> real_name("_m_A_5b_1_2c_2_5d_"), real_name("omega_m")
    ('A[1,2]', 'omega_m')
    """
    if not safe.startswith(PREFIX):
        return safe
    return re.sub(r"_([0-9a-f]+)_", lambda m: chr(int(m.group(1), 16)), safe[len(PREFIX):])


def _spans(text: str):
    """(start, end, name) of each name in `text`, left to right (function names such as ``sin`` included)."""
    for match in _TOKEN.finditer(text):
        if match.group("name"):
            yield match.start(), match.end(), match.group("name")


def expression_names(text: str) -> tuple[str, ...]:
    """The names `text` writes, as written (functions too), each once, left to right."""
    return tuple(dict.fromkeys(name for _, _, name in _spans(text)))


def with_safe_names(text: str) -> str:
    """`text` with every name that is not plain replaced by its :func:`safe_name`.

    Examples
    --------
    >>> with_safe_names("der(x) + 2*mass.v")
    '_m_der_28_x_29_ + 2*_m_mass_2e_v'
    """
    out, last = [], 0
    for start, end, name in _spans(text):
        out += [text[last:start], safe_name(name)]
        last = end
    return "".join(out) + text[last:]


def parse_expression(text: str) -> ast.Expression:
    """`text` parsed as a Python expression (:func:`ast.parse`, ``mode="eval"``) whose names may be FMU names;
    each :class:`ast.Name` of the tree holds the name as written (``mass.s``), not its safe name.

    Raises
    ------
    SyntaxError
        `text` is no expression.
    """
    tree = ast.parse(with_safe_names(str(text)), mode="eval")
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            node.id = real_name(node.id)
    return tree


#: What the dots of a name become in a python-control input or output name (:func:`control_label`).
CONTROL_DOT = ":"


def control_label(name: str, *, keep_dots: bool = False) -> str:
    """`name` as a python-control signal name: its dots written :data:`CONTROL_DOT` (``mass.s`` ->
    ``mass:s``), or kept with `keep_dots` (a state's name may hold dots). :func:`label_name` reverses it.

    Raises
    ------
    InvalidSettingError
        `name` holds :data:`CONTROL_DOT` itself, which would not read back.

    Examples
    --------
    >>> control_label("mass.s"), label_name("mass:s"), control_label("der(x)")
    ('mass:s', 'mass.s', 'der(x)')
    """
    name = str(name)
    if CONTROL_DOT in name:
        raise InvalidSettingError(f"signal name {name!r} holds {CONTROL_DOT!r}, which python-control signal names "
                                  f"use for '.'; rename the signal")
    return name if keep_dots else name.replace(".", CONTROL_DOT)


def label_name(label: str) -> str:
    """The signal name a python-control `label` stands for (:func:`control_label` reversed)."""
    return str(label).replace(CONTROL_DOT, ".")
