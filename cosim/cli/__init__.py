"""The ``cosim`` command: a thin layer over the library.

Every command takes ``--json`` (one JSON object on stdout, progress and messages on stderr) and exits
non-zero with a one-line ``error: ...`` on bad input, never a traceback (set ``COSIM_DEBUG=1`` to see one).
"""

from __future__ import annotations

import functools
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
import numpy as np

from ..errors import CosimError, DataError, InvalidSettingError
from ..numbers import parse_number

__all__ = ["main"]


def _emit(as_json: bool, payload: dict[str, Any], text: str) -> None:
    if as_json:
        click.echo(json.dumps(payload, default=float))
    else:
        click.echo(text)


def _friendly(func: Callable) -> Callable:
    """Turn library errors into one line on stderr and exit status 1 (2 for internal errors)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except CosimError as exc:
            if os.environ.get("COSIM_DEBUG"):
                raise
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)
        except KeyboardInterrupt:
            click.echo("error: interrupted", err=True)
            sys.exit(130)
        except Exception as exc:  # a bug of ours: still one line, with the way to see more
            if os.environ.get("COSIM_DEBUG"):
                raise
            click.echo(f"error: internal error {type(exc).__name__}: {exc} (set COSIM_DEBUG=1 for the "
                       "traceback and report it)", err=True)
            sys.exit(2)

    return wrapper


def _pairs(items: tuple[str, ...], option: str) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise InvalidSettingError(f"{option} takes NAME=VALUE, got {item!r}")
        out[name.strip()] = value.strip()
    return out


def _resolve_fmu(path: str) -> Path:
    """`bundled` (or `bundled3` for FMI 3.0) names the bundled two-mass servo FMU."""
    if path in ("bundled", "bundled3"):
        from ..plant.build import build_fmu

        return build_fmu(fmi_version="3.0" if path == "bundled3" else "2.0")
    return Path(path)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 110})
@click.version_option(package_name="cosim")
def main() -> None:
    """cosim: identify, diagnose and control machines with FMU plants.

    \b
    Example:
      cosim fmu build
      cosim simulate bundled --input Tm=square:amp=0.1,freq=2 --duration 4 --dt 1/2257 -o data.csv
      cosim demo
    """


@main.group()
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
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
@_friendly
def fmu_info(path: str, as_json: bool) -> None:
    """Describe an FMU: inputs, outputs, states, parameters with units and start values.

    PATH is an .fmu file, or `bundled` for the bundled servo.

    \b
    Example:
      cosim fmu info bundled
    """
    from ..plant.fmu_plant import open_model_description

    fmu_path = _resolve_fmu(path)
    md = open_model_description(fmu_path)

    def describe(v: Any) -> dict[str, Any]:
        d = {"name": v.name, "type": v.type, "unit": v.unit or "", "start": v.start,
             "description": v.description or ""}
        for key in ("min", "max"):
            if getattr(v, key, None) not in (None, ""):
                d[key] = getattr(v, key)
        return d

    groups = {c: [describe(v) for v in md.modelVariables if v.causality == c]
              for c in ("input", "output", "parameter")}
    states = [v.derivative.name for v in md.modelVariables if getattr(v, "derivative", None) is not None]
    info = {
        "path": str(fmu_path), "model": md.modelName, "fmi_version": md.fmiVersion,
        "model_identifier": md.coSimulation.modelIdentifier, "generation_tool": md.generationTool,
        "inputs": groups["input"], "outputs": groups["output"], "parameters": groups["parameter"],
        "states": states,
        "default_step": getattr(md.defaultExperiment, "stepSize", None) if md.defaultExperiment else None,
    }
    lines = [f"{md.modelName} (FMI {md.fmiVersion}, co-simulation, {md.generationTool or 'unknown tool'})",
             f"  file: {fmu_path}"]
    for title, key in (("inputs", "inputs"), ("outputs", "outputs"), ("parameters", "parameters")):
        lines.append(f"  {title}:")
        for d in info[key]:
            rng = f"  [{d.get('min', '')}, {d.get('max', '')}]" if "min" in d or "max" in d else ""
            lines.append(f"    {d['name']:<12} {d['start'] or '':>10} {d['unit']:<12}{rng}  {d['description']}")
    lines.append(f"  states: {', '.join(states) or 'not declared'}")
    _emit(as_json, info, "\n".join(lines))


@main.command()
@click.argument("path")
@click.option("--input", "-i", "inputs", multiple=True, metavar="NAME=SPEC",
              help="Input signal, e.g. Tm=square:amp=0.1,freq=2 (amp: fraction of the input's declared max). "
                   "Kinds: square, sine, prbs, chirp, multisine, step, const, or a number.")
@click.option("--duration", required=True, help="Length of the run [s].")
@click.option("--dt", required=True, help="Communication step [s], e.g. 1/2257.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="Parameter value, e.g. Fc=0.3.")
@click.option("--start", "starts", multiple=True, metavar="NAME=VALUE", help="Start value, e.g. theta_m=-2.")
@click.option("--noise", default="0", show_default=True,
              help="Measurement noise level: std = level x std of the clean signal, per state/output.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the noise.")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Write the trajectory (.csv or "
              ".parquet).")
@click.option("--progress/--no-progress", default=None, help="Progress bar (default: long runs on a terminal).")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary.")
@_friendly
def simulate(path: str, inputs: tuple[str, ...], duration: str, dt: str, sets: tuple[str, ...],
             starts: tuple[str, ...], noise: str, seed: int, out: str | None, progress: bool | None,
             as_json: bool) -> None:
    """Simulate an FMU at a fixed step with zero-order-hold inputs and write the trajectory.

    PATH is an .fmu file, or `bundled` for the bundled servo.

    \b
    Example:
      cosim simulate bundled --input Tm=square:amp=0.1,freq=2 --duration 4 --dt 1/2257 \\
          --set Fc=0.3 --noise 0.1 --seed 0 -o data.csv
    """
    from ..data.simulation import simulate as run

    fmu_path = _resolve_fmu(path)
    parameters = {k: parse_number(v, what=f"--set {k}") for k, v in _pairs(sets, "--set").items()}
    start = {k: parse_number(v, what=f"--start {k}") for k, v in _pairs(starts, "--start").items()}
    level = parse_number(noise, what="--noise")
    traj = run(fmu_path, _pairs(inputs, "--input"), duration=parse_number(duration, what="--duration"),
               dt=parse_number(dt, what="--dt"), parameters=parameters, start=start, progress=progress)
    if level:
        traj = traj.with_noise(level, seed=seed)
    if out:
        traj.write(out)
    final = {name: float(traj[name][-1]) for name in traj.names}
    summary = {"path": str(Path(out).resolve()) if out else None, "fmu": str(fmu_path), "samples": len(traj),
               "dt": traj.meta["dt"], "duration": float(traj.time[-1] - traj.time[0]), "signals": list(traj.names),
               "noise": level, "seed": seed, "final": final}
    text = (f"simulated {len(traj)} samples of {', '.join(traj.names)}"
            + (f" with {level:g} noise" if level else "") + (f"; wrote {out}" if out else ""))
    _emit(as_json, summary, text)


@main.group()
def data() -> None:
    """Inspect data files (trajectories as CSV or Parquet)."""


@data.command("info")
@click.argument("path")
@click.option("--time", "time_column", default="time", show_default=True, help="Name of the time column [s].")
@click.option("--columns", default=None, help="Comma-separated columns to read (default: all).")
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
@_friendly
def data_info(path: str, time_column: str, columns: str | None, as_json: bool) -> None:
    """Check a data file (NaN, time order, columns) and describe it: signals, units, roles, sampling.

    \b
    Example:
      cosim data info data.csv --columns Tm,theta_L
    """
    from ..data.trajectory import Trajectory

    chosen = [c.strip() for c in columns.split(",")] if columns else None
    traj = Trajectory.read(path, columns=chosen, time=time_column)
    info = {
        "path": str(Path(path).resolve()), "samples": len(traj), "t_start": float(traj.time[0]),
        "t_end": float(traj.time[-1]), "dt": traj.dt, "uniform": traj.is_uniform(),
        "signals": [{"name": n, "unit": u, "role": r, "min": float(traj[n].min()), "max": float(traj[n].max())}
                    for n, u, r in zip(traj.names, traj.units, traj.roles, strict=True)],
        "meta": traj.meta,
    }
    lines = [f"{path}: {len(traj)} samples, t = {info['t_start']:g} .. {info['t_end']:g} s, "
             f"dt = {traj.dt:.6g} s ({'uniform' if info['uniform'] else 'NOT uniform'})"]
    lines += [f"  {s['name']:<12} {s['role']:<7} [{s['unit']}]  {s['min']:.6g} .. {s['max']:.6g}"
              for s in info["signals"]]
    _emit(as_json, info, "\n".join(lines))


def _name_values(text: str | None, option: str) -> dict[str, float] | None:
    """``"theta_m=0,omega_m=0.1"`` -> {"theta_m": 0.0, "omega_m": 0.1}."""
    if not text:
        return None
    return {k: parse_number(v, what=f"{option} {k}") for k, v in _pairs(tuple(text.split(",")), option).items()}


def _names(text: str, option: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InvalidSettingError(f"{option} takes comma-separated column names, got {text!r}")
    return names


@main.command("identify")
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


@main.command("export")
@click.argument("model_path", metavar="MODEL.json")
@click.option("--to", "targets", multiple=True, required=True, metavar="FILE",
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
      cosim export model.json --to statespace.mat --to model.fmu
    """
    from ..export.core import export
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


