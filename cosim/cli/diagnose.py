"""``cosim diagnose``: the physical effect a model lacks, found in measured data and added."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import DataError
from ..numbers import parse_number
from ._command import _emit, _friendly, _names, _pairs

__all__ = ["DIAGNOSE_MIN_SAMPLES", "diagnose_command"]


#: Fewest samples :func:`cosim.diagnose.diagnosis.diagnose` accepts (checked here before a model is identified).
DIAGNOSE_MIN_SAMPLES = 200


@click.command("diagnose")
@click.argument("data_path", metavar="DATA")
@click.option("--state", "states", required=True, metavar="A,B,...",
              help="State columns, in order (derived velocities by their name, e.g. qm,qm_dot).")
@click.option("--input", "inputs", required=True, metavar="U,...",
              help="Input columns; one may be a scaled expression, e.g. 'force=35.15*vir'.")
@click.option("--model", "model_path", default=None, type=click.Path(dir_okay=False),
              help="The model to diagnose (cosim model JSON); default: identify a linear SINDYc model first.")
@click.option("--effects", default="all", show_default=True, metavar="all|NAME,...",
              help="Which catalogued effects to try.")
@click.option("--derive", default=None, metavar="POS,...",
              help="Derive velocities <POS>_dot from measured positions (Savitzky-Golay).")
@click.option("--kinematics", default=None, metavar="POS=VEL,...",
              help="Known rows d(POS)/dt = VEL for the identified model, e.g. theta_m=omega_m,theta_L=omega_L "
                   "(derived velocities are added by themselves). Effects on velocities need them.")
@click.option("--time", "time_column", default=None, help="Name of the time column (default t, else time).")
@click.option("--resample", is_flag=True,
              help="Interpolate a record whose time steps are not uniform onto a uniform grid instead of refusing it.")
@click.option("--max-effects", default=3, show_default=True, type=click.IntRange(1, 10), help="Most effects added.")
@click.option("--x0", "initial_state", type=click.Choice(["estimate", "measured"]), default="estimate",
              show_default=True,
              help="The free runs' initial state: estimated in every fit, or held at the first sample (for "
                   "precisely measured states on a long record of a drifting plant).")
@click.option("--noise", default=None, metavar="STATE=LEVEL,...",
              help="A state's noise level, e.g. its sensor's resolution 'qm=5e-6', instead of the estimate from "
                   "the data.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="Write an HTML report (PNG plots beside it).")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default=None,
              help="Write the model with the effects as JSON.")
@click.option("--json", "as_json", is_flag=True,
              help='Print {"effects": [{"name", "attached_to", "parameters"}...], "before": {...}, "after": {...}}.')
@_friendly
def diagnose_command(data_path: str, states: str, inputs: str, model_path: str | None, effects: str,
                     derive: str | None, kinematics: str | None, time_column: str | None, resample: bool,
                     max_effects: int, initial_state: str, noise: str | None, report_path: str | None,
                     out: str | None, as_json: bool) -> None:
    """Find the physical effect a model lacks in measured data, add it, and report the error before and after.

    DATA is a CSV, Parquet or MATLAB .mat file; columns are chosen by name.

    \b
    Example:
      cosim diagnose data.csv --state theta_m,omega_m,theta_L,omega_L --input Tm --report diagnosis.html
      cosim diagnose data.csv --state theta_m,omega_m,theta_L,omega_L --input Tm --kinematics theta_m=omega_m
      cosim diagnose DATA_EMPS.mat --state qm,qm_dot --input "force=35.15*vir" --derive qm --json
      cosim diagnose DATA_EMPS.mat --state qm,qm_dot --input "force=35.15*vir" --derive qm --x0 measured \\
          --noise qm=5e-6
    """
    from ..data.datafile import load_data
    from ..diagnose.diagnosis import diagnose
    from ..identify.model import IdentifiedModel
    from ..identify.sindyc import SINDYc

    state_names, input_specs = _names(states, "--state"), _names(inputs, "--input")
    input_names = [spec.partition("=")[0].strip() for spec in input_specs]
    derived = _names(derive, "--derive") if derive else []
    derived_names = {f"{p}_dot" for p in derived}
    columns = [n for n in state_names if n not in derived_names] + input_specs
    roles = {**dict.fromkeys(state_names, "state"), **dict.fromkeys(input_names, "input")}
    data = load_data(data_path, time=time_column, columns=columns, roles=roles, derive=derived, resample=resample)
    data = data.select([*state_names, *input_names])
    if len(data) < DIAGNOSE_MIN_SAMPLES:  # before identifying: its own minimum would name a library option
        raise DataError(f"{Path(data_path).name} has {len(data)} samples; diagnosis needs at least "
                        f"{DIAGNOSE_MIN_SAMPLES}; use a longer record")
    if model_path:
        model = IdentifiedModel.load(model_path)
    else:
        known = {p: f"{p}_dot" for p in derived if p in state_names and f"{p}_dot" in state_names}
        known.update(_pairs(tuple(kinematics.split(",")), "--kinematics") if kinematics else {})
        model = SINDYc(library="linear", include_constant=True, threshold=0.0, kinematics=known or None,
                       refine="output_error").fit(data, states=state_names, inputs=input_names).model_
    levels = {name: parse_number(text, what=f"--noise {name}")
              for name, text in _pairs(tuple(noise.split(",")), "--noise").items()} if noise else None
    report = diagnose(model, data, effects=effects, max_effects=max_effects, x0=initial_state, noise=levels)
    payload = report.to_dict()
    if report_path:
        payload["report"] = str(report.write_report(report_path))
    if out:
        payload["model"] = str(report.model_after.save(out))
    lines = [report.message]
    for i, e in enumerate(report.effects, start=1):
        params = ", ".join(f"{k}={v:.5g}" + (f" ± {report.effects[i - 1].uncertainty[k]:.2g}"
                                              if k in report.effects[i - 1].uncertainty else "")
                           for k, v in e.parameters.items())
        lines.append(f"  {i}. {e.name} on {e.attached_to} ({', '.join(e.rows)}): {params}")
    lines.append(f"  before: NRMSE {report.before['nrmse_pct']:.4g} %, R2 {report.before['r2']:.6g}; "
                 f"after: NRMSE {report.after['nrmse_pct']:.4g} %, R2 {report.after['r2']:.6g}")
    lines += [f"{k}: {payload[k]}" for k in ("report", "model") if k in payload]
    _emit(as_json, payload, "\n".join(lines))
