"""``cosim simulate`` and ``cosim data info``: an FMU run into a trajectory file, and a data file described."""

from __future__ import annotations

from pathlib import Path

import click

from ..numbers import parse_number
from ._command import _emit, _friendly, _pairs, _resolve_fmu

__all__ = ["data", "simulate"]


@click.command()
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


@click.group()
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
