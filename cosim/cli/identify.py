"""``cosim identify``: a SINDYc model from a data file, its equations and its free-run fit."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import click

from ..numbers import parse_number
from ._command import _decimate_option, _emit, _friendly, _names, _pairs, _split
from ._data_options import data_options, derive_option, read_records
from ._outputs import check_outputs

__all__ = ["identify_command", "parse_kinematics_option", "format_kinematics"]


def parse_kinematics_option(text: str | None) -> str | dict[str, str]:
    """The value of a ``--kinematics`` option for :class:`~cosim.identify.sindyc.SINDYc`: ``"auto"`` (also for
    no value), ``"none"``, or a mapping from ``POS=VEL,...``.

    Examples
    --------
    >>> parse_kinematics_option("theta_m=omega_m, theta_L=omega_L")
    {'theta_m': 'omega_m', 'theta_L': 'omega_L'}
    >>> parse_kinematics_option(None), parse_kinematics_option("None")
    ('auto', 'none')
    """
    if text is None or text.strip().lower() in ("", "auto"):
        return "auto"
    if text.strip().lower() == "none":
        return "none"
    return {k: str(v) for k, v in _pairs(tuple(_split(text)), "--kinematics").items()}


def format_kinematics(pairs: tuple) -> str:
    """One line naming the fixed kinematic rows and how each was found (``kinematics: none`` without any).

    Examples
    --------
    >>> from cosim.identify.kinematics import KinematicPair
    >>> format_kinematics((KinematicPair("theta_m", "omega_m", "name"), KinematicPair("x", "v", "data")))
    "kinematics: theta_m' = omega_m (names), x' = v (data)"
    """
    return "kinematics: " + (", ".join(str(p) for p in pairs) if pairs else "none")


@click.command("identify")
@click.argument("data", metavar="DATA")
@click.option("--state", "states", required=True, metavar="A,B,...",
              help="State columns, in order (NAME=EXPR for an expression of the file's variables).")
@click.option("--input", "inputs", default="", metavar="U,...",
              help="Input columns (none for an autonomous model; NAME=EXPR, e.g. force=35.15*vir).")
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
@click.option("--kinematics", default="auto", show_default=True, metavar="auto|none|POS=VEL,...",
              help="Rows d(POS)/dt = VEL fixed exactly: detected from names and data (auto), none, or given, "
                   "e.g. theta_m=omega_m,theta_L=omega_L.")
@data_options
@click.option("--allow-unstable", is_flag=True,
              help="Keep an unstable identified model (with a warning) instead of failing with exit status 1.")
@click.option("--decimate", default="auto", show_default=True, metavar="auto|N",
              help="Refine on the record's step times N (states low-pass filtered, inputs averaged), then once more "
                   "at its own step; auto: down to ten times the record's band on records of more than 4000 "
                   "samples; 1: never.")
@click.option("--json", "as_json", is_flag=True, help="Print the model, equations and fit as JSON.")
@_friendly
def identify_command(data: str, states: str, inputs: str, out: str | None, library: str, degree: int, terms: str,
                     threshold: str, differentiation: str, refine: bool, kinematics: str, derive: str | None,
                     derive_window: int | None, time_column: str | None, resample: bool, allow_unstable: bool,
                     decimate: str, as_json: bool) -> None:
    """Identify a SINDYc model from a data file (CSV or Parquet) and print its equations and fit.

    The fit is `cosim compare`'s on the same data: the model's free run with the measured inputs held between
    samples, from an initial state estimated from the data, against the measured states: fit_pct (MATLAB's
    NRMSE fit, 100 is perfect), nrmse_pct (the error, 0 is perfect) and R² per state. Kinematic rows
    (position' = velocity) are found from the state names and the data unless --kinematics says otherwise,
    and printed. An unstable model is an error (exit status 1, nothing written) unless --allow-unstable.

    \b
    Example:
      cosim identify data.csv --state theta_m,omega_m,theta_L,omega_L --input Tm -o model.json
    """
    from ..identify.compare import compare
    from ..identify.sindyc import IdentificationWarning, SINDYc

    check_outputs({"-o/--output": [out]}, {"-o/--output": (".json",)})
    state_specs, input_specs = _names(states, "--state"), _names(inputs, "--input") if inputs else []
    state_names = [s.partition("=")[0].strip() for s in state_specs]
    input_names = [s.partition("=")[0].strip() for s in input_specs]
    derived = derive_option(derive)
    [traj] = read_records([data], states=state_specs, inputs=input_specs, derive=derived, time=time_column,
                          resample=resample, differentiate=False)
    estimator = SINDYc(library=library, degree=degree, terms=[t for t in terms.split(";") if t.strip()],
                       threshold=threshold if threshold == "auto" else parse_number(threshold, what="--threshold"),
                       differentiation=differentiation, kinematics=parse_kinematics_option(kinematics),
                       velocities=derived or None, derive_window=derive_window,
                       refine="output_error" if refine else None, allow_unstable=allow_unstable,
                       decimate=_decimate_option(decimate))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", IdentificationWarning)
        estimator.fit(traj, states=state_names, inputs=input_names)
    notes = [f"warning: {w.message}" for w in caught if issubclass(w.category, IdentificationWarning)]
    model = estimator.model_
    fit: dict[str, Any] = {}
    status = "ok"
    scored = traj
    if derived:  # the fit is compare's on the same file with the same --derive: the velocities differentiated here
        [scored] = read_records([data], states=state_specs, inputs=input_specs, derive=derived, time=time_column,
                                resample=resample, derive_window=derive_window)
    if all(s in scored.names for s in model.states):
        scores = compare(model, scored)
        status = "ok" if all(math.isfinite(v) for v in scores.fit_pct.values()) else "diverged"
        fit = {key: getattr(scores, key) for key in ("fit_pct", "nrmse_pct", "r2")} if status == "ok" else {}
    if out:
        model.save(out)
    windows = model.meta["data"].get("derive_window") or {}
    payload = {"model": str(Path(out).resolve()) if out else None, "equations": model.equations(),
               "states": list(model.states), "inputs": list(model.inputs), "threshold": estimator.threshold_,
               "stable": model.meta.get("stable"), "simulation": status, "fit": fit,
               "kinematics": [p.to_dict() for p in estimator.kinematics_], "derive_window": windows,
               "warnings": [n.removeprefix("warning: ") for n in notes]}
    lines = model.equations() + [format_kinematics(estimator.kinematics_)]
    if windows:
        how = "given" if derive_window else "chosen from the data"
        lines.append("derived: " + ", ".join(f"{v} from {derived[v]} (Savitzky-Golay window {w} samples, {how})"
                                             for v, w in windows.items()))
    if fit:
        lines.append("free-run fit: " + ", ".join(f"{s} {fit['fit_pct'][s]:.2f} % (R2 {fit['r2'][s]:.5f})"
                                                  for s in model.states))
    lines += notes
    if status != "ok":
        lines.append("warning: the model's free run leaves its range on these data (diverged)")
    if out:
        lines.append(f"wrote {out}")
    _emit(as_json, payload, "\n".join(lines))
