"""``cosim demo``: the main job on the bundled servo FMU, end to end, into one folder of results."""

from __future__ import annotations

import click

from ._command import _emit, _friendly

__all__ = ["demo"]


@click.command()
@click.option("-o", "--out-dir", "--out", "out_dir", default="cosim-demo", show_default=True,
              type=click.Path(file_okay=False),
              help="Folder for the results.")
@click.option("--progress/--no-progress", default=None,
              help="Progress bars on stderr (default: only when stderr is a terminal).")
@click.option("--plant", type=click.Choice(["bundled", "split"]), default="bundled", show_default=True,
              help="bundled: the servo FMU; split: the same servo as a motor FMU and a shaft-and-load FMU wired by an "
                   "SSP file, run by cosim's system master (names component.variable: load.theta_L, motor.Fc).")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary.")
@_friendly
def demo(out_dir: str, progress: bool | None, plant: str, as_json: bool) -> None:
    """Run the main job on the bundled servo FMU and write its results (data, models, controllers, plots, one
    HTML report) to --out-dir: a linear model of friction-laden noisy data (identified as `cosim identify` does
    given no options), the diagnosis of the friction it lacks, PID and MPC designed on each model and validated
    on the FMU.

    \b
    Example:
      cosim demo --out-dir cosim-demo
      cosim demo --plant split --out-dir cosim-demo-split
    """
    from ..demo import run_demo, summary_lines

    result = run_demo(out_dir, progress=progress, plant=plant)
    _emit(as_json, result, "\n".join(summary_lines(result)))
