"""Stepping speed: `FmuPlant.step` against FMPy's own slave calls, side by side.

Closed loop: both loops run the same proportional law on the same FMU (the bundled two-mass servo, FMI 2.0)
at the study's 2257 Hz. Reference FMUs: the Modelica Association's VanDerPol and Dahlquist, FMI 2.0 and FMI
3.0 co-simulation (built by tests/reference_fmus.py), stepped at 0.01 s: `FmuPlant.step` against FMPy's
`FMU2Slave` setReal/doStep/getReal loop (`FMU3Slave` setFloat64/doStep/getFloat64), the same number of steps;
neither FMU has an input, so both loops only step and read the outputs (FMPy's set call is skipped, not made
with nothing to set). Rounds alternate between the loops so that machine noise hits both alike. The figures
(steps per second, median over rounds, and their ratio) go to benchmarks/results/step_speed.json and .md.

Run:  python benchmarks/bench_step.py [--steps 20000] [--rounds 7]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import fmpy
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.model_description import read_model_description

from cosim import FmuPlant, build_fmu
from cosim.files import write_text_atomic

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # tests/ is not a package
from reference_fmus import reference_fmus  # noqa: E402

DT = 1 / 2257
REF_DT = 0.01  # communication step of the Reference FMUs
REFERENCE = ("VanDerPol", "Dahlquist")
KP = 2000.0  # N m/rad on the load angle: a trivial proportional law
REF = 0.01   # rad


def loop_cosim(fmu: Path, steps: int) -> float:
    with FmuPlant(fmu, dt=DT) as plant:
        y = plant.read_outputs()
        start = time.perf_counter()
        for _ in range(steps):
            y = plant.step([KP * (REF - y[2]), 0.0])
        elapsed = time.perf_counter() - start
    return steps / elapsed


def loop_fmpy(fmu: Path, steps: int) -> float:
    md = read_model_description(str(fmu))
    unzipdir = fmpy.extract(str(fmu))
    vrs = {v.name: v.valueReference for v in md.modelVariables}
    u_vr = [vrs["Tm"], vrs["TL"]]
    y_vr = [vrs[n] for n in ("theta_m", "omega_m", "theta_L", "omega_L")]
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="bench")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    try:
        y = slave.getReal(y_vr)
        t = 0.0
        start = time.perf_counter()
        for k in range(steps):
            slave.setReal(u_vr, [KP * (REF - y[2]), 0.0])
            t = k * DT
            slave.doStep(t, DT)
            y = slave.getReal(y_vr)
        elapsed = time.perf_counter() - start
    finally:
        slave.terminate()
        slave.freeInstance()
    return steps / elapsed


def loop_cosim_free(fmu: Path, steps: int, dt: float = REF_DT) -> float:
    """Steps per second of `FmuPlant.step` on an FMU without inputs."""
    with FmuPlant(fmu, dt=dt) as plant:
        none: list[float] = []
        start = time.perf_counter()
        for _ in range(steps):
            plant.step(none)
        elapsed = time.perf_counter() - start
    return steps / elapsed


def loop_fmpy_free(fmu: Path, steps: int, dt: float = REF_DT) -> float:
    """Steps per second of FMPy's slave loop (doStep, then get the outputs) on an FMU without inputs."""
    md = read_model_description(str(fmu))
    unzipdir = fmpy.extract(str(fmu))
    y_vr = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    fmi3 = md.fmiVersion.startswith("3")
    cls = FMU3Slave if fmi3 else FMU2Slave
    slave = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="bench")
    slave.instantiate()
    if fmi3:
        slave.enterInitializationMode(startTime=0.0)
        get = slave.getFloat64
    else:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        get = slave.getReal
    slave.exitInitializationMode()
    try:
        get(y_vr)
        start = time.perf_counter()
        for k in range(steps):
            slave.doStep(k * dt, dt)
            get(y_vr)
        elapsed = time.perf_counter() - start
    finally:
        slave.terminate()
        slave.freeInstance()
    return steps / elapsed


