"""``cosim diagnose``: the physical effect a model lacks, found in measured data and added."""

from __future__ import annotations

import time
from pathlib import Path

import click

from ..errors import DataError, InvalidSettingError
from ..numbers import parse_number
from ._command import _decimate_option, _emit, _friendly, _names, _pairs, _resolve_fmu, _settings, _split
from ._data_options import data_options, derive_option, read_records
from ._outputs import check_outputs

__all__ = ["DIAGNOSE_MIN_SAMPLES", "diagnose_command"]


#: Fewest samples :func:`cosim.diagnose.diagnosis.diagnose` accepts (checked here before a model is identified).
DIAGNOSE_MIN_SAMPLES = 200


@click.command("diagnose")
@click.argument("data_paths", metavar="DATA...", nargs=-1, required=True)
@click.option("--state", "states", required=True, metavar="A,B,...",
              help="State columns, in order (derived velocities by their name, e.g. qm,qm_dot).")
@click.option("--input", "inputs", required=True, metavar="U,...",
              help="Input columns; one may be a scaled expression, e.g. 'force=35.15*vir'.")
@click.option("--model", "model_path", default=None, type=click.Path(dir_okay=False),
              help="The model to diagnose (cosim model JSON); default: identify a linear SINDYc model first.")
@click.option("--effects", default="all", show_default=True, metavar="all|NAME,...",
              help="Which catalogued effects to try.")
@click.option("--candidate", "user_candidates", multiple=True, metavar="'NAME: EXPR'",
              help="An effect of your own, searched beside the catalogue's: an expression of the states and inputs, "
                   "linear in named parameters, e.g. 'orifice: -a*sqrt(abs(h1))' (repeatable).")
@click.option("--kinematics", default="auto", show_default=True, metavar="auto|none|POS=VEL,...",
              help="Rows d(POS)/dt = VEL pinned in the identified model: found from the names and the data "
                   "(auto), none, or given, e.g. theta_m=omega_m,theta_L=omega_L. Effects on velocities need them.")
@data_options
@click.option("--max-effects", default=3, show_default=True, type=click.IntRange(1, 10), help="Most effects added.")
@click.option("--x0", "initial_state", type=click.Choice(["estimate", "measured"]), default="estimate",
              show_default=True,
              help="The free runs' initial state: estimated in every fit, or held at the first sample (for "
                   "precisely measured states on a long record of a drifting plant).")
@click.option("--noise", default=None, metavar="STATE=LEVEL,...",
              help="A state's noise level, e.g. its sensor's resolution 'qm=5e-6', instead of the estimate from "
                   "the data.")
@click.option("--decimate", default="auto", show_default=True, metavar="auto|N",
              help="Identify and search at the record's step times N (measured signals low-pass filtered, inputs "
                   "averaged), then refit at the record's own step; auto: down to ten times the record's band on "
                   "records of more than 4000 samples; 1: never.")
@click.option("--plant", default=None, metavar="FMU|bundled",
              help="An FMU of the plant: where the data leave two readings open (gravity or a spring over small "
                   "swings), run the experiment that separates them on it and diagnose again beside its record.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="A parameter of the --plant FMU (repeat).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="Write an HTML report (PNG plots beside it).")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default=None,
              help="Write the model with the effects as JSON.")
@click.option("--json", "as_json", is_flag=True,
              help='Print {"effects": [{"name", "attached_to", "parameters"}...], "before": {...}, "after": {...}}.')
