"""The closed-loop validation report: one HTML file with the verdict, the checks, the figures and the plots.

Examples
--------
>>> import tempfile, pathlib
>>> from cosim import build_fmu
>>> from cosim.loop.validation import validate
>>> from controllers.pid import PID
>>> pid = PID(kp=1.5e4, ki=1.3e4, kd=6.4e3, tf=0.022, b=0.33, dt=1e-3, inputs="Tm", outputs="theta_L",
...           u_min=-5000, u_max=5000)
>>> verdict = validate(build_fmu(), pid, "step:amp=0.01,duration=1", ["input_limit<=5000"])
>>> out = pathlib.Path(tempfile.mkdtemp())
>>> path, pngs = write_validation_report(verdict, out / "report.html", controller=pid)
>>> path.name, [p.name for p in pngs]
('report.html', ['closed_loop_1.png'])
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..figures import save_figure
from ..report import Report, step_text
from .plots import plot_closed_loop
from .validation import Verdict

__all__ = ["fmu_text", "verdict_summary", "write_validation_report"]


def _fmt(value: Any) -> Any:
    if isinstance(value, float):
        return "n/a" if not math.isfinite(value) else float(f"{value:.6g}")
    return "n/a" if value is None else value


def fmu_text(fmu: str | os.PathLike, *, kind: str | None = None, parameters: Mapping[str, Any] | None = None) -> str:
    """The plant as a summary names it: ``two_mass_servo.fmu (two_mass_servo, FMI 2.0, co-simulation); set: Fc=100``.

    Parameters
    ----------
    fmu : path-like or FmuPlant
    kind : {"cs", "me"}, optional
        The interface it ran through (default: the one :func:`~cosim.plant.model_description.interface_kind`
        picks).
    parameters : mapping, optional
        The FMU parameters set for the run.
    """
    from ..errors import CosimError
    from ..plant.model_description import interface_kind, open_model_description

    path = Path(getattr(fmu, "path", fmu))
    name = path.name
    try:
        md = open_model_description(path, kind)
        interface = {"cs": "co-simulation", "me": "Model Exchange"}[interface_kind(md, kind)]
        text = f"{name} ({md.modelName}, FMI {md.fmiVersion}, {interface})"
    except (CosimError, OSError):  # (a report still names an FMU it can no longer open)
        text = name
    if parameters:
        text += "; set: " + ", ".join(f"{k}={v:g}" if isinstance(v, (int, float)) else f"{k}={v}"
                                      for k, v in parameters.items())
    return text


def verdict_summary(verdict: Verdict, label: str, *, note: str = "") -> dict[str, Any]:
    """One row of a summary box's verdicts (:func:`cosim.report.summary_box`): `label`, PASSED or FAILED overall
    and per scenario (a scenario passes when it met every spec that applies and its loop ran to the end)."""
    scenarios = {}
    for scenario, result in zip(verdict.scenarios, verdict.results, strict=True):
        marks = [c["passed"] for c in verdict.checks if c["scenario"] == scenario.name and c["passed"] is not None]
        scenarios[scenario.name] = all(marks) and result.status == "completed"
    return {"label": label, "passed": verdict.passed, "scenarios": scenarios, "note": note}


def _summary(verdict: Verdict, controller: Any, robustness: Any, fmu: Any, kind: str | None,
             parameters: Mapping[str, Any] | None, seconds: float | None, min_pass_rate: float) -> dict[str, Any]:
    """The summary box's facts of a validation."""
    context = []
    label = "controller"
    if controller is not None:
        label = getattr(controller, "kind", type(controller).__name__)
        signals = "; ".join(f"{what} {', '.join(getattr(controller, key))}" for what, key in
                            (("inputs", "inputs"), ("measured", "outputs"), ("tracked", "tracked")))
        context.append(("Controller", f"{label}, dt {step_text(controller.dt)}; {signals}"))
    specs = list(dict.fromkeys(c["spec"] for c in verdict.checks))
    context.append(("Scenarios", "; ".join(f"{s.name} ({s.duration:g} s)" for s in verdict.scenarios)
                    + f"; {len(specs)} specs: {', '.join(specs)}"))
    more = []
    gaps = [(s.name, r.metrics.get("model_discrepancy_pct")) for s, r in zip(verdict.scenarios, verdict.results,
                                                                              strict=True) if s.kind != "disturbance"]
    gaps = [(name, g) for name, g in gaps if g is not None and math.isfinite(g)]
    if gaps:
        more.append(("Model vs FMU", "the design model's loop differs from the FMU's by "
                     + "; ".join(f"{g:.3g} % of the step (RMS) in {name}" for name, g in gaps)))
    if verdict.reasons:
        more.append(("Why it failed", "; ".join(verdict.reasons[:3])
                     + (f"; ... {len(verdict.reasons) - 3} more below" if len(verdict.reasons) > 3 else "")))
    rob = None
    if robustness is not None:
        worst = robustness.worst
        rob = {"samples": robustness.samples, "pass_rate": robustness.pass_rate,
               "passed": robustness.pass_rate >= min_pass_rate,
               "text": f"{robustness.samples} plants drawn around the nominal one (at least {min_pass_rate:.0%} "
                       "required); worst case " + ", ".join(f"{k}={v:.4g}" for k, v in worst["parameters"].items())}
    return {"plant": fmu_text(fmu, kind=kind, parameters=parameters) if fmu is not None else None,
            "context": context, "verdicts": [verdict_summary(verdict, label)], "robustness": rob, "more": more,
            "seconds": seconds}


