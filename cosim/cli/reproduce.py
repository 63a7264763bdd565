"""``cosim reproduce paper``: the reference study's results on the bundled FMU, beside its published numbers."""

from __future__ import annotations

import sys

import click

from ..numbers import parse_number
from ._command import _emit, _friendly

__all__ = ["reproduce"]


@click.group()
def reproduce() -> None:
    """Reproduce published results."""


@reproduce.command("paper")
@click.option("--seeds", default=3, show_default=True, type=click.IntRange(1, 1000),
              help="Noise realisations per excitation and noise level.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786); default: local processes.")
@click.option("--workers", default=None, type=click.IntRange(1, 512), help="Local processes (default: all cores).")
@click.option("--out-dir", "--out", "out_dir", default="paper-repro", show_default=True,
              type=click.Path(file_okay=False),
              help="Folder for the tables, plots and report.html.")
@click.option("--noise", "noise_levels", default=None, metavar="LEVELS",
              help="Comma-separated subset of the study's noise levels, e.g. 0,0.1,0.5.")
@click.option("--excitation", "excitations", type=click.Choice(["square", "sine"]), multiple=True,
              help="Restrict to one excitation (default: both).")
@click.option("--progress/--no-progress", default=None,
              help="Progress bar on stderr (default: only when stderr is a terminal).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@_friendly
def reproduce_paper_command(seeds: int, scheduler: str | None, workers: int | None, out_dir: str,
                            noise_levels: str | None, excitations: tuple[str, ...], progress: bool | None,
                            as_json: bool) -> None:
    """The reference study's simulation results on the bundled FMU, beside its published numbers.

    Both excitations (square wave at 10 % of the max torque, 5 Hz sine), noise 0-50 %, several seeds; writes
    Table 1 (maximum deviation), R² against noise (PNG, CSV), square versus sine, the coefficients beside
    the FMU's true ones and one HTML report.

    \b
    Example:
      cosim reproduce paper --seeds 3 --out-dir paper-repro --json
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
