"""``cosim fmu build`` and ``cosim fmu info``: the bundled FMU built from its C source, any FMU described."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ._command import _emit, _friendly, _resolve_fmu

__all__ = ["fmu"]


@click.group()
def fmu() -> None:
    """Build and inspect FMUs."""


@fmu.command("build")
@click.option("--fmi", "fmi_version", type=click.Choice(["2.0", "3.0"]), default="2.0", show_default=True,
              help="FMI version of the FMU to build.")
@click.option("--force", is_flag=True, help="Rebuild even if the cache holds it.")
@click.option("--json", "as_json", is_flag=True, help="Print {\"path\": ...} as JSON.")
@_friendly
def fmu_build(fmi_version: str, force: bool, as_json: bool) -> None:
    """Build the bundled two-mass servo FMU from its C source (cached) and print its path.

    \b
    Example:
      cosim fmu build --fmi 3.0 --json
    """
    from ..plant.build import build_fmu

    path = build_fmu(fmi_version=fmi_version, force=force)
    _emit(as_json, {"path": str(path), "fmi_version": fmi_version}, str(path))


@fmu.command("info")
@click.argument("path")
@click.option("--all", "show_all", is_flag=True,
              help="Also list the local variables (what `cosim simulate --record` can record beside the outputs).")
@click.option("--input", "-i", "inputs", multiple=True, metavar="NAME[=SPEC]",
              help="An input a run would drive, as `cosim simulate --input` gives it: the inputs are then listed as "
                   "driven or left to the FMU.")
@click.option("--input-file", "input_file", type=click.Path(dir_okay=False), default=None, metavar="DATA",
              help="A file a run would take inputs from, as `cosim simulate --input-file`: its columns named as "
                   "inputs are driven.")
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
@_friendly
def fmu_info(path: str, show_all: bool, inputs: tuple[str, ...], input_file: str | None, as_json: bool) -> None:
    """Describe an FMU: inputs, outputs, states, parameters with units and start values.

    PATH is an .fmu file, or `bundled` for the bundled servo.

    A run drives only the inputs it is given (--input, --input-file, a controller's inputs, a disturbance); the
    others are left to the FMU after their start values, as FMPy leaves them. With --input/--input-file, the
    inputs are listed as driven or left, as `cosim simulate` would run them.

    \b
    Example:
      cosim fmu info bundled
      cosim fmu info bundled --all --json
      cosim fmu info model.fmu --input-file force.csv
    """
    from ..plant._variables import NUMERIC, expand_signals, shape_of
    from ..plant.model_description import open_model_description
    from ..plant.system_structure import is_system_file

    fmu_path = _resolve_fmu(path)
    if is_system_file(fmu_path):
        _system_info(fmu_path, as_json)
        return
    md = open_model_description(fmu_path)
    driven = _driven(fmu_path, [s for s in expand_signals(md.modelVariables).values() if s.var.causality == "input"
                                and s.kind in NUMERIC and not (s.shape and s.offset is None)], inputs, input_file)
    starts = {v.name: v.start for v in md.modelVariables}

    def describe(v: Any) -> dict[str, Any]:
        d = {"name": v.name, "type": v.type, "unit": v.unit or "", "start": _typed(v.type, v.start),
             "description": v.description or ""}
        for key in ("min", "max"):
            if getattr(v, key, None) not in (None, ""):
                d[key] = _typed(v.type, getattr(v, key))
        if getattr(v, "dimensions", None):  # an FMI 3 array: its elements are the signals v[1,1]...
            d["shape"] = list(shape_of(v, starts))
        return d

    groups = {c: [describe(v) for v in md.modelVariables if v.causality == c]
              for c in ("input", "output", "parameter", "local")}
    states = [v.derivative.name for v in md.modelVariables if getattr(v, "derivative", None) is not None]
    info = {
        "path": str(fmu_path), "model": md.modelName, "fmi_version": md.fmiVersion,
        "model_identifier": (md.coSimulation or md.modelExchange).modelIdentifier,
        "kinds": [k for k, i in (("cs", md.coSimulation), ("me", md.modelExchange)) if i is not None],
        "generation_tool": md.generationTool,
        "inputs": groups["input"], "driven": driven[0], "left": driven[1],
        "outputs": groups["output"], "parameters": groups["parameter"],
        "states": states, **({"locals": groups["local"]} if show_all else {}),
        "default_step": _typed("Float64", getattr(md.defaultExperiment, "stepSize", None))
        if md.defaultExperiment else None,
    }
    kinds = " and ".join({"cs": "co-simulation", "me": "Model Exchange"}[k] for k in info["kinds"])
    lines = [f"{md.modelName} (FMI {md.fmiVersion}, {kinds}, {md.generationTool or 'unknown tool'})",
             f"  file: {fmu_path}"]
    for title, key in (("inputs", "inputs"), ("outputs", "outputs"), ("parameters", "parameters"),
                       *((("locals", "locals"),) if show_all else ())):
        lines.append(f"  {title}:")
        for d in info[key]:
            rng = f"  [{d.get('min', '')}, {d.get('max', '')}]" if "min" in d or "max" in d else ""
            start = "" if d["start"] is None else d["start"]
            kind = d["type"] + (f"[{'x'.join(map(str, d['shape']))}]" if "shape" in d else "")
            lines.append(f"    {d['name']:<12} {kind:<10} {start!s:>10} {d['unit']:<12}{rng}  {d['description']}")
        if key == "inputs":
            lines.append(f"  {_RULE}" if not (inputs or input_file) else
                         f"  a run with these options drives {', '.join(driven[0]) or 'no input'}"
                         + (f"; leaves {', '.join(driven[1])} to the FMU (start value set once)" if driven[1]
                            else ""))
    lines.append(f"  states: {', '.join(states) or 'not declared'}")
    _emit(as_json, info, "\n".join(lines))


def _system_info(path: Any, as_json: bool) -> None:
    """``cosim fmu info`` of a system of FMUs: its components, connections, free inputs, outputs, the order a
    Gauss-Seidel master steps them in, and the loops found."""
    from ..plant.system_structure import read_system
    from ..plant.system_wiring import wire

    system = read_system(path)
    w = wire(system)
    comps = [{"name": n, "fmu": str(c.source), "model": w.descriptions[n].modelName,
              "fmi_version": w.descriptions[n].fmiVersion, "kind": w.kinds[n], "step_multiple": c.step_multiple,
              "parameters": {k: v for k, v in c.parameters.items()}} for n, c in system.components.items()]
    links = [{"from": f"{lk.start[0]}.{lk.start[1]}", "to": f"{lk.end[0]}.{lk.end[1]}", "factor": lk.factor,
              "offset": lk.offset} for lk in w.links]
    info = {"path": str(path), "system": system.name, "components": comps, "connections": links,
            "inputs": list(w.inputs), "outputs": list(w.outputs), "order": list(w.order),
            "loops": [list(x) for x in w.loops], "possible_loops": [list(x) for x in w.possible_loops],
            "default_step": system.dt}
    lines = [f"{system.name}: a system of {len(comps)} FMUs", f"  file: {path}", "  components:"]
    for c in comps:
        every = f", every {c['step_multiple']} steps" if c["step_multiple"] > 1 else ""
        bound = f"; sets {', '.join(f'{k}={v}' for k, v in c['parameters'].items())}" if c["parameters"] else ""
        lines.append(f"    {c['name']:<12} {Path(c['fmu']).name} (FMI {c['fmi_version']}, {c['kind']}{every}){bound}")
    lines.append("  connections:")
    for lk in links:
        scale = "" if (lk["factor"], lk["offset"]) == (1.0, 0.0) else f"  (x {lk['factor']:g} + {lk['offset']:g})"
        lines.append(f"    {lk['from']} -> {lk['to']}{scale}")
    lines.append(f"  free inputs: {', '.join(w.inputs) or 'none'}")
    lines.append(f"  outputs: {', '.join(w.outputs)}")
    lines.append(f"  Gauss-Seidel order: {', '.join(w.order)}")
    loops = [" -> ".join((*x, x[0])) for x in w.loops]
    maybe = [" -> ".join((*x, x[0])) for x in w.possible_loops]
    lines.append(f"  algebraic loops: {'; '.join(loops) or 'none'}"
                 + (f"; possible through undeclared output dependencies: {'; '.join(maybe)}" if maybe else ""))
    _emit(as_json, info, "\n".join(lines))


_RULE = ("a run drives only the inputs it is given (--input, --input-file, a controller's, a disturbance); the "
         "others are left to the FMU after their start values")


def _driven(fmu_path: Any, signals: list[Any], inputs: tuple[str, ...], input_file: str | None
            ) -> tuple[list[str], list[str]]:
    """The FMU's numeric inputs a run given `inputs` (NAME or NAME=SPEC) and `input_file` drives, and the others."""
    from ..errors import UnknownVariableError
    from ..plant._fmu_description import _close_matches

    names = [s.name for s in signals]
    given = [item.partition("=")[0].strip() for item in inputs]
    for name in given:
        if name not in names:
            raise UnknownVariableError(f"--input {name}: {fmu_path.name} has no input named {name!r}."
                                       + _close_matches(name, names))
    if input_file:
        from ..data.datafile import file_variables

        given += file_variables(input_file)
    driven = [name for name in names if name in given]
    return driven, [name for name in names if name not in driven]


_INTEGER_TYPES = ("Integer", "Enumeration", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64")


def _typed(kind: str, text: Any) -> Any:
    """A model description's attribute as its variable type's JSON value: numbers as numbers, Booleans as
    true/false, an FMI 3 array's space-separated start as a list; strings (and anything unreadable) as given.

    Examples
    --------
    >>> _typed("Real", "0.5"), _typed("Int32", "-3"), _typed("Boolean", "true"), _typed("Float64", "1 2")
    (0.5, -3, True, [1.0, 2.0])
    """
    if text is None or not isinstance(text, str) or kind in ("String", "Binary", "Clock"):
        return text
    parts = text.split()
    try:
        if kind == "Boolean":
            values = [{"true": True, "false": False, "1": True, "0": False}[p.lower()] for p in parts]
        elif kind in _INTEGER_TYPES:
            values = [int(p) for p in parts]
        else:
            values = [float(p) for p in parts]
    except (KeyError, ValueError):
        return text
    return values[0] if len(values) == 1 else values
