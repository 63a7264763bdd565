"""The main job, `cosim demo`: the whole toolkit on the bundled servo FMU.

Stage by stage, as capabilities land: build the FMU, simulate it with the reference study's square-wave
excitation and initial state, with and without an undeclared effect (Coulomb friction) and with measurement
noise, and write the data and plots. Identification, diagnosis and control join here as they arrive.

Examples
--------
>>> import tempfile
>>> result = run_demo(tempfile.mkdtemp())
>>> sorted(result)[:3]
['data', 'dt', 'fmu']
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from .build import build_fmu
from .plots import plot_trajectory
from .simulation import simulate
from .study import STUDY_DT, STUDY_X0

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
    return {
        "fmu": str(fmu),
        "data": str(Path(data)),
        "plot": str(plot),
        "samples": len(measured),
        "dt": STUDY_DT,
        "seconds": round(time.perf_counter() - started, 3),
    }
