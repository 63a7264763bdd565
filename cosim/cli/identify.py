"""``cosim identify``: a SINDYc model from a data file, its equations and its free-run fit."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ..numbers import parse_number
from ._command import _emit, _friendly, _names, _pairs

__all__ = ["identify_command"]


@click.command("identify")
@click.argument("data", metavar="DATA")
@click.option("--state", "states", required=True, metavar="A,B,...", help="State columns, in order.")
@click.option("--input", "inputs", default="", metavar="U,...", help="Input columns (none for an autonomous model).")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Write the model as JSON.")
@click.option("--library", type=click.Choice(["linear", "polynomial"]), default="linear", show_default=True,
              help="Candidate terms: constant, states and inputs (the study's), or polynomials up to --degree.")
@click.option("--degree", default=2, show_default=True, type=click.IntRange(1, 5), help="Polynomial degree.")
@click.option("--terms", default="", metavar="EXPR;EXPR",
              help="Extra library terms, e.g. 'tanh(omega_m/0.01);sin(theta_L)'.")
@click.option("--threshold", default="auto", show_default=True,
              help="STLSQ threshold on scaled coefficients, or 'auto' (chosen by BIC along the path).")
@click.option("--differentiation", default="integral", show_default=True,
              help="integral, zoh, finite_difference, smoothed_finite_difference, savitzky_golay, spline, ...")
@click.option("--refine/--no-refine", default=True, show_default=True,
              help="Output-error refinement (minimise the free-run simulation error).")
@click.option("--kinematics", default=None, metavar="POS=VEL,...",
              help="Known rows d(POS)/dt = VEL, e.g. theta_m=omega_m,theta_L=omega_L.")
@click.option("--derive", default=None, metavar="VEL=POS,...",
              help="Derive velocity states from measured positions, e.g. omega_m=theta_m.")
@click.option("--time", "time_column", default="time", show_default=True, help="Name of the time column [s].")
@click.option("--json", "as_json", is_flag=True, help="Print the model, equations and fit as JSON.")
@_friendly
def identify_command(data: str, states: str, inputs: str, out: str | None, library: str, degree: int, terms: str,
                     threshold: str, differentiation: str, refine: bool, kinematics: str | None,
                     derive: str | None, time_column: str, as_json: bool) -> None:
    """Identify a SINDYc model from a data file (CSV or Parquet) and print its equations and fit.

    The fit is the free-run simulation of the model from the first sample, with the measured inputs held
    between samples, against the measured states: R² and NRMSE fit % per state.

    \b
    Example:
      cosim identify data.csv --state theta_m,omega_m,theta_L,omega_L --input Tm -o model.json
    """
    from ..data.trajectory import Trajectory
    from ..identify.metrics import nrmse_fit_pct, r2
    from ..identify.sindyc import SINDYc

    state_names, input_names = _names(states, "--state"), _names(inputs, "--input") if inputs else []
    derived = {k: str(v) for k, v in _pairs(tuple(derive.split(",")), "--derive").items()} if derive else {}
    columns = list(dict.fromkeys([n for n in state_names if n not in derived] + list(derived.values())
                                 + input_names))
    traj = Trajectory.read(data, columns=columns, time=time_column)
    kin = {k: str(v) for k, v in _pairs(tuple(kinematics.split(",")), "--kinematics").items()} if kinematics else None
    estimator = SINDYc(library=library, degree=degree, terms=[t for t in terms.split(";") if t.strip()],
                       threshold=threshold if threshold == "auto" else parse_number(threshold, what="--threshold"),
                       differentiation=differentiation, kinematics=kin, velocities=derived or None,
                       refine="output_error" if refine else None)
    estimator.fit(traj, states=state_names, inputs=input_names)
    model = estimator.model_
    x0 = model.meta.get("x0")
    start = np.asarray(x0[0] if x0 and isinstance(x0[0], list) else x0) if x0 else None
    sim = estimator.simulate(start if start is not None else [traj[s][0] for s in model.states],
                             traj[list(model.inputs)][:-1] if model.inputs else None, dt=traj.dt)
    fit = {}
    if all(s in traj.names for s in model.states) and sim.ok:
        measured = traj[list(model.states)]
        fit = {"r2": dict(zip(model.states, np.atleast_1d(r2(measured, sim.states)).tolist(), strict=True)),
               "nrmse_pct": dict(zip(model.states, np.atleast_1d(nrmse_fit_pct(measured, sim.states)).tolist(),
                                     strict=True))}
    if out:
        model.save(out)
    payload = {"model": str(Path(out).resolve()) if out else None, "equations": model.equations(),
               "states": list(model.states), "inputs": list(model.inputs), "threshold": estimator.threshold_,
               "stable": model.meta.get("stable"), "simulation": sim.status, "fit": fit}
    lines = model.equations()
    if fit:
        lines.append("free-run fit: " + ", ".join(f"{s} R2={fit['r2'][s]:.5f} NRMSE={fit['nrmse_pct'][s]:.2f} %"
                                                  for s in model.states))
    if not sim.ok:
        lines.append(f"warning: {sim.message}")
    if out:
        lines.append(f"wrote {out}")
    _emit(as_json, payload, "\n".join(lines))
