"""A :class:`~cosim.plant.system_structure.System` checked against its FMUs: :func:`wire`.

What a system file cannot say by itself is decided here from the FMUs' model descriptions:

* every connection joins an output to an input of the same kind of value (a number to a number of its kind), and
  its units agree or convert (SSP's rule: units defined over the same base units are converted; others refused);
* the system's free inputs are the component inputs no connection drives, its outputs every component output;
* the order a Gauss-Seidel master steps the components in: from the FMUs' declared output dependencies, a
  component whose outputs answer an input at once (direct feedthrough) steps after the component that drives
  that input;
* algebraic loops: a cycle of connections each reaching an output that depends directly on it. A cycle only
  through outputs whose dependencies the FMU does not declare is a *possible* loop (FMI says to assume
  feedthrough there; most exporters simply leave the attribute out) and is reported as such.

Examples
--------
>>> from cosim.plant.build import build_ssp
>>> from cosim.plant.system_structure import read_system
>>> w = wire(read_system(build_ssp()))
>>> w.inputs, w.order
(('motor.Tm', 'load.TL'), ('motor', 'load'))
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..errors import CosimError, InvalidSettingError, UnknownVariableError
from ._fmu_description import _close_matches, interface_kind, open_model_description, variable_unit
from ._variables import NUMERIC, expand_signals
from .system_structure import Connection, System, split_name

__all__ = ["Link", "Wiring", "wire"]


@dataclass(frozen=True)
class Link:
    """A resolved connection: ``end = factor * start + offset`` (unit conversion and transformation composed)."""

    start: tuple[str, str]  # (component, variable)
    end: tuple[str, str]
    factor: float
    offset: float


@dataclass(frozen=True)
class Wiring:
    """What :func:`wire` found: the system, its components' model descriptions and interfaces, free inputs,
    outputs, the links, the stepping order and the loops."""

    system: System
    descriptions: Mapping[str, Any]
    kinds: Mapping[str, str]
    inputs: tuple[str, ...]  # free inputs, component.variable
    outputs: tuple[str, ...]  # every component output, component.variable
    links: tuple[Link, ...]
    order: tuple[str, ...]  # Gauss-Seidel order of the components
    loops: tuple[tuple[str, ...], ...] = ()  # algebraic loops through declared feedthrough (connector names)
    possible_loops: tuple[tuple[str, ...], ...] = ()  # cycles only through undeclared dependencies
    component_inputs: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # per component, all it takes


def _kind(var: Any) -> str:
    from ._variables import kind_of

    return kind_of(var.type)


def wire(system: System) -> Wiring:
    """Check `system` against its FMUs and resolve it (see the module's docstring).

    Raises
    ------
    UnknownVariableError
        A connection names a variable its FMU does not have.
    InvalidSettingError
        A connection joins values of different kinds, an output to an output, or units that differ with no
        conversion.
    """
    mds, kinds, signals = {}, {}, {}
    for name, comp in system.components.items():
        try:
            md = open_model_description(comp.source, comp.kind)
            mds[name], kinds[name] = md, interface_kind(md, comp.kind)
        except CosimError as exc:  # the same error, saying which component: a system may hold many FMUs
            raise type(exc)(f"component {name}: {exc}") from None
        signals[name] = expand_signals(md.modelVariables)
    units = _unit_table(system, mds)
    links = []
    for c in system.connections:
        links.append(_link(c, system, signals, units))
    driven = {link.end for link in links}
    inputs, outputs, component_inputs = [], [], {}
    for name in system.components:
        numeric = [s for s in signals[name].values()
                   if s.kind in NUMERIC and not (s.shape and s.offset is None)]
        ins = tuple(s.name for s in numeric if s.var.causality == "input")
        component_inputs[name] = ins
        inputs += [f"{name}.{v}" for v in ins if (name, v) not in driven]
        outputs += [f"{name}.{s.name}" for s in numeric if s.var.causality == "output"]
    feeds = _feedthrough(mds, signals)
    order, loops, possible = _order(system, links, feeds)
    return Wiring(system, mds, kinds, tuple(inputs), tuple(outputs), tuple(links), order, loops, possible,
                  component_inputs)


def _link(c: Connection, system: System, signals: Mapping[str, Any], units: Mapping[str, tuple]) -> Link:
    where = f"connection {c.start} -> {c.end}"
    ends = []
    for side, causality in ((c.start, "output"), (c.end, "input")):
        comp, var = split_name(side, system.components, what=where)
        sig = signals[comp].get(var)
        if sig is None or (sig.shape and sig.offset is None):
            raise UnknownVariableError(f"{where}: {system.components[comp].source.name} (component {comp}) has no "
                                       f"variable {var}.{_close_matches(var, signals[comp])}")
        if sig.var.causality != causality and not (causality == "output" and sig.var.causality == "local"):
            raise InvalidSettingError(f"{where}: {side} is {'an' if sig.var.causality[0] in 'aeiou' else 'a'} "
                                      f"{sig.var.causality}, not {'an' if causality == 'output' else 'an'} "
                                      f"{causality}; a connection runs from an output to an input")
        ends.append((comp, var, sig))
    (sc, sv, ss), (ec, ev, es) = ends
    if ss.kind != es.kind or ss.kind not in NUMERIC:
        raise InvalidSettingError(f"{where}: a connector of the wrong type: {c.start} is {ss.var.type}, {c.end} is "
                                  f"{es.var.type}; connect values of one kind (a float to a float)")
    factor, offset = 1.0, 0.0
    su = system.components[sc].units.get(sv) or variable_unit(ss.var)
    eu = system.components[ec].units.get(ev) or variable_unit(es.var)
    if c.convert_units and su and eu and su != eu:
        a, b = units.get(su), units.get(eu)
        if a is None or b is None or a[:8] != b[:8]:
            undefined = [u for u, d in ((su, a), (eu, b)) if d is None]
            why = (f"{' and '.join(undefined)} {'is' if len(undefined) == 1 else 'are'} not defined over SI base "
                   "units" if undefined else "they measure different quantities")
            raise InvalidSettingError(f"{where}: units that differ with no conversion: {c.start} is in {su}, "
                                      f"{c.end} in {eu} ({why}); define both in the system's Units, or give the "
                                      "connection a LinearTransformation with suppressUnitConversion=\"true\"")
        factor, offset = a[8] / b[8], (a[9] - b[9]) / b[8]  # to SI, then from SI
    return Link((sc, sv), (ec, ev), c.factor * factor, c.factor * offset + c.offset)


def _unit_table(system: System, mds: Mapping[str, Any]) -> dict[str, tuple]:
    """Unit name -> (8 base-unit exponents, factor, offset) from every FMU's UnitDefinitions and the system's."""
    table: dict[str, tuple] = {}
    for md in mds.values():
        for u in getattr(md, "unitDefinitions", None) or []:
            b = u.baseUnit
            if b is not None:
                table[u.name] = (b.kg, b.m, b.s, b.A, b.K, b.mol, b.cd, b.rad, float(b.factor), float(b.offset))
    table.update({k: tuple(v) for k, v in system.unit_definitions.items()})
    return table


def _feedthrough(mds: Mapping[str, Any], signals: Mapping[str, Any]) -> dict[str, dict[str, set | None]]:
    """Per component, per output: the inputs it depends on directly (None: not declared, so possibly all)."""
    out: dict[str, dict[str, set | None]] = {}
    for name, md in mds.items():
        per: dict[str, set | None] = {}
        for o in md.outputs:
            deps = o.dependencies
            per[o.variable.name] = None if deps is None else {d.name for d in deps if d.causality == "input"}
        out[name] = per
    return out


def _order(system: System, links: tuple[Link, ...] | list[Link],
           feeds: Mapping[str, Mapping[str, set | None]]) -> tuple[tuple[str, ...], tuple, tuple]:
    """The Gauss-Seidel order and the loops (see the module's docstring)."""
    names = list(system.components)

    def instant(link: Link, strict: bool) -> bool:
        """Whether the input `link` drives reaches an output of its component at once."""
        comp, var = link.end
        for deps in feeds[comp].values():
            if deps is None and not strict:
                return True
            if deps is not None and var in deps:
                return True
        return False

    loops = _cycles(names, links, lambda lk: instant(lk, True), feeds)
    possible = [c for c in _cycles(names, links, lambda lk: instant(lk, False), feeds) if c not in loops]
    # Kahn's algorithm: instant edges must be respected (unless they close a loop), the others followed where they
    # do not close a cycle; ties in declaration order
    edges: set[tuple[str, str]] = set()
    for strict in (True, False):
        for lk in links:
            a, b = lk.start[0], lk.end[0]
            if a != b and instant(lk, strict) and not _reaches(edges, b, a):
                edges.add((a, b))
    for lk in links:
        a, b = lk.start[0], lk.end[0]
        if a != b and not _reaches(edges, b, a):
            edges.add((a, b))
    order: list[str] = []
    left = list(names)
    while left:
        ready = next(n for n in left if not any((m, n) in edges for m in left if m != n))
        order.append(ready)
        left.remove(ready)
    return tuple(order), tuple(loops), tuple(possible)


def _reaches(edges: set[tuple[str, str]], a: str, b: str) -> bool:
    seen, todo = {a}, [a]
    while todo:
        n = todo.pop()
        if n == b:
            return True
        for x, y in edges:
            if x == n and y not in seen:
                seen.add(y)
                todo.append(y)
    return False


def _cycles(names: list[str], links, is_instant, feeds) -> list[tuple[str, ...]]:
    """Algebraic loops at the connectors' level: output -> input (a link) -> output of the same component that
    depends on it at once. Each loop once, as the connector names along it (outputs and the inputs they drive),
    starting at its smallest output."""
    graph: dict[str, set[tuple[str, str]]] = {}
    for lk in links:
        if not is_instant(lk):
            continue
        src = f"{lk.start[0]}.{lk.start[1]}"
        comp, var = lk.end
        for out, deps in feeds[comp].items():
            if deps is None or var in deps:
                graph.setdefault(src, set()).add((f"{comp}.{var}", f"{comp}.{out}"))
    found: list[tuple[str, ...]] = []
    for start in sorted(graph):
        stack = [(start, (start,), (start,))]
        while stack:
            node, outs, path = stack.pop()
            for via, nxt in sorted(graph.get(node, ())):
                if nxt == start:
                    if min(outs) == start and (*path, via) not in found:
                        found.append((*path, via))
                elif nxt not in outs:
                    stack.append((nxt, (*outs, nxt), (*path, via, nxt)))
    return found


def check_names(wiring: Wiring, names: list[str], role: str) -> None:
    """Refuse a name that is not one of the system's free inputs (``role="input"``) or recordable variables."""
    pool = wiring.inputs if role == "input" else None
    for n in names:
        if pool is not None and n not in pool:
            raise UnknownVariableError(f"{n} is not a free input of the system.{_close_matches(n, pool)}")
    if role != "input":
        signals: dict[str, Any] = {}  # each component's signals, expanded once
        for n in names:
            comp, var = split_name(n, wiring.system.components, what=role)
            if comp not in signals:
                signals[comp] = expand_signals(wiring.descriptions[comp].modelVariables)
            if var not in signals[comp]:
                raise UnknownVariableError(f"{n}: component {comp} has no variable {var}")


def description(wiring: Wiring) -> Any:
    """The system as one FMU's model description (an FMPy ``ModelDescription``), for everything that reads one:
    every component variable under its ``component.variable`` name; the connected inputs become locals, so that
    the inputs are the free ones; states keep their derivatives; units from every component's definitions. What
    validation, robustness and the reports read of a plant (parameters, an input's declared range, units) then
    reads the same of a system."""
    import attrs
    from fmpy.model_description import CoSimulation, DefaultExperiment, ModelDescription, Unknown

    system = wiring.system
    driven = {link.end for link in wiring.links}
    copies: dict[int, Any] = {}
    variables = []
    for name, md in wiring.descriptions.items():
        for v in md.modelVariables:
            if v.causality == "independent" and variables:
                continue  # one time variable
            full = v.name if v.causality == "independent" else f"{name}.{v.name}"
            causality = "local" if (name, v.name) in driven else v.causality
            copies[id(v)] = attrs.evolve(v, name=full, causality=causality)
            variables.append(copies[id(v)])
    for md in wiring.descriptions.values():
        for v in md.modelVariables:
            if getattr(v, "derivative", None) is not None and id(v.derivative) in copies:
                copies[id(v)].derivative = copies[id(v.derivative)]
    outputs = [Unknown(index=0, variable=copies[id(o.variable)], dependencies=None)
               for md in wiring.descriptions.values() for o in md.outputs]
    units = {u.name: u for md in wiring.descriptions.values() for u in (md.unitDefinitions or [])}
    versions = sorted({md.fmiVersion for md in wiring.descriptions.values()})
    return ModelDescription(
        fmiVersion="/".join(versions), modelName=system.name, description=f"a system of {len(system.components)} "
        f"FMUs ({', '.join(system.components)})", generationTool="cosim (a system of FMUs)",
        coSimulation=CoSimulation(modelIdentifier=system.name), modelVariables=variables, outputs=outputs,
        unitDefinitions=list(units.values()),
        defaultExperiment=DefaultExperiment(stepSize=str(system.dt)) if system.dt else None)
