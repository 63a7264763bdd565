"""``cosim simulate`` and ``cosim data info``: an FMU run into a trajectory file, and a data file described."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ..errors import InvalidSettingError
from ..numbers import parse_number
from ._command import _emit, _friendly, _names, _pairs, _resolve_fmu, _settings
from ._outputs import check_outputs

__all__ = ["data", "simulate"]


@click.command()
@click.argument("path")
@click.option("--input", "-i", "inputs", multiple=True, metavar="NAME=SPEC",
              help="Input signal, e.g. Tm=square:amp=500,freq=2 (amp in the input's unit; frac=0.1: a fraction of its "
                   "declared max). "
                   "Kinds: square, sine, prbs, chirp, multisine, step, const, or a number. With --input-file, "
                   "NAME=EXPR is also an expression of the file's variables: Tm=data[:,1] (a .mat matrix's column, "
                   "0-based), force=35.15*vir. Only the inputs given are driven; the others are left to the FMU.")
@click.option("--input-file", "input_file", type=click.Path(dir_okay=False), default=None, metavar="DATA",
              help="Drive the FMU's inputs from a recorded file (CSV, Parquet, .mat): every column named as an FMU "
                   "input, and each --input NAME=EXPR; --dt and --duration default to the file's.")
@click.option("--hold", type=click.Choice(["zoh", "linear"]), default="zoh", show_default=True,
              help="Recorded inputs between their samples: held (zero-order hold, cosim's convention) or "
                   "interpolated linearly.")
@click.option("--time", "time_column", default=None, metavar="COLUMN",
              help="Time column of --input-file (default t, else time; data[:,0] for a .mat matrix's column).")
@click.option("--duration", default=None, help="Length of the run [s] (required without --input-file).")
@click.option("--dt", default=None, help="Communication step [s], e.g. 1/2257 (required without --input-file).")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help="Parameter value, e.g. Fc=0.3; an array element A[1,2]=0.5 or a whole array A=[[0,1],[-2,-3]]; "
                   "true/false; text for a String; hex digits for a Binary (626172: the bytes 62 61 72). A variable "
                   "that is no parameter (an input, a state) takes it as its start value, as with --start.")
@click.option("--start", "starts", multiple=True, metavar="NAME=VALUE",
              help="Start value, e.g. theta_m=-2 (values as for --set).")
@click.option("--noise", default="0", show_default=True,
              help="Measurement noise level: std = level x std of the clean signal, per state/output.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the noise.")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Write the trajectory (.csv, "
              ".parquet, or .mat: time and a MATLAB variable per signal).")
@click.option("--record", default=None, metavar="NAME,...|all",
              help="Variables to record (default: the FMU's outputs): outputs, states and local variables by name "
                   "(e.g. mass.s), or all (every Float variable).")
@click.option("--kind", type=click.Choice(["cs", "me"]), default=None,
              help="The FMU's interface: cs (co-simulation) or me (Model Exchange, integrated by FMPy's solvers). "
                   "Default: cs when the FMU has it, else me.")
@click.option("--solver", type=click.Choice(["cvode", "euler"]), default="cvode", show_default=True,
              help="Solver of a Model Exchange FMU.")
@click.option("--master", type=click.Choice(["gauss-seidel", "jacobi"]), default=None,
              help="A system's co-simulation algorithm (default gauss-seidel; see docs/systems.md).")
@click.option("--extrapolation", type=click.IntRange(0, 2), default=None,
              help="A system's input extrapolation order: 0 (first-order coupling), 1 (default) or 2.")
@click.option("--progress/--no-progress", default=None, help="Progress bar (default: long runs on a terminal).")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary.")
@_friendly
def simulate(path: str, inputs: tuple[str, ...], input_file: str | None, hold: str, time_column: str | None,
             duration: str | None, dt: str | None, sets: tuple[str, ...], starts: tuple[str, ...], noise: str,
             seed: int, out: str | None, record: str | None, kind: str | None, solver: str, master: str | None,
             extrapolation: int | None, progress: bool | None, as_json: bool) -> None:
    """Simulate an FMU at a fixed step with zero-order-hold inputs and write the trajectory.

    PATH is an .fmu file, `bundled` for the bundled servo, or a system of FMUs (an .ssp, a SystemStructure.ssd,
    an OspSystemStructure.xml) whose variables are named component.variable (--set load.JL=500).

    \b
    Example:
      cosim simulate bundled --input Tm=square:amp=500,freq=2 --duration 4 --dt 1/2257 \\
          --set Fc=0.3 --noise 0.1 --seed 0 -o data.csv
      cosim simulate bundled --input-file data.csv --set Fc=0.3 -o again.csv
      cosim simulate bundled --input-file rig.mat --input "Tm=data[:,1]" -o run.mat
      cosim simulate bundled-split --input motor.Tm=step:amp=100 --duration 1 --dt 1/2257 --master jacobi -o s.csv
    """
    from ..data.simulation import simulate as run

    check_outputs({"-o/--output": [out]}, {"-o/--output": (".csv", ".parquet", ".pq", ".mat")})
    fmu_path = _resolve_fmu(path)
    parameters, start = _start_values(fmu_path, _settings(sets, "--set"), _settings(starts, "--start"))
    level = parse_number(noise, what="--noise")
    signals: dict = dict(_pairs(inputs, "--input"))
    t0, note = None, ""
    expression = next((f"{n}={text}" for n, text in signals.items()
                       if not _is_signal_spec(text) and any(c in text for c in "[]*/()")), None)
    if expression and not input_file:
        raise InvalidSettingError(f"--input {expression}: an expression of a file's variables needs --input-file DATA; "
                                  "without one, give a signal spec such as square:amp=500,freq=2 or a number")
    if input_file:
        record_signals, t0, step, span, note = _recorded(fmu_path, input_file, time_column, hold, dt, duration,
                                                         signals)
        signals.update(record_signals)
        dt, duration = dt or repr(step), duration or repr(span)
    if dt is None or duration is None:
        raise InvalidSettingError("give --dt and --duration (or --input-file, whose step and length they take)")
    traj = run(fmu_path, signals, duration=parse_number(duration, what="--duration"),
               dt=parse_number(dt, what="--dt"), parameters=parameters, start=start, progress=progress, t0=t0,
               kind=kind, solver=solver, master={k: v for k, v in (("algorithm", master),
                                                                  ("extrapolation", extrapolation)) if v is not None},
               outputs=None if record is None else "all" if record.strip() == "all" else _names(record, "--record"))
    if level:
        traj = traj.with_noise(level, seed=seed)
    if out:
        traj.write(out)
    final = {name: float(traj[name][-1]) for name in traj.names}
    status = traj.meta.get("status", "completed")
    left = traj.meta.get("left_inputs", {})
    master_used = {"master": traj.meta["master"]} if "master" in traj.meta else {}
    summary = {"status": status, "kind": traj.meta["kind"], **master_used,
               "path": str(Path(out).resolve()) if out else None, "fmu": str(fmu_path),
               "driven": list(traj.inputs), "left": list(left), "samples": len(traj), "dt": traj.meta["dt"],
               "duration": float(traj.time[-1] - traj.time[0]), "signals": list(traj.names),
               "noise": level, "seed": seed, "final": final}
    ended = ""
    if status == "terminated":
        summary["terminated"] = traj.meta["terminated"]
        said = traj.meta["terminated"]["message"]
        ended = (f"; the FMU ended the simulation at t={traj.meta['terminated']['time']:.9g} s"
                 + (f" ({said})" if said else " (it gave no message)") + ", everything until then is kept")
    if input_file:
        summary["input_file"] = {"path": input_file, "hold": hold, "note": note}
    starts = ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in left.values())
    driving = (f"; drove {', '.join(traj.inputs) or 'no input'}"
               + (f"; left {', '.join(left)} to the FMU (start {starts})" if left else ""))
    text = (f"simulated {len(traj)} samples of {', '.join(traj.names)}"
            + (f" with {level:g} noise" if level else "") + ended + (f"; {note}" if note else "") + driving
            + (f"; wrote {out}" if out else ""))
    _emit(as_json, summary, text)


def _start_values(fmu_path: Path, sets: dict, starts: dict) -> tuple[dict, dict]:
    """``--set`` values split into parameters and the start values of variables that are no parameter (an input,
    a state: ``--set Binary_input=626172``), with the ``--start`` values."""
    from ..plant._variables import expand_signals
    from ..plant.model_description import open_model_description
    from ..plant.system_structure import is_system_file

    if not sets or is_system_file(fmu_path):  # a system sorts its components' values itself
        return sets, starts
    signals = expand_signals(open_model_description(fmu_path).modelVariables)
    moved = {name: value for name, value in sets.items()
             if name in signals and signals[name].var.causality != "parameter"}
    twice = sorted(set(moved) & set(starts))
    if twice:
        raise InvalidSettingError(f"{twice[0]} is given by --set and by --start; give it once")
    return {name: value for name, value in sets.items() if name not in moved}, {**starts, **moved}


def _is_signal_spec(text: str) -> bool:
    """`text` is a signal spec (``square:amp=500``, a kind's name, a number), not an expression of a file's
    variables (``data[:,1]``, ``35.15*vir``)."""
    from ..data.signals import SIGNAL_KINDS

    head, colon, _ = text.strip().partition(":")
    if head.strip().lower() in SIGNAL_KINDS and (colon or head.strip() == text.strip()):
        return True
    try:
        parse_number(text)
    except InvalidSettingError:
        return False
    return True


def _recorded(fmu_path: Path, input_file: str, time_column: str | None, hold: str, dt: str | None,
              duration: str | None, given: dict[str, str]) -> tuple[dict, float, float, float, str]:
    """The FMU inputs found in `input_file` and the given inputs whose text is an expression of its variables
    (``Tm=data[:,1]``), sampled on the run's grid: (signals, t0, file step, file span, a note saying what was
    taken and how it is held)."""
    from ..data.datafile import file_variables, load_data
    from ..data.simulation import recorded_inputs, steps_for
    from ..plant._variables import NUMERIC, expand_signals
    from ..plant.model_description import open_model_description
    from ..plant.system_structure import is_system_file, read_system
    from ..plant.system_wiring import wire

    if is_system_file(fmu_path):
        names = list(wire(read_system(fmu_path)).inputs)
    else:
        names = [s.name for s in expand_signals(open_model_description(fmu_path).modelVariables).values()
                 if s.var.causality == "input" and s.kind in NUMERIC and not (s.shape and s.offset is None)]
    expressions = {name: text for name, text in given.items() if not _is_signal_spec(text)}
    variables = file_variables(input_file)
    found = [n for n in names if n in variables and n not in expressions]
    if not found and not expressions:
        raise InvalidSettingError(f"{Path(input_file).name} has no column named as an input of {fmu_path.name} "
                                  f"({', '.join(names) or 'none'}); its columns: {', '.join(variables)}; or name "
                                  f"one: --input NAME=EXPR (e.g. {names[0] if names else 'u'}=data[:,1])")
    twice = sorted(set(given) & set(found))
    if twice:
        raise InvalidSettingError(f"input {twice[0]} is given by --input and by --input-file; give it once")
    record = load_data(input_file, time=time_column, columns={**{n: n for n in found}, **expressions},
                       excitation=False)
    step = float(record.dt)
    stated = record.meta.get("dt")  # a cosim file's own step, exact (the one from its time column is rounded)
    if isinstance(stated, (int, float)) and abs(stated - step) <= 1e-9 * step:
        step = float(stated)
    span = float(record.time[-1] - record.time[0])
    run_dt = parse_number(dt, what="--dt") if dt else step
    run_duration = parse_number(duration, what="--duration") if duration else span
    n = steps_for(run_duration, run_dt)
    t0 = float(record.time[0])
    grid = t0 + run_dt * np.arange(n + 1)
    values = recorded_inputs(record, list(record.names), grid, hold=hold)
    how = "held between samples (zero-order hold)" if hold == "zoh" else "interpolated linearly"
    taken = [*found, *(f"{n}={text}" for n, text in expressions.items())]
    note = f"inputs {', '.join(taken)} from {Path(input_file).name}, {how}"
    return values, t0, step, span, note


@click.group()
def data() -> None:
    """Inspect data files (trajectories as CSV, Parquet or MATLAB .mat)."""


@data.command("info")
@click.argument("path")
@click.option("--time", "time_column", default=None, metavar="COLUMN",
              help="Time column [s] (default t, else time).")
@click.option("--columns", default=None, help="Comma-separated columns to read (default: all; NAME=EXPR too).")
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
@_friendly
def data_info(path: str, time_column: str | None, columns: str | None, as_json: bool) -> None:
    """Check a data file (NaN, time order, columns) and describe it: signals, units, roles, sampling.

    DATA is a CSV, Parquet or MATLAB .mat file.

    \b
    Example:
      cosim data info data.csv --columns Tm,theta_L
      cosim data info rig.mat --time "data[:,0]" --columns "pos=data[:,1],force=data[:,2]"
    """
    from ..data.trajectory import Trajectory

    chosen = _names(columns, "--columns") if columns else None
    if Path(path).suffix.lower() == ".mat":
        from ..data.datafile import load_data

        traj = load_data(path, time=time_column, columns=chosen, excitation=False)
    else:
        from ..data.datafile import time_column as time_rule

        traj = Trajectory.read(path, columns=chosen, time=time_column or time_rule(path))
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