@main.group()
def reproduce() -> None:
    """Reproduce published results."""


@reproduce.command("paper")
@click.option("--seeds", default=3, show_default=True, type=click.IntRange(1, 1000),
              help="Noise realisations per excitation and noise level.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786); default: local processes.")
@click.option("--workers", default=None, type=click.IntRange(1, 512), help="Local processes (default: all cores).")
@click.option("--out", "out_dir", default="paper-repro", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the tables, plots and report.html.")
@click.option("--noise", "noise_levels", default=None, metavar="LEVELS",
              help="Comma-separated subset of the study's noise levels, e.g. 0,0.1,0.5.")
@click.option("--excitation", "excitations", type=click.Choice(["square", "sine"]), multiple=True,
              help="Restrict to one excitation (default: both).")
@click.option("--progress/--no-progress", default=True, help="Progress bar on stderr.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@_friendly
def reproduce_paper_command(seeds: int, scheduler: str | None, workers: int | None, out_dir: str,
                            noise_levels: str | None, excitations: tuple[str, ...], progress: bool,
                            as_json: bool) -> None:
    """The reference study's simulation results on the bundled FMU, beside its published numbers.

    Both excitations (square wave at 10 % of the max torque, 5 Hz sine), noise 0-50 %, several seeds; writes
    Table 1 (maximum deviation), R² against noise (PNG, CSV), square versus sine, the coefficients beside
    the FMU's true ones and one HTML report.

    \b
    Example:
      cosim reproduce paper --seeds 3 --out paper-repro --json
    """
    from ..study.paper import STUDY_NOISE_LEVELS
    from ..study.reproduce import reproduce_paper

    levels = STUDY_NOISE_LEVELS
    if noise_levels:
        levels = tuple(parse_number(v, what="--noise") for v in noise_levels.split(","))
    result = reproduce_paper(seeds=seeds, scheduler=scheduler, workers=workers, out_dir=out_dir,
                             noise_levels=levels, excitations=excitations or ("square", "sine"), progress=progress)
    summary = result.summary
    lines = ["max deviation, % of amplitude (cosim | study):"]
    for i, level in enumerate(summary.get("noise_levels", [])):
        cells = [f"{s} {summary['max_dev_pct'][s][i]:.3g} | {summary['study_max_dev_pct'][s][i]}"
                 for s in summary.get("max_dev_pct", {})]
        lines.append(f"  {level:>4.0%}: " + ";  ".join(cells))
    lines.append(f"report: {result.files.get('report.html')}")
    if summary.get("failed_cases"):
        lines.append(f"{summary['failed_cases']} case(s) failed: see {result.files.get('cases.json')}")
    _emit(as_json, summary, "\n".join(lines))
    if summary.get("failed_cases"):
        sys.exit(1)


@main.group()
def design() -> None:
    """Design a controller on an identified model (cosim model JSON) and save it as JSON.

    \b
    Example:
      cosim design pid model.json --output theta_L --velocity omega_m --u-max 5000 -o pid.json
      cosim design mpc model.json --measured theta_m,theta_L --tracked theta_L --u-max 5000 -o mpc.json
    """


def _design_model(model_path: str, dt_text: str | None):
    """The identified model as a continuous named StateSpace, and the controller's sample time."""
    from ..export.core import to_statespace
    from ..identify.model import IdentifiedModel

    model = IdentifiedModel.load(model_path)
    if not model.is_linear:
        raise InvalidSettingError(f"{model_path} is nonlinear, and controllers are designed on a linear model; "
                                  "identify one with `cosim identify ... --library linear`")
    dt = parse_number(dt_text, what="--dt") if dt_text else model.dt
    if dt is None or not dt > 0:
        raise InvalidSettingError("the model has no sample time; pass the controller's --dt (e.g. --dt 1/2257)")
    return to_statespace(model), float(dt), model


def _limit(text: str | None, option: str) -> float | None:
    return None if text is None else parse_number(text, what=option)


def _bounds(u_min: str | None, u_max: str | None) -> tuple[float | None, float | None]:
    """--u-min and --u-max; a missing --u-min mirrors --u-max."""
    hi = _limit(u_max, "--u-max")
    lo = _limit(u_min, "--u-min") if u_min is not None else (-hi if hi is not None else None)
    return lo, hi


def _design_summary(controller: Any, out: str | None) -> tuple[dict[str, Any], list[str]]:
    info = {k: v for k, v in controller.info.items()}
    payload = {"kind": controller.kind, "dt": controller.dt, "inputs": list(controller.inputs),
               "outputs": list(controller.outputs), "tracked": list(controller.tracked), "info": info}
    if out:
        payload["file"] = str(controller.save(out))
    lines = [f"{controller!r}"] + [f"  {k}: {v}" for k, v in info.items() if not isinstance(v, (dict, list))]
    if out:
        lines.append(f"written: {out}")
    return payload, lines


@design.command("pid")
@click.argument("model_path", metavar="MODEL.json")
@click.option("--input", "input_name", default=None, help="Manipulated input (default: the model's first).")
@click.option("--output", "output_name", default=None, help="Controlled output (default: the model's first).")
@click.option("--velocity", default=None, metavar="Y",
              help="Take the derivative action from this measured velocity (e.g. omega_m, the motor's) instead of "
                   "differentiating the output: damps a two-mass resonance.")
@click.option("--dt", "dt_text", default=None, help="Sample time [s] (default: the model's, e.g. 1/2257).")
@click.option("--phase-margin", type=float, default=None, help="Target phase margin [deg] (default 60).")
@click.option("--bandwidth-hz", type=float, default=None, help="Target crossover frequency [Hz] instead.")
@click.option("--gain-margin-db", type=float, default=6.0, show_default=True, help="Least gain margin [dB].")
@click.option("--no-derivative", is_flag=True, help="Design a PI (no derivative action).")
@click.option("--u-min", default=None, help="Lower input limit (default: -u-max).")
@click.option("--u-max", default=None, help="Upper input limit, e.g. 5000.")
@click.option("--du-max", default=None, help="Largest input change per sample.")
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False), default=None, help="Write the controller JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print the gains and margins as JSON.")
@_friendly
def design_pid(model_path: str, input_name: str | None, output_name: str | None, velocity: str | None,
               dt_text: str | None,
               phase_margin: float | None, bandwidth_hz: float | None, gain_margin_db: float, no_derivative: bool,
               u_min: str | None, u_max: str | None, du_max: str | None, out: str | None, as_json: bool) -> None:
    """Tune a discrete PID on the model for a phase margin or a bandwidth; report the margins achieved.

    \b
    Example:
      cosim design pid model.json --input Tm --output theta_L --velocity omega_m --u-max 5000 -o pid.json
    """
    from controllers.base import DesignModel
    from controllers.pid import tune_pid

    sys_c, dt, _ = _design_model(model_path, dt_text)
    lo, hi = _bounds(u_min, u_max)
    pid = tune_pid(sys_c, dt=dt, input=input_name, output=output_name, velocity=velocity, phase_margin=phase_margin,
                   bandwidth_hz=bandwidth_hz, gain_margin_db=gain_margin_db,
                   derivative=False if no_derivative else None, u_min=lo, u_max=hi,
                   du_max=_limit(du_max, "--du-max"))
    pid.design_model = DesignModel.from_statespace(sys_c, dt=dt)
    payload, lines = _design_summary(pid, out)
    _emit(as_json, payload, "\n".join(lines))


