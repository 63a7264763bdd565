"""``cosim export``: an identified model written as MATLAB state space, an FMU or JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from ..numbers import parse_number
from ._command import _emit, _friendly, _pairs, _split

__all__ = ["export_command"]


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
@click.option("--dt", default=None, help="Discretise (zero-order hold) at this step [s]; an FMU needs it for a "
              "linear model (default: the model's sampling step).")
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
    """Export an identified model to MATLAB, FMI or JSON.

    \b
    Example:
      cosim export model.json -o statespace.mat -o model.fmu
    """
    from ..export import export
    from ..identify.model import IdentifiedModel

    model = IdentifiedModel.load(model_path)
    step = parse_number(dt, what="--dt") if dt else None
    written = []
    for target in targets:
        suffix = Path(target).suffix.lower()
        if suffix == ".mat":
            point = _name_values(op, "--operating-point")
            operating = None
            if point is not None:
                operating = ({k: v for k, v in point.items() if k in model.states},
                             {k: v for k, v in point.items() if k in model.inputs})
            options: dict[str, Any] = {"dt": step, "constant": constant, "operating_point": operating}
        elif suffix == ".fmu":
            options = {"dt": step or model.dt, "nsub": nsub}
        else:
            options = {}
        written.append(str(export(model, target, **options)))
    _emit(as_json, {"model": model_path, "written": written}, "\n".join(f"wrote {w}" for w in written))