def write_validation_report(verdict: Verdict, path: str | os.PathLike, *, controller: Any = None,
                            robustness: Any = None, plots_dir: str | os.PathLike | None = None,
                            title: str = "Closed-loop validation", fmu: str | os.PathLike | None = None,
                            kind: str | None = None, parameters: Mapping[str, Any] | None = None,
                            seconds: float | None = None, min_pass_rate: float = 1.0) -> tuple[Path, list[Path]]:
    """Write the HTML report of `verdict` (and of a robustness study); return its path and the PNG plots.

    Parameters
    ----------
    verdict : Verdict
    path : path-like
        The HTML file.
    controller : Controller, optional
        Its kind, settings summary and design figures (``info``) go into the report.
    robustness : RobustnessResult, optional
        Pass rate, worst case and the per-sample table.
    plots_dir : path-like, optional
        Where the PNG plots go (default: beside the report), named ``closed_loop_<i>.png``.
    title : str
    fmu : path-like, optional
        The plant validated on, named in the summary box with `kind` and the `parameters` set for every scenario.
    kind : {"cs", "me"}, optional
    parameters : mapping, optional
    seconds : float, optional
        How long the validation took (measured where it ran), for the summary box.
    min_pass_rate : float
        The robustness pass rate required (the summary box marks it passed or failed).

    Returns
    -------
    (Path, list of Path)
        The HTML file and the PNG plots.
    """
    path = Path(path)
    folder = Path(plots_dir) if plots_dir is not None else path.parent
    report = Report(title, subtitle=("PASSED" if verdict.passed else "FAILED") +
                    f": {sum(1 for c in verdict.checks if c['passed'])} of "
                    f"{sum(1 for c in verdict.checks if c['passed'] is not None)} checks met")
    report.add_summary(**_summary(verdict, controller, robustness, fmu, kind, parameters, seconds, min_pass_rate))
    if verdict.reasons:
        report.add_text("Why it failed", "\n\n".join(verdict.reasons))
    if controller is not None:
        info = {k: v for k, v in getattr(controller, "info", {}).items() if not isinstance(v, (dict, list))}
        report.add_table("Controller", [{"kind": getattr(controller, "kind", type(controller).__name__),
                                         "dt [s]": controller.dt, "inputs": ", ".join(controller.inputs),
                                         "measured": ", ".join(controller.outputs),
                                         "tracked": ", ".join(controller.tracked), **info}])
    rows = [{"scenario": c["scenario"], "spec": c["spec"], "value": _fmt(c["value"]),
             "result": "n/a" if c["passed"] is None else ("met" if c["passed"] else "NOT MET")}
            for c in verdict.checks]
    marks = {(i, "result"): c["passed"] for i, c in enumerate(verdict.checks) if c["passed"] is not None}
    report.add_table("Specs", rows, highlight=marks)
    solve = verdict.solve_time_us()
    keys = ("rise_time", "settling_time", "overshoot_pct", "iae", "steady_state_error", "peak_error", "input_peak",
            "constraint_violations", "deadline_misses", "solve_time_median_us", "solve_time_p99_us",
            "realtime_factor", "model_discrepancy_pct")
    report.add_table("Figures per scenario", [{"scenario": s.name, **{k: _fmt(r.metrics.get(k)) for k in keys}}
                                              for s, r in zip(verdict.scenarios, verdict.results, strict=True)],
                     caption=f"controller compute time over all runs: median {solve['median']:.1f} µs, "
                             f"p99 {solve['p99']:.1f} µs, max {solve['max']:.1f} µs")
    pngs = []
    for i, (scenario, result) in enumerate(zip(verdict.scenarios, verdict.results, strict=True), start=1):
        png = save_figure(plot_closed_loop(result, title=scenario.name), folder / f"closed_loop_{i}.png", close=False)
        pngs.append(png)
        caption = (f"status {result.status}; " + "; ".join(f"t={e['time']:.4g} s {e['kind']}: {e['message']}"
                                                           for e in result.events[:5]))
        report.add_figure(f"Scenario {i}: {scenario.name}", png, caption=caption)
    if verdict.notes:
        report.add_text("Notes", "\n\n".join(verdict.notes), note=True)
    if robustness is not None:
        worst = robustness.worst
        report.add_text("Robustness (Monte Carlo)",
                        f"{robustness.samples} plants drawn around the nominal one: pass rate "
                        f"{robustness.pass_rate:.1%}. Worst case: "
                        + ", ".join(f"{k}={v:.4g}" for k, v in worst["parameters"].items())
                        + (" - " + "; ".join(worst["reasons"]) if worst["reasons"] else " (passed)"))
        report.add_table(None, robustness.table.head(200).round(6))
    return report.write(path), pngs