@design.command("mpc")
@click.argument("model_path", metavar="MODEL.json")
@click.option("--input", "input_names", default=None, metavar="U,...",
              help="Manipulated inputs (default: the model's first that is not 'const').")
@click.option("--measured", default=None, metavar="Y,...",
              help="Measured outputs, in the plant's order (default: all model outputs); the rest is estimated.")
@click.option("--tracked", default=None, metavar="Y,...", help="Outputs that follow the set-point (default: the "
              "first measured).")
@click.option("--dt", "dt_text", default=None, help="Sample time [s] (default: the model's, e.g. 1/2257).")
@click.option("--horizon", default=20, show_default=True, type=click.IntRange(1, 500), help="Moves N.")
@click.option("--q", "q_text", default=None, help="Tracking-error weight (default: the MPC's).")
@click.option("--q-rate", default=None, help="Weight on the tracked outputs' rate (damping).")
@click.option("--r", "r_text", default=None, help="Input weight.")
@click.option("--r-delta", default=None, help="Input-change weight.")
@click.option("--u-min", default=None, help="Lower input bound (default: -u-max).")
@click.option("--u-max", default=None, help="Upper input bound, e.g. 5000.")
@click.option("--du-max", default=None, help="Largest input change per sample.")
@click.option("--state-bound", "state_bounds", multiple=True, metavar="NAME=LOW:HIGH",
              help="Soft bound on a state or output, e.g. omega_m=-2:2. Repeatable.")
