"""``cosim export``: an identified model written as MATLAB state space, an FMU or JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ..errors import InvalidSettingError
from ..numbers import parse_number
from ._command import _emit, _friendly, _pairs, _split
from ._outputs import check_outputs, staged_outputs

__all__ = ["export_command"]

_SUFFIXES = (".mat", ".fmu", ".json")


def _name_values(text: str | None, option: str) -> dict[str, float] | None:
    """``"theta_m=0,omega_m=0.1"`` -> {"theta_m": 0.0, "omega_m": 0.1}."""
    if not text:
        return None
    return {k: parse_number(v, what=f"{option} {k}") for k, v in _pairs(tuple(_split(text)), option).items()}


@click.command("export")
@click.argument("model_path", metavar="MODEL.json")
@click.option("-o", "--output", "--to", "targets", multiple=True, required=True, metavar="FILE",
              help="Output file; the suffix picks the format: .mat (A, B, C, D with names), .fmu (FMI 2.0 "
                   "co-simulation), .json (the model). Repeat for several.")
@click.option("--dt", default=None, help="Discretise (zero-order hold) at this step [s]. A .mat file is the "
              "continuous state space without it, linear or linearised model alike; an FMU steps at --dt (default: "
              "the model's sampling step).")
@click.option("--constant", type=click.Choice(["input", "operating_point", "ignore"]), default="input",
              show_default=True, help="How a constant term is exported (.mat): an extra input 'const' held at 1, "
              "the model about its equilibrium, or dropped.")
@click.option("--operating-point", "op", default=None, metavar="NAME=VALUE,...",
              help="Linearise a nonlinear model here (states and inputs by name) for .mat.")
@click.option("--nsub", default=1, show_default=True, type=click.IntRange(1, 10000),
              help="RK4 substeps per step of a nonlinear model's FMU.")
@click.option("--json", "as_json", is_flag=True, help="Print the written paths as JSON.")
@_friendly
def export_command(model_path: str, targets: tuple[str, ...], dt: str | None, constant: str, op: str | None,
                   nsub: int, as_json: bool) -> None:
    """Export an identified model to MATLAB, FMI or JSON; or a controller (`cosim design`'s file) as an FMU.

    \b
    Example:
      cosim export model.json -o statespace.mat -o model.fmu
      cosim export pid.json -o pid.fmu    # the PID as an FMI 2.0 FMU, to place beside the plant in an SSP
      cosim export mpc.json -o mpc.fmu    # the MPC: its step's generated C and its QP solver
    """
    from ..export import export
    from ..identify.model import IdentifiedModel

    check_outputs({"-o/--output": targets}, {"-o/--output": _SUFFIXES})  # all of them, before any is written
    if _is_controller_file(model_path):
        _export_controller(model_path, targets, as_json)
        return
    model = IdentifiedModel.load(model_path)
    step = parse_number(dt, what="--dt") if dt else None
    if step is not None and not step > 0:
        raise InvalidSettingError(f"--dt must be a positive step in seconds, e.g. --dt 1/2257; got {dt}")
    operating = _operating_point(model, _name_values(op, "--operating-point"))
    if operating is None and not model.is_linear and any(Path(t).suffix.lower() == ".mat" for t in targets):
        nonlinear = [t for t in model.terms if not _is_linear_term(t, model)]
        raise InvalidSettingError(f"{model_path} is nonlinear (terms {', '.join(nonlinear)}) and a .mat file holds a "
                                  "linear state space: linearise it with --operating-point "
                                  + ",".join(f"{n}=VALUE" for n in (*model.states, *model.inputs)))
    written, notes = [], []
    with staged_outputs(targets) as staged:  # every file or none: an FMU that does not build leaves no .mat
        for target, place in zip(targets, staged, strict=True):
            suffix = Path(target).suffix.lower()
            options: dict[str, Any] = {}
            if suffix == ".mat":
                options = {"dt": step, "constant": constant, "operating_point": operating}
                notes.append(f"{target}: " + ("continuous, dx/dt = A x + B u (--dt for the zero-order-hold discrete "
                                              "one)" if step is None else f"discrete at dt={step:.9g} s (zero-order "
                                              "hold), x[k+1] = A x[k] + B u[k]")
                             + ("" if operating is None else ", linearised at --operating-point " + op))
            elif suffix == ".fmu":
                options = {"dt": step or model.dt, "nsub": nsub}
            export(model, place, **options)
            written.append(str(Path(target)))
    _emit(as_json, {"model": model_path, "written": written, "notes": notes},
          "\n".join([*(f"wrote {w}" for w in written), *(f"  {n}" for n in notes)]))


def _is_controller_file(path: str) -> bool:
    """Whether `path` is a controller file (``"format": "cosim.controller"``), not a model."""
    import json

    try:
        return json.loads(Path(path).read_text(encoding="utf-8")).get("format") == "cosim.controller"
    except (OSError, ValueError, AttributeError):
        return False  # the model reader says what is wrong with it


def _export_controller(path: str, targets: tuple[str, ...], as_json: bool) -> None:
    """A PID or MPC controller file as an FMU (controllers.pid.fmu, controllers.mpc.fmu); other kinds and other formats
    refused in one line."""
    from controllers.base import load_controller

    bad = [t for t in targets if Path(t).suffix.lower() != ".fmu"]
    if bad:
        raise InvalidSettingError(f"{path} is a controller; a controller exports as an FMU (-o NAME.fmu), not "
                                  f"{bad[0]}")
    controller = load_controller(path)
    if controller.kind == "pid":
        from controllers.pid.fmu import export_fmu
    elif controller.kind == "mpc":
        from controllers.mpc.fmu import export_fmu
    else:
        raise InvalidSettingError(f"{path} is a {controller.kind} controller; cosim exports a PID or an MPC as an FMU")

    written = []
    with staged_outputs(targets) as staged:
        for target, place in zip(targets, staged, strict=True):
            export_fmu(controller, place, name=Path(target).stem)
            written.append(str(Path(target)))
    _emit(as_json, {"controller": path, "written": written, "notes": []},
          "\n".join(f"wrote {w}: the {controller.kind} as an FMI 2.0 co-simulation FMU" for w in written))


def _operating_point(model: Any, point: dict[str, float] | None) -> tuple[dict, dict] | None:
    """--operating-point as (states, inputs) by name; a name that is neither, or a state left out, is refused."""
    if point is None:
        return None
    names = (*model.states, *model.inputs)
    unknown = [k for k in point if k not in names]
    if unknown:
        raise InvalidSettingError(f"--operating-point {unknown[0]}: not a state or input of the model; give "
                                  f"{', '.join(names)}")
    missing = [k for k in names if k not in point]
    if missing:
        raise InvalidSettingError(f"--operating-point has no value for {', '.join(missing)}; add "
                                  + ",".join(f"{k}=VALUE" for k in missing) + " (every state and input)")
    return {k: point[k] for k in model.states}, {k: point[k] for k in model.inputs}


def _is_linear_term(term: str, model: Any) -> bool:
    return term == "1" or term in model.states or term in model.inputs