def reference_rates(steps: int, rounds: int) -> list[dict]:
    """FmuPlant against FMPy on each Reference FMU of :data:`REFERENCE`, FMI 2.0 and 3.0, interleaved rounds."""
    rows = []
    for version in (2, 3):
        fmus = reference_fmus(version, optimized=True)  # the Release build, as an exporting tool's
        for name in REFERENCE:
            fmu = fmus[name]
            loop_cosim_free(fmu, 1000), loop_fmpy_free(fmu, 1000)  # warm-up
            ours, theirs = [], []
            for _ in range(rounds):
                ours.append(loop_cosim_free(fmu, steps))
                theirs.append(loop_fmpy_free(fmu, steps))
            ratios = [a / b for a, b in zip(ours, theirs, strict=True)]
            rows.append({"model": name, "fmi": f"{version}.0", "dt": REF_DT,
                         "cosim_steps_per_s_median": statistics.median(ours),
                         "fmpy_steps_per_s_median": statistics.median(theirs),
                         "ratio_median": statistics.median(ratios), "ratio_min": min(ratios),
                         "ratio_max": max(ratios)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "step_speed"))
    args = parser.parse_args()
    fmu, fmu3 = build_fmu(), build_fmu(fmi_version="3.0")
    loop_cosim(fmu, 1000), loop_fmpy(fmu, 1000), loop_cosim(fmu3, 1000)  # warm-up: imports, page cache
    cosim_rates, fmpy_rates, fmi3_rates = [], [], []
    for _ in range(args.rounds):
        cosim_rates.append(loop_cosim(fmu, args.steps))
        fmpy_rates.append(loop_fmpy(fmu, args.steps))
        fmi3_rates.append(loop_cosim(fmu3, args.steps))
    ratios = [a / b for a, b in zip(cosim_rates, fmpy_rates, strict=True)]
    reference = reference_rates(args.steps, args.rounds)
    result = {
        "benchmark": "closed loop, proportional law, bundled two_mass_servo FMI 2.0, dt=1/2257 s",
        "steps_per_round": args.steps,
        "rounds": args.rounds,
        "cosim_steps_per_s_median": statistics.median(cosim_rates),
        "fmpy_steps_per_s_median": statistics.median(fmpy_rates),
        "ratio_median": statistics.median(ratios),
        "ratio_min": min(ratios),
        "ratio_max": max(ratios),
        "cosim_us_per_step": 1e6 / statistics.median(cosim_rates),
        "cosim_fmi3_steps_per_s_median": statistics.median(fmi3_rates),
        "fmpy_us_per_step": 1e6 / statistics.median(fmpy_rates),
        "reference_fmus": reference,
        "python": platform.python_version(),
        "fmpy": fmpy.__version__,
        "machine": platform.machine(),
    }
    out = Path(args.out)
    write_text_atomic(out.with_suffix(".json"), json.dumps(result, indent=2) + "\n")
    table = (
        "| loop | steps/s (median) | us/step |\n| --- | --- | --- |\n"
        f"| cosim FmuPlant.step | {result['cosim_steps_per_s_median']:,.0f} | {result['cosim_us_per_step']:.2f} |\n"
        f"| fmpy FMU2Slave setReal/doStep/getReal | {result['fmpy_steps_per_s_median']:,.0f} | "
        f"{result['fmpy_us_per_step']:.2f} |\n"
        f"| cosim FmuPlant.step, FMI 3.0 build | {result['cosim_fmi3_steps_per_s_median']:,.0f} | "
        f"{1e6 / result['cosim_fmi3_steps_per_s_median']:.2f} |\n\n"
        f"ratio (median over {args.rounds} interleaved rounds of {args.steps} steps): "
        f"{result['ratio_median']:.2f} (min {result['ratio_min']:.2f}, max {result['ratio_max']:.2f})\n\n"
        f"Reference FMUs (no inputs, dt = {REF_DT} s): FmuPlant.step against FMPy's slave loop (FMI 2.0 "
        "FMU2Slave doStep/getReal, FMI 3.0 FMU3Slave doStep/getFloat64)\n\n"
        "| FMU | FMI | cosim steps/s | fmpy steps/s | ratio median (min, max) |\n| --- | --- | --- | --- | --- |\n"
        + "".join(f"| {r['model']} | {r['fmi']} | {r['cosim_steps_per_s_median']:,.0f} | "
                  f"{r['fmpy_steps_per_s_median']:,.0f} | {r['ratio_median']:.2f} ({r['ratio_min']:.2f}, "
                  f"{r['ratio_max']:.2f}) |\n" for r in reference)
    )
    write_text_atomic(out.with_suffix(".md"), table)
    print(table)


if __name__ == "__main__":
    main()
