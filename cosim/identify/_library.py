"""The structure of a :class:`~cosim.identify.sindyc.SINDYc` model: its library terms and fixed kinematic rows.

:func:`_library_terms` lists the library ``theta(x, u)`` (step 1 of the :mod:`cosim.identify.sindyc`
docstring): constant, states and inputs, or all their monomials up to a degree, plus the user's terms.
:func:`_kinematic_rows` gathers the known rows ``d position/dt = velocity`` (step 4), from ``kinematics=`` and
from the velocities derived from positions (``velocities=``).

Examples
--------
>>> kin = _kinematic_rows({"x": "v"}, None, ["x", "v"])
>>> _library_terms("linear", 2, True, ["x*u"], ["x", "v"], ["u"], kin)
['1', 'x', 'v', 'u', 'x*u']
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import InvalidSettingError, UnknownVariableError
from ._settings import _check_mapping
from .terms import Term, polynomial_terms


def _kinematic_rows(kinematics: Any, velocities: Mapping[str, str] | None,
                    state_names: Sequence[str]) -> dict[str, str]:
    """The fixed kinematic rows, position state -> velocity state, checked against the states."""
    kin = _check_mapping("kinematics", kinematics)
    for vel, pos in (velocities or {}).items():
        if kin.get(pos, vel) != vel:
            raise InvalidSettingError(f"kinematics says d{pos}/dt = {kin[pos]} but velocities derives {vel} "
                                      f"from {pos}; make them agree")
        kin[pos] = vel
    for pos, vel in kin.items():
        for name in (pos, vel):
            if name not in state_names:
                raise UnknownVariableError(f"kinematics names {name!r}, which is not a state; states: "
                                           f"{', '.join(state_names)}")
    return kin


def _library_terms(library: str, degree: int, include_constant: bool, terms: Sequence[str],
                   state_names: list[str], input_names: list[str], kin: Mapping[str, str]) -> list[str]:
    """The library's terms as text: ``library`` ("linear" or "polynomial" of `degree`), then the user's `terms`.

    Every term of a kinematic row of `kin` must be in it.
    """
    names = state_names + input_names
    if library == "linear":
        found = (["1"] if include_constant else []) + names
    else:
        found = polynomial_terms(names, int(degree), include_bias=include_constant)
    for text in terms:
        term = Term(text)
        term.check_names(names)
        if term.text not in found:
            found.append(term.text)
    if not found:
        raise InvalidSettingError("the library is empty: include the constant or add states, inputs, terms")
    for pos, vel in kin.items():
        if vel not in found:
            raise InvalidSettingError(f"kinematic row {pos}' = {vel} needs the term {vel!r} in the library")
    return found