@_friendly
def diagnose_command(data_paths: tuple[str, ...], states: str, inputs: str, model_path: str | None, effects: str,
                     user_candidates: tuple[str, ...],
                     kinematics: str, derive: str | None, derive_window: int | None, time_column: str | None,
                     resample: bool, max_effects: int, initial_state: str, noise: str | None, decimate: str,
                     plant: str | None, sets: tuple[str, ...], report_path: str | None,
                     out: str | None, as_json: bool) -> None:
    """Find the physical effect a model lacks in measured data, add it, and report the error before and after.

    DATA is a CSV, Parquet or MATLAB .mat file; columns are chosen by name. Several files are separate records
    of one plant (the same signals, the same step), fitted together, each from its own initial state.

    \b
    Example:
      cosim diagnose data.csv --state theta_m,omega_m,theta_L,omega_L --input Tm --report diagnosis.html
      cosim diagnose data.csv --state theta_m,omega_m,theta_L,omega_L --input Tm --kinematics theta_m=omega_m
      cosim diagnose DATA_EMPS.mat --state qm,qm_dot --input "force=35.15*vir" --derive qm --json
      cosim diagnose run1.csv run2.csv --state x,v --input u
      cosim diagnose tanks.csv --state h1,h2 --input q --candidate "orifice: -a*sqrt(abs(h1))"
      cosim diagnose swing.csv --state theta_m,omega_m,theta_L,omega_L --input Tm --plant bundled --set mgl=4440
    """
    from ..diagnose.ambiguity import check_plant
    from ..diagnose.diagnosis import BASE_SETTINGS, diagnose
    from ..diagnose.effects import effect_selection
    from ..diagnose.user_candidates import candidate
    from ..identify.model import IdentifiedModel
    from ..identify.sindyc import SINDYc
    from .identify import format_kinematics

    started = time.perf_counter()
    check_outputs({"--report": [report_path], "-o/--output": [out]},
                  {"--report": (".html", ".htm"), "-o/--output": (".json",)})  # before anything runs
    state_names, input_specs = _names(states, "--state"), _names(inputs, "--input")
    input_names = [spec.partition("=")[0].strip() for spec in input_specs]
    extra = [candidate(text, signals=[*state_names, *input_names]) for text in user_candidates]  # before any run
    derived = derive_option(derive)
    known = _kinematics_option(kinematics, state_names)
    if sets and not plant:
        raise InvalidSettingError("--set sets a parameter of the --plant FMU; give --plant FMU too")
    plant_path = _resolve_fmu(plant) if plant else None
    if plant_path is not None:
        check_plant(plant_path, [*state_names, *input_names])  # before any run
    records = read_records(data_paths, states=state_names, inputs=input_specs, derive=derived, time=time_column,
                           derive_window=derive_window, resample=resample)
    for path, data in zip(data_paths, records, strict=True):
        if len(data) < DIAGNOSE_MIN_SAMPLES:  # before identifying: its own minimum would name a library option
            raise DataError(f"{Path(path).name} has {len(data)} samples; diagnosis needs at least "
                            f"{DIAGNOSE_MIN_SAMPLES}; use a longer record")
    selection = effect_selection(effects)  # names checked now; fixed values against the data in diagnose()
    factor = _decimate_option(decimate)
    found_rows = ""
    if model_path:
        model = IdentifiedModel.load(model_path)
    else:
        if isinstance(known, dict):
            known = {**{p: v for v, p in derived.items() if p in state_names and v in state_names}, **known}
        estimator = SINDYc(**{**BASE_SETTINGS, "kinematics": known, "decimate": factor}).fit(
            records, states=state_names, inputs=input_names)
        model, found_rows = estimator.model_, format_kinematics(estimator.kinematics_)
    levels = {name: parse_number(text, what=f"--noise {name}")
              for name, text in _pairs(tuple(_split(noise)), "--noise").items()} if noise else None
    report = diagnose(model, records if len(records) > 1 else records[0], effects=selection,
                      max_effects=max_effects, x0=initial_state, noise=levels, decimate=factor, candidates=extra,
                      plant=plant_path, plant_parameters=_settings(sets, "--set") if sets else None)
    payload = report.to_dict()
    if report_path:
        payload["report"] = str(report.write_report(
            report_path, seconds=time.perf_counter() - started, records=records,
            model_from=f"from {Path(model_path).name}" if model_path else "linear SINDYc identified from the data"))
    if out:
        payload["model"] = str(report.model_after.save(out))
    lines = [report.message] + ([found_rows] if found_rows else [])
    if found_rows:
        payload["kinematics"] = found_rows.removeprefix("kinematics: ")
    for i, e in enumerate(report.effects, start=1):
        params = ", ".join(f"{k}={v:.5g}" + (f" ± {report.effects[i - 1].uncertainty[k]:.2g}"
                                              if k in report.effects[i - 1].uncertainty else "")
                           for k, v in e.parameters.items())
        lines.append(f"  {i}. {e.name} on {e.attached_to} ({', '.join(e.rows)}): {params}")
    for c in report.rejected:
        lines.append(f"  rejected: {c.name} on {c.attached_to}: held-out NRMSE "
                     f"{c.explained.get('held_out_nrmse_without_pct', float('nan')):.4g} % without, "
                     f"{c.explained.get('held_out_nrmse_with_pct', float('nan')):.4g} % with it")
    for e in report.experiments:
        lines.append(f"  experiment run on the plant ({' or '.join(e['effects'])}): the input x{e['input_scale']:g}, "
                     f"{e['signal']} swinging ±{e['swing']:.3g}")
    if report.dropped_terms:
        lines.append("  terms no longer needed: " + ", ".join(report.dropped_terms))
    rate = report.analysis
    if rate.get("decimation", 1) > 1:
        lines.append(f"  searched at {1.0 / rate['dt']:.4g} Hz (the records decimated by {rate['decimation']}), "
                     f"refitted at their own {1.0 / rate['record_dt']:.4g} Hz")
    lines.append(f"  before: NRMSE {report.before['nrmse_pct']:.4g} %, R2 {report.before['r2']:.6g}; "
                 f"after: NRMSE {report.after['nrmse_pct']:.4g} %, R2 {report.after['r2']:.6g}")
    lines += [f"{k}: {payload[k]}" for k in ("report", "model") if k in payload]
    _emit(as_json, payload, "\n".join(lines))


def _kinematics_option(text: str, states: list[str]) -> str | dict[str, str]:
    """``--kinematics``: "auto", "none" or POS=VEL pairs, each a state (checked here: a one-line error)."""
    from .identify import parse_kinematics_option

    parsed = parse_kinematics_option(text)
    for position, velocity in (parsed.items() if isinstance(parsed, dict) else ()):
        for name in (position, velocity):
            if name not in states:
                raise InvalidSettingError(f"--kinematics {position}={velocity}: {name!r} is not a state; states are "
                                          f"{', '.join(states)}")
    return parsed