@click.option("--hard-state-bounds", is_flag=True, help="Make the state bounds hard (the QP may become infeasible).")
@click.option("--disturbance", type=click.Choice(["input", "output", "none"]), default="input", show_default=True,
              help="Disturbance model for offset-free tracking.")
@click.option("--no-codegen", is_flag=True, help="Evaluate the QP through casadi's Python API instead of C.")
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False), default=None, help="Write the controller JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print the design figures as JSON.")
@_friendly
def design_mpc(model_path: str, input_names: str | None, measured: str | None, tracked: str | None,
               dt_text: str | None, horizon: int, q_text: str | None, q_rate: str | None, r_text: str | None,
               r_delta: str | None, u_min: str | None, u_max: str | None, du_max: str | None,
               state_bounds: tuple[str, ...], hard_state_bounds: bool, disturbance: str, no_codegen: bool,
               out: str | None, as_json: bool) -> None:
    """Design a linear MPC (casadi, condensed QP, DAQP compiled to C) on the model.

    Terminal cost from the discrete Riccati equation, input and input-rate bounds, soft state bounds,
    offset-free tracking through a disturbance observer (steady-state Kalman filter).

    \b
    Example:
      cosim design mpc model.json --measured theta_m,theta_L --tracked theta_L --u-max 5000 -o mpc.json
    """
    from controllers.mpc import MPC

    sys_c, dt, _ = _design_model(model_path, dt_text)
    lo, hi = _bounds(u_min, u_max)
    weights = {key: parse_number(text, what=f"--{key.replace('_', '-')}")
               for key, text in (("q", q_text), ("q_rate", q_rate), ("r", r_text), ("r_delta", r_delta)) if text}
    mpc = MPC(sys_c, dt=dt, horizon=horizon, inputs=_names(input_names, "--input") if input_names else None,
              outputs=_names(measured, "--measured") if measured else None,
              tracked=_names(tracked, "--tracked") if tracked else None, u_min=lo, u_max=hi,
              du_max=_limit(du_max, "--du-max"), state_bounds=_ranges(state_bounds, "--state-bound") or None,
              hard_state_bounds=hard_state_bounds, disturbance=None if disturbance == "none" else disturbance,
              codegen=not no_codegen, **weights)
    payload, lines = _design_summary(mpc, out)
    _emit(as_json, payload, "\n".join(lines))


