"""The main job, `cosim demo`: the whole toolkit on the bundled servo FMU.

Stage by stage, as capabilities land: build the FMU, simulate it from rest with a 1-40 Hz multisine torque
(broadband: it pins the torque gain that the study's square wave from a 4 rad initial twist leaves loose at
5 % noise), with and without an undeclared effect (Coulomb friction) and with measurement noise; identify a
linear SINDYc model from the noisy data (the model lacks the friction: its free-run error is what the
diagnosis stage will explain), save it, export it to MATLAB, and write the data and plots.
Then design a PID (velocity feedback from the motor) and an MPC on the identified model, validate both
against the FMU with the friction on (a 0.01 rad load-angle step and a 500 N m load-torque step, the
telescope specs of :mod:`cosim.validation`), and write one HTML report with every plot. Diagnosis joins here
when it arrives.

Examples
--------
>>> import tempfile
>>> result = run_demo(tempfile.mkdtemp())
>>> sorted(result)[:3], result["controllers"]["mpc"]["passed"]
(['controllers', 'data', 'dt'], True)
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from .build import build_fmu
from .export import export_mat, to_statespace
from .identification import STUDY_SETTINGS, SINDYc
from .metrics import nrmse_fit_pct, r2
from .plots import plot_closed_loop, plot_trajectory
from .report import Report
from .simulation import simulate
from .study import STATES, STUDY_DT
from .validation import TELESCOPE_SPECS, disturbance_step, setpoint_step, validate

#: The demo's identification experiment: a 1-40 Hz multisine at 20 % of the rated torque, from rest.
DEMO_EXCITATION = "multisine:amp=0.2,fmin=1,fmax=40"
#: The demo's closed-loop scenarios: a 0.01 rad load-angle step, then a 500 N m load-torque step.
DEMO_SCENARIOS = (setpoint_step(0.01, at=0.05, duration=2.0), disturbance_step(500.0, at=0.3, duration=2.0))

__all__ = ["run_demo"]


def run_demo(out_dir: str | os.PathLike, *, duration: float = 4.0, friction: float = 100.0,
             noise: float = 0.05, seed: int = 0) -> dict[str, Any]:
    """Run the demo and write its files into `out_dir`; return a summary (paths and figures).

    Parameters
    ----------
    out_dir : path-like
        Folder for the results (created).
    duration : float
        Length of each run [s]; a whole number of steps of 1/2257 s.
    friction : float
        Coulomb friction torque Fc [N m] of the run with the undeclared effect.
    noise, seed : float, int
        Measurement noise level (std = level x std of each clean state) and its seed.
    """
    out = Path(out_dir)
    started = time.perf_counter()
    fmu = build_fmu()
    excitation = {"Tm": DEMO_EXCITATION}
    steps = round(duration / STUDY_DT)
    duration = steps * STUDY_DT
    clean = simulate(fmu, excitation, duration=duration, dt=STUDY_DT)
    effect = simulate(fmu, excitation, duration=duration, dt=STUDY_DT, parameters={"Fc": friction})
    measured = effect.with_noise(noise, seed=seed)
    data = measured.write(out / "data_friction_noisy.csv")
    clean.write(out / "data_clean.csv")
    plot = plot_trajectory(measured, out / "simulation.png", label=f"Fc={friction:g} N m, {noise:.0%} noise",
                           others=[("no friction", clean)],
                           title="Bundled two-mass servo FMU: multisine 1-40 Hz, 20 % of max torque, from rest")
    estimator = SINDYc(**STUDY_SETTINGS).fit(measured, states=list(STATES), inputs=["Tm"])
    model = estimator.model_
    model.save(out / "model.json")
    export_mat(model, out / "statespace.mat")
    x0 = np.asarray(model.meta["x0"][0]) if "x0" in model.meta else measured[list(STATES)][0]
    sim = model.simulate(x0, measured[["Tm"]][:-1], dt=STUDY_DT)
    fit_plot = plot_trajectory(measured.select(list(STATES)), out / "model_vs_data.png", label="measured",
                               others=[("linear SINDYc model, free run", sim.to_trajectory())],
                               title="Identified linear model against the data it lacks friction for")
    truth = effect[list(STATES)]
    fit = {"fit_r2": dict(zip(STATES, np.atleast_1d(r2(truth, sim.states)).round(6).tolist(), strict=True)),
           "fit_nrmse_pct": dict(zip(STATES, np.atleast_1d(nrmse_fit_pct(truth, sim.states)).round(3).tolist(),
                                     strict=True))}
    report = Report("cosim demo", subtitle=f"Bundled two-mass servo FMU with Coulomb friction Fc={friction:g} N m "
                    f"and {noise:.0%} measurement noise; linear SINDYc model; PID and MPC designed on it, validated "
                    "on the FMU")
    _data_sections(report, plot, fit_plot, model, fit)
    control_summary = _control_stage(report, model, fmu, out, friction=friction)
    report_path = report.write(out / "report.html")
    return {
        "equations": model.equations(),
        "model": str(out / "model.json"),
        **fit,
        "model_plot": str(fit_plot),
        "fmu": str(fmu),
        "data": str(Path(data)),
        "plot": str(plot),
        "samples": len(measured),
        "dt": STUDY_DT,
        "controllers": control_summary,
        "report": str(report_path),
        "seconds": round(time.perf_counter() - started, 3),
    }


def _data_sections(part: Report, plot: Path, fit_plot: Path, model: Any, fit: dict[str, Any]) -> None:
    """The data and identification sections of the report."""
    part.add_figure("Data from the FMU", plot, caption="Multisine torque from rest; with and without friction.")
    part.add_text("Identified linear model (SINDYc)", "\n\n".join(model.equations()))
    part.add_table(None, [{"state": k, "R2": fit["fit_r2"][k], "NRMSE fit %": fit["fit_nrmse_pct"][k]}
                          for k in fit["fit_r2"]], caption="free run of the model against the noise-free data")
    part.add_figure(None, fit_plot, caption="The linear model lacks the friction.")


def _control_stage(report: Report, model: Any, fmu: Path, out: Path, *, friction: float) -> dict[str, Any]:
    """Design a PID and an MPC on `model`, validate both on the FMU with friction; add them to `report`."""
    from controllers.mpc import MPC
    from controllers.pid import tune_pid

    sys_c = to_statespace(model)
    limits = {"u_min": -5000.0, "u_max": 5000.0}
    pid = tune_pid(sys_c, dt=STUDY_DT, input="Tm", output="theta_L", velocity="omega_m", **limits)
    mpc = MPC(sys_c, dt=STUDY_DT, horizon=20, inputs=["Tm"], outputs=["theta_m", "theta_L"], tracked=["theta_L"],
              **limits)
    summary: dict[str, Any] = {}
    for name, controller in (("pid", pid), ("mpc", mpc)):
        if controller.design_model is None:
            from controllers.base import DesignModel

            controller.design_model = DesignModel.from_statespace(sys_c, dt=STUDY_DT)
        controller.save(out / f"{name}.json")
        verdict = validate(fmu, controller, DEMO_SCENARIOS, TELESCOPE_SPECS, parameters={"Fc": friction})
        pngs = [plot_closed_loop(result, out / f"closed_loop_{name}_{i}.png", title=f"{name.upper()}: {s.name}")
                for i, (s, result) in enumerate(zip(verdict.scenarios, verdict.results, strict=True), start=1)]
        step = verdict.results[0].metrics
        summary[name] = {"passed": verdict.passed, "reasons": list(verdict.reasons),
                         "settling_time": step["settling_time"], "overshoot_pct": step["overshoot_pct"],
                         "steady_state_error": step["steady_state_error"],
                         "solve_time_us": verdict.solve_time_us(), "file": str(out / f"{name}.json"),
                         "plots": [str(p) for p in pngs]}
        rows = [{"scenario": c["scenario"], "spec": c["spec"],
                 "value": "n/a" if c["value"] is None else float(f"{c['value']:.4g}"),
                 "result": "n/a" if c["passed"] is None else ("met" if c["passed"] else "NOT MET")}
                for c in verdict.checks]
        report.add_table(f"{name.upper()} on the FMU with friction: {'PASSED' if verdict.passed else 'FAILED'}",
                         rows, highlight={(i, "result"): c["passed"] for i, c in enumerate(verdict.checks)
                                          if c["passed"] is not None},
                         caption=f"compute time per call: median {verdict.solve_time_us()['median']:.1f} µs, "
                                 f"p99 {verdict.solve_time_us()['p99']:.1f} µs")
        for png in pngs:
            report.add_figure(None, png)
    return summary
