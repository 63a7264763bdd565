"""``cosim validate``: a controller run against an FMU in closed loop, its specs checked (and Monte Carlo)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from ._command import _emit, _friendly, _names, _ranges, _resolve_fmu, _settings
from ._outputs import check_outputs

__all__ = ["validate_command"]


@click.command("validate")
@click.argument("fmu_path", metavar="FMU")
@click.argument("controller_path", metavar="CTRL.json")
@click.option("--scenario", "scenarios", multiple=True, metavar="KIND:amp=..,at=..",
              help="step:amp=0.01 | ramp:amp=0.01,rate=0.02 | disturbance:amp=500,at=0.5[,input=TL]; keys amp, at, "
                   "duration, rate, input, setpoint, band, name; extra NAME=VALUE items set FMU parameters for that "
                   "scenario. Repeatable. Default: a step of the controller's design step (cosim design pid's "
                   "--step), long enough to settle; on the bundled servo step:amp=0.01,at=0.05,duration=2.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help="FMU parameter for every scenario, e.g. --set Fc=100 (Coulomb friction on). Repeatable.")
@click.option("--spec", "specs", multiple=True, metavar="METRIC<=LIMIT",
              help="settling_time<=1, overshoot<=10%, steady_state_error<=2e-5, input_limit<=5000, "
                   "deadline_miss_rate<=0.001, solve_time_p99<=50us, ... (quote it: the shell reads < and >). "
                   "Repeatable. Default from the plant and the design: settling_time twice the predicted one, "
                   "overshoot<=10%, steady_state_error 2% of the step, input_limit the controller's limit (else "
                   "the FMU input's declared range); on the bundled servo the telescope's specs. Compute time is "
                   "reported, and judged only when a timing spec is given.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="Write an HTML report (PNG plots beside it).")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for the PNG plots (default: beside --report).")
@click.option("--no-model", is_flag=True, help="Do not also run the controller against its design model.")
@click.option("--robustness", "samples", type=click.IntRange(0, None), default=0, show_default=True,
              help="Also validate on N plants drawn around the nominal one (Monte Carlo).")
@click.option("--spread", default=0.2, show_default=True, type=float,
              help="Relative spread of the varied parameters in the Monte Carlo (0.2 = ±20 %).")
@click.option("--vary", "vary", default=None, metavar="NAME,...",
              help="FMU parameters the Monte Carlo spreads by ±--spread around their values (--set, else the "
                   "start value); an array names all its elements. Default: Jm, JL, KL, Bm, BL where the FMU has "
                   "them all (the bundled servo's inertias, stiffness and damping), else every real parameter "
                   "(array elements too) whose value is not zero.")
@click.option("--effect", "effects", multiple=True, metavar="NAME=LOW:HIGH",
              help="Effect parameter range in the Monte Carlo, e.g. --effect Fc=0:200. Repeatable.")
@click.option("--min-pass-rate", default=1.0, show_default=True, type=click.FloatRange(0.0, 1.0),
              help="Exit 1 when the Monte Carlo pass rate falls below this fraction.")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler for the Monte Carlo.")
@click.option("--workers", type=click.IntRange(1, None), default=None, help="Local worker processes.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the Monte Carlo draws.")
@click.option("--kind", type=click.Choice(["cs", "me"]), default=None,
              help="The FMU's interface: cs (co-simulation) or me (Model Exchange, integrated by FMPy's CVode). "
                   "Default: cs when the FMU has it, else me.")
@click.option("--progress/--no-progress", default=None,
              help="Progress bars on stderr (default: only when stderr is a terminal).")
@click.option("--json", "as_json", is_flag=True,
              help='Print {"passed", "metrics", "solve_time_us": {"median", "p99"}, "reasons", ...}.')
@_friendly
def validate_command(fmu_path: str, controller_path: str, scenarios: tuple[str, ...], sets: tuple[str, ...],
                     specs: tuple[str, ...], report_path: str | None, plots_dir: str | None, no_model: bool,
                     samples: int, spread: float, vary: str | None, effects: tuple[str, ...], min_pass_rate: float,
                     scheduler: str | None, workers: int | None, seed: int, kind: str | None,
                     progress: bool | None, as_json: bool) -> None:
    """Run a controller against an FMU in closed loop and check specs; exit 1 when one fails.

    Without --scenario and --spec the checks come from the plant and the design (a step of the controller's
    design step, its predicted settling time with a margin, 10 % overshoot, 2 % steady-state error, the input
    limit), printed with the reason for each; the bundled servo keeps the telescope's specs.

    With --robustness N it also validates on N plants drawn around the nominal one (the --vary parameters within
    ±--spread, effects within --effect ranges) through the sweep engine, and exits 1 when the pass rate is below
    --min-pass-rate.

    \b
    Example:
      cosim validate bundled ctrl.json --scenario step:amp=0.01,duration=2 --set Fc=100 --json
      cosim validate bundled ctrl.json --spec "settling_time<=1" --spec "overshoot<=10%" --report v.html
      cosim validate bundled ctrl.json --robustness 50 --spread 0.2 --effect Fc=0:200
      cosim validate model.fmu pid.json --robustness 20 --vary k,m
    """
    from controllers.base import load_controller

    from ..loop.validation import parse_scenario, parse_spec, validate
    from ..loop.validation_defaults import check_parameter_names, default_checks
    from ..loop.validation_report import write_validation_report

    started = time.perf_counter()
    check_outputs({"--report": [report_path]}, {"--report": (".html", ".htm")})

    scenario_list = [parse_scenario(s) for s in scenarios]
    spec_list = [parse_spec(s) for s in specs]  # refused before anything runs
    fmu = _resolve_fmu(fmu_path)
    if not fmu.is_file():
        from ..errors import FmuNotFoundError

        raise FmuNotFoundError(f"FMU not found: {fmu}; build the bundled one with `cosim fmu build` or pass bundled")
    controller = load_controller(controller_path)
    parameters = _settings(sets, "--set")
    defaults = None
    if not scenarios or not specs:
        steps = [abs(s.amplitude) for s in scenario_list if s.kind != "disturbance"]
        defaults = default_checks(fmu, controller, kind=kind, steps=steps)
        scenario_list = scenario_list or [parse_scenario(defaults.scenario)]
        spec_list = spec_list or [parse_spec(s) for s in defaults.specs]
    check_parameter_names(fmu, scenario_list, parameters, kind=kind)  # a misspelt key, before anything runs
    uncertain = _names(vary, "--vary") if vary else None
    rob_args = None
    if samples:
        from ..study.robustness import robustness, robustness_plan

        rob_args = {"samples": samples, "spread": spread, "uncertain": uncertain,
                    "effects": _ranges(effects, "--effect"), "parameters": parameters, "kind": kind}
        robustness_plan(fmu, **{k: v for k, v in rob_args.items() if k != "samples"})  # bad names, before running
    verdict = validate(fmu, controller, scenario_list, spec_list, parameters=parameters or None,
                       model=None if no_model else "design", progress=progress, kind=kind)
    rob = None
    if rob_args is not None:
        rob = robustness(fmu, controller, [s.with_effects(**parameters) for s in scenario_list], spec_list,
                         seed=seed, scheduler=scheduler, workers=workers, progress=progress, **rob_args)
    payload = verdict.to_dict()
    if defaults is not None:
        payload["defaults"] = {"scenario": None if scenarios else defaults.scenario,
                               "specs": None if specs else list(defaults.specs), "why": list(defaults.why)}
    files: dict[str, str] = {}
    if report_path or plots_dir:
        target = Path(report_path) if report_path else Path(plots_dir) / "validation.html"
        html, pngs = write_validation_report(verdict, target, controller=controller, robustness=rob,
                                             plots_dir=plots_dir, fmu=fmu, kind=kind, parameters=parameters or None,
                                             seconds=time.perf_counter() - started, min_pass_rate=min_pass_rate)
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
    if defaults is not None:
        chosen = ([] if scenarios else [f"scenario {defaults.scenario}"]) + ([] if specs else list(defaults.specs))
        lines.append(f"defaults: {', '.join(chosen)} ({'; '.join(defaults.why)})")
    if rob is not None:
        lines.append(f"robustness: {rob.samples} samples, pass rate {rob.pass_rate:.1%}, worst case "
                     + ", ".join(f"{k}={v:.4g}" for k, v in rob.worst["parameters"].items()))
        lines.append(f"  run on {rob.sweep.scheduler}")
    lines += [f"{k}: {v}" for k, v in files.items()]
    _emit(as_json, payload, "\n".join(lines))
    if not verdict.passed or (rob is not None and rob.pass_rate < min_pass_rate):
        sys.exit(1)
