"""The main job, `cosim demo`: the whole toolkit on the bundled servo FMU.

Stage by stage, as capabilities land: build the FMU, simulate it with the reference study's square-wave
excitation and initial state, with and without an undeclared effect (Coulomb friction) and with measurement
noise; identify a linear SINDYc model from the noisy data (the model lacks the friction: its free-run error
is what the diagnosis stage will explain), save it, export it to MATLAB, and write the data and plots.
Diagnosis and control join here as they arrive.

Examples
--------
>>> import tempfile
>>> result = run_demo(tempfile.mkdtemp())
>>> sorted(result)[:3]
['data', 'dt', 'equations']
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from .build import build_fmu
from .export import export_mat
from .identification import STUDY_SETTINGS, SINDYc
from .metrics import nrmse_fit_pct, r2
from .plots import plot_trajectory
from .simulation import simulate
from .study import STATES, STUDY_DT, STUDY_X0

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
    excitation = {"Tm": "square:amp=0.1,freq=2"}
    steps = round(duration / STUDY_DT)
    duration = steps * STUDY_DT
    clean = simulate(fmu, excitation, duration=duration, dt=STUDY_DT, start=STUDY_X0)
    effect = simulate(fmu, excitation, duration=duration, dt=STUDY_DT, start=STUDY_X0,
                      parameters={"Fc": friction})
    measured = effect.with_noise(noise, seed=seed)
    data = measured.write(out / "data_friction_noisy.csv")
    clean.write(out / "data_clean.csv")
    plot = plot_trajectory(measured, out / "simulation.png", label=f"Fc={friction:g} N m, {noise:.0%} noise",
                           others=[("no friction", clean)],
                           title="Bundled two-mass servo FMU: square 10 % of max torque, study's X0")
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
    return {
        "equations": model.equations(),
        "model": str(out / "model.json"),
        "fit_r2": dict(zip(STATES, np.atleast_1d(r2(truth, sim.states)).round(6).tolist(), strict=True)),
        "fit_nrmse_pct": dict(zip(STATES, np.atleast_1d(nrmse_fit_pct(truth, sim.states)).round(3).tolist(),
                                  strict=True)),
        "model_plot": str(fit_plot),
        "fmu": str(fmu),
        "data": str(Path(data)),
        "plot": str(plot),
        "samples": len(measured),
        "dt": STUDY_DT,
        "seconds": round(time.perf_counter() - started, 3),
    }
