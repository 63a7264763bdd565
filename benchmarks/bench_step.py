"""Closed-loop stepping speed: `FmuPlant.step` against FMPy's `FMU2Slave` calls, side by side.

Both loops run the same proportional law on the same FMU (the bundled two-mass servo, FMI 2.0) at the
study's 2257 Hz; rounds alternate between the two so that machine noise hits both alike. The figures
(steps per second, median over rounds, and their ratio) go to benchmarks/results/step_speed.json and .md.

Run:  python benchmarks/bench_step.py [--steps 20000] [--rounds 7]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import fmpy
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import read_model_description

from cosim import FmuPlant, build_fmu
from cosim.files import write_text_atomic

DT = 1 / 2257
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
        f"{result['ratio_median']:.2f} (min {result['ratio_min']:.2f}, max {result['ratio_max']:.2f})\n"
    )
    write_text_atomic(out.with_suffix(".md"), table)
    print(table)


if __name__ == "__main__":
    main()
