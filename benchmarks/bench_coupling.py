"""How accurate is the system master? The split servo (two FMUs coupled by cosim's master) against the one-FMU
servo, over four communication steps, for each algorithm and extrapolation order.

The bundled servo split as tools split it (fmus/two_mass_servo_split: a motor FMU, a shaft-and-load FMU, wired by
an SSP file) and the one-FMU servo (fmus/two_mass_servo) integrate the same equations with the same RK4; what
differs is only the coupling: the shaft torque and the motor's angle and speed are exchanged once a communication
step. Both are driven by the same held torque (a step and a 2 Hz sine on Tm), and compared sample by sample:
the error is the largest difference over the run, per state, over the one-FMU servo's range of that state.

Measured: the error at dt = 1/500, 1/1000, 1/2000 and 1/4000 s for Jacobi and Gauss-Seidel with extrapolation of
order 0, 1 and 2, the convergence order between successive steps (log2 of the error ratio), and at dt = 1/2257 s
(the reference study's rate) with the default master, the motor and load speeds' errors. Twice: the linear
servo, and with Coulomb friction, cogging and gravity switched on where they sit (the smooth effects; a backlash
is a kink, at which any master is first order).

Run:  python benchmarks/bench_coupling.py [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

STEPS = (1 / 500, 1 / 1000, 1 / 2000, 1 / 4000)
STUDY_DT = 1 / 2257
DURATION = 1.0
STATES = ("theta_m", "omega_m", "theta_L", "omega_L")
SYSTEM_NAMES = ("motor.theta_m", "motor.omega_m", "load.theta_L", "load.omega_L")
#: label -> (effects switched on, the torque): a step and a 2 Hz sine; and a random staircase (a new level every
#: 22 ms, +-800 N m), whose steps ring the shaft's resonance at every one of them
CASES = {"linear": ({}, "sine"),
         "friction, cogging, gravity": ({"Fc": 20.0, "Tcog": 5.0, "ncog": 12.0, "mgl": 200.0}, "sine"),
         "linear, a random torque staircase": ({}, "staircase")}
WHERE = {"Fc": "motor", "Tcog": "motor", "ncog": "motor", "mgl": "load"}


def torque(t: np.ndarray, kind: str = "sine") -> np.ndarray:
    if kind == "staircase":
        return np.random.default_rng(0).uniform(-800.0, 800.0, 60)[(t / (50 / 2257)).astype(int)]
    return 200.0 * np.sin(2 * np.pi * 2.0 * t) + 100.0 * (t >= 0.1)


def one_fmu(dt: float, effects: dict, kind: str) -> np.ndarray:
    from cosim import FmuPlant, build_fmu

    n = int(round(DURATION / dt))
    t = dt * np.arange(n)
    with FmuPlant(build_fmu(), dt=dt, parameters=effects, outputs=list(STATES)) as plant:
        return np.vstack([plant.read_outputs(), plant.run(np.c_[torque(t, kind), np.zeros(n)])])


def split(dt: float, effects: dict, kind: str, **master) -> tuple[np.ndarray, float, str]:
    from cosim.plant.build import build_ssp
    from cosim.plant.system_plant import SystemPlant

    n = int(round(DURATION / dt))
    t = dt * np.arange(n)
    parameters = {f"{WHERE[k]}.{k}": v for k, v in effects.items()}
    with SystemPlant(build_ssp(), dt=dt, parameters=parameters, outputs=list(SYSTEM_NAMES), **master) as plant:
        first = plant.read_outputs()
        start = time.perf_counter()
        y = plant.run(np.c_[torque(t, kind), np.zeros(n)])
        return np.vstack([first, y]), (time.perf_counter() - start) / n, plant.engine


def errors(y: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per state, the largest difference over the run over the reference's range."""
    return np.max(np.abs(y - reference), axis=0) / np.ptp(reference, axis=0)


def measure() -> dict:
    result = {"steps": list(STEPS), "study_dt": STUDY_DT, "duration": DURATION, "cases": {}}
    for label, (effects, kind) in CASES.items():
        references = {dt: one_fmu(dt, effects, kind) for dt in (*STEPS, STUDY_DT)}
        rows = []
        for algorithm in ("jacobi", "gauss-seidel"):
            for order in (0, 1, 2):
                errs, costs = [], []
                for dt in STEPS:
                    y, cost, engine = split(dt, effects, kind, algorithm=algorithm, extrapolation=order)
                    errs.append(float(np.max(errors(y, references[dt]))))
                    costs.append(cost)
                rows.append({"algorithm": algorithm, "extrapolation": order, "errors": errs,
                             "orders": [float(np.log2(a / b)) for a, b in zip(errs, errs[1:], strict=False)],
                             "step_us": 1e6 * float(np.median(costs)), "engine": engine})
        y, _, engine = split(STUDY_DT, effects, kind)
        e = errors(y, references[STUDY_DT])
        result["cases"][label] = {"effects": effects, "rows": rows,
                                  "default_at_study_dt": dict(zip(STATES, map(float, e), strict=True))}
    return result


def markdown(result: dict, commit: str) -> str:
    lines = ["# The system master's accuracy: the split servo against the one-FMU servo", "",
             f"`python benchmarks/bench_coupling.py` at {commit}, {platform.machine()}, {time.strftime('%Y-%m-%d')}. "
             f"Both driven {result['duration']:g} s by the same held torque (a step and a 2 Hz sine, or a random "
             "staircase); error: the "
             "largest difference over the run, over the one-FMU servo's range, the worst of the four states. Order: "
             "log2 of the ratio of successive errors (the step halves).", ""]
    for label, case in result["cases"].items():
        lines += [f"## {label}" + (f" ({', '.join(f'{k}={v:g}' for k, v in case['effects'].items())})"
                                   if case["effects"] else ""), "",
                  "| master | " + " | ".join(f"dt = 1/{round(1 / dt)}" for dt in result["steps"])
                  + " | orders | step (µs) |", "| --- " * (len(result["steps"]) + 3) + "|"]
        for r in case["rows"]:
            lines.append(f"| {r['algorithm']}, extrapolation {r['extrapolation']} | "
                         + " | ".join(f"{e:.2e}" for e in r["errors"])
                         + f" | {', '.join(f'{o:.2f}' for o in r['orders'])} | {r['step_us']:.2f} ({r['engine']}) |")
        d = case["default_at_study_dt"]
        lines += ["", f"Default master (Gauss-Seidel, extrapolation 1) at dt = 1/{round(1 / result['study_dt'])}: "
                  f"motor speed {d['omega_m']:.1e}, load speed {d['omega_L']:.1e} of their ranges "
                  f"(angles {d['theta_m']:.1e}, {d['theta_L']:.1e}); the issue asks 1e-3.", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = parser.parse_args()
    from cosim.files import write_text_atomic

    result = measure()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip() or "unknown"
    out = Path(args.out)
    write_text_atomic(out / "coupling.json", json.dumps({**result, "commit": commit}, indent=1))
    text = markdown(result, commit)
    write_text_atomic(out / "coupling.md", text)
    print(text)


if __name__ == "__main__":
    main()