#: Fewest samples :func:`cosim.diagnose.diagnosis.diagnose` accepts (checked here before a model is identified).
DIAGNOSE_MIN_SAMPLES = 200


@main.command("diagnose")
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


def _ranges(items: tuple[str, ...], option: str) -> dict[str, tuple[float, float]]:
    """``("Fc=0:200",)`` -> {"Fc": (0.0, 200.0)}."""
    out = {}
    for name, text in _pairs(items, option).items():
        low, sep, high = text.partition(":")
        if not sep:
            raise InvalidSettingError(f"{option} takes NAME=LOW:HIGH, got {name}={text}")
        out[name] = (parse_number(low, what=f"{option} {name} low"), parse_number(high, what=f"{option} {name} high"))
    return out


@main.command("validate")
@click.argument("fmu_path", metavar="FMU")
@click.argument("controller_path", metavar="CTRL.json")
@click.option("--scenario", "scenarios", multiple=True, metavar="KIND:amp=..,at=..",
              help="step:amp=0.01 | ramp:amp=0.01,rate=0.02 | disturbance:amp=500,at=0.5[,input=TL]; extra "
                   "NAME=VALUE items set FMU parameters for that scenario. Repeatable. Default: "
                   "step:amp=0.01,at=0.05,duration=2.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help="FMU parameter for every scenario, e.g. --set Fc=100 (Coulomb friction on). Repeatable.")
@click.option("--spec", "specs", multiple=True, metavar="METRIC<=LIMIT",
              help="settling_time<=1, overshoot<=10%, steady_state_error<=2e-5, input_limit<=5000, "
                   "deadline_miss_rate<=0.001, solve_time_p99<=50us, ... Repeatable. Default: the telescope specs.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="Write an HTML report (PNG plots beside it).")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for the PNG plots (default: beside --report).")
@click.option("--no-model", is_flag=True, help="Do not also run the controller against its design model.")
@click.option("--robustness", "samples", type=click.IntRange(0, None), default=0, show_default=True,
              help="Also validate on N plants drawn around the nominal one (Monte Carlo).")
@click.option("--spread", default=0.2, show_default=True, type=float,
              help="Relative spread of Jm, JL, KL, Bm, BL in the Monte Carlo (0.2 = ±20 %).")
@click.option("--effect", "effects", multiple=True, metavar="NAME=LOW:HIGH",
              help="Effect parameter range in the Monte Carlo, e.g. --effect Fc=0:200. Repeatable.")
@click.option("--min-pass-rate", default=1.0, show_default=True, type=click.FloatRange(0.0, 1.0),
              help="Exit 1 when the Monte Carlo pass rate falls below this fraction.")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler for the Monte Carlo.")
@click.option("--workers", type=click.IntRange(1, None), default=None, help="Local worker processes.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the Monte Carlo draws.")
@click.option("--json", "as_json", is_flag=True,
              help='Print {"passed", "metrics", "solve_time_us": {"median", "p99"}, "reasons", ...}.')
@_friendly
def validate_command(fmu_path: str, controller_path: str, scenarios: tuple[str, ...], sets: tuple[str, ...],
                     specs: tuple[str, ...], report_path: str | None, plots_dir: str | None, no_model: bool,
                     samples: int, spread: float, effects: tuple[str, ...], min_pass_rate: float,
                     scheduler: str | None, workers: int | None, seed: int, as_json: bool) -> None:
    """Run a controller against an FMU in closed loop and check specs; exit 1 when one fails.

    With --robustness N it also validates on N plants drawn around the nominal one (inertias, stiffness and
    damping within ±--spread, effects within --effect ranges) through the sweep engine, and exits 1 when the
    pass rate is below --min-pass-rate.

    \b
    Example:
      cosim validate bundled ctrl.json --scenario step:amp=0.01,duration=2 --set Fc=100 --json
      cosim validate bundled ctrl.json --spec settling_time<=1 --spec overshoot<=10% --report v.html
      cosim validate bundled ctrl.json --robustness 50 --spread 0.2 --effect Fc=0:200
    """
    from controllers.base import load_controller

    from ..loop.validation import TELESCOPE_SPECS, parse_scenario, parse_spec, validate
    from ..loop.validation_report import write_validation_report

    fmu = _resolve_fmu(fmu_path)
    if not fmu.is_file():
        from ..errors import FmuNotFoundError

        raise FmuNotFoundError(f"FMU not found: {fmu}; build the bundled one with `cosim fmu build` or pass bundled")
    controller = load_controller(controller_path)
    parameters = {k: parse_number(v, what=f"--set {k}") for k, v in _pairs(sets, "--set").items()}
    scenario_list = [parse_scenario(s) for s in (scenarios or ("step:amp=0.01,at=0.05,duration=2",))]
    spec_list = [parse_spec(s) for s in (specs or TELESCOPE_SPECS)]
    verdict = validate(fmu, controller, scenario_list, spec_list, parameters=parameters or None,
                       model=None if no_model else "design")
    rob = None
    if samples:
        from ..study.robustness import robustness

        rob = robustness(fmu, controller, [s.with_effects(**parameters) for s in scenario_list], spec_list,
                         samples=samples, spread=spread, effects=_ranges(effects, "--effect"), seed=seed,
                         scheduler=scheduler, workers=workers)
    payload = verdict.to_dict()
    files: dict[str, str] = {}
    if report_path or plots_dir:
        target = Path(report_path) if report_path else Path(plots_dir) / "validation.html"
        html, pngs = write_validation_report(verdict, target, controller=controller, robustness=rob,
                                             plots_dir=plots_dir)
        files = {"plots": [str(p) for p in pngs]}
        if report_path:
            files["report"] = str(html)
        else:
            html.unlink()
    payload["files"] = files
    if rob is not None:
        payload["robustness"] = rob.to_dict()
    solve = verdict.solve_time_us()
    lines = [f"{'PASSED' if verdict.passed else 'FAILED'}: {controller.kind} on {fmu.name}, "
             f"{len(scenario_list)} scenario(s), {len(spec_list)} spec(s); controller compute median "
             f"{solve['median']:.1f} µs, p99 {solve['p99']:.1f} µs"]
    lines += [f"  {c['scenario']}: {c['spec']} -> "
              + ("n/a" if c["passed"] is None else f"{c['value']:.6g} {'ok' if c['passed'] else 'NOT MET'}"
                 if c["value"] is not None else "undefined, NOT MET") for c in verdict.checks]
    lines += [f"  reason: {r}" for r in verdict.reasons]
    if rob is not None:
        lines.append(f"robustness: {rob.samples} samples, pass rate {rob.pass_rate:.1%}, worst case "
                     + ", ".join(f"{k}={v:.4g}" for k, v in rob.worst["parameters"].items()))
    lines += [f"{k}: {v}" for k, v in files.items()]
    _emit(as_json, payload, "\n".join(lines))
    if not verdict.passed or (rob is not None and rob.pass_rate < min_pass_rate):
        sys.exit(1)


@main.command()
@click.option("--out", "out_dir", default="cosim-demo", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the results.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary.")
@_friendly
def demo(out_dir: str, as_json: bool) -> None:
    """Run the main job on the bundled servo FMU and write its results (data, models, controllers, plots, one
    HTML report) to --out: a linear model of friction-laden noisy data, the diagnosis of the friction it lacks,
    PID and MPC designed on each model and validated on the FMU.

    \b
    Example:
      cosim demo --out cosim-demo
    """
    from ..demo import run_demo, summary_lines

    result = run_demo(out_dir)
    _emit(as_json, result, "\n".join(summary_lines(result)))


if __name__ == "__main__":  # pragma: no cover
    main()
