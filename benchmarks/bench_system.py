"""What does a system of FMUs cost a step? The split servo run by cosim's master against its two FMUs' own steps,
and against FMPy's SSP simulation of the same file.

1. ``SystemPlant.run`` on the split servo (fmus/two_mass_servo_split: a motor FMU and a shaft-and-load FMU, the
   default master: Gauss-Seidel, linear extrapolation, its compiled loop), per step, over the sum of the two FMUs'
   own steps: each FMU alone in a ``FmuPlant`` stepped by ``FmuPlant.run`` with its inputs held (the issue asks
   at most 1.3). The same with ``engine="python"`` (the master's loop in Python) for scale.
2. ``fmpy.ssp.simulation.simulate_ssp`` on the same ``.ssp`` file, the same step and length, over
   ``cosim.simulate`` of it (the issue asks at least 3): both whole runs, files read and FMUs instantiated
   included. FMPy's reader stops at an input connector nothing drives (``UnboundLocalError`` in
   ``fmpy.ssp.ssd.get_connections``), so both run a copy of the file whose SSD leaves the free inputs (motor.Tm,
   load.TL) out of the components' connectors; cosim takes its free inputs from the FMUs, so it reads the copy as
   the original.

Rounds are interleaved and the medians kept, since this machine's speed moves from one minute to the next; the
figures are ratios measured side by side.

Run:  python benchmarks/bench_system.py [--steps 20000] [--rounds 5] [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

DT = 1 / 2257


def per_step_system(ssp: Path, steps: int, engine: str) -> float:
    from cosim.plant.system_plant import SystemPlant

    u = np.c_[np.full(steps, 100.0), np.zeros(steps)]
    with SystemPlant(ssp, dt=DT, engine=engine) as plant:
        start = time.perf_counter()
        plant.run(u)
        return (time.perf_counter() - start) / steps


def per_step_component(fmu: Path, inputs: list[float], steps: int) -> float:
    from cosim import FmuPlant

    with FmuPlant(fmu, dt=DT) as plant:
        u = np.tile(np.asarray(inputs, dtype=float)[: len(plant.inputs)], (steps, 1))
        start = time.perf_counter()
        plant.run(u)
        return (time.perf_counter() - start) / steps


def fmpy_readable(ssp: Path, folder: Path) -> Path:
    """A copy of `ssp` without the free inputs' connectors (see the module's docstring)."""
    import re
    import zipfile

    target = folder / ssp.name
    with zipfile.ZipFile(ssp) as src, zipfile.ZipFile(target, "w") as dst:
        for info in src.infolist():
            data = src.read(info.filename)
            if info.filename == "SystemStructure.ssd":
                data = re.sub(rb'\s*<ssd:Connector name="(Tm|TL)" kind="input">.*?</ssd:Connector>', b"", data)
            dst.writestr(info, data)
    return target


def whole_run_fmpy(ssp: Path, duration: float) -> float:
    from fmpy.ssp.simulation import simulate_ssp

    start = time.perf_counter()
    simulate_ssp(str(ssp), stop_time=duration, step_size=DT)
    return time.perf_counter() - start


def whole_run_cosim(ssp: Path, duration: float) -> float:
    from cosim import simulate

    start = time.perf_counter()
    simulate(ssp, {}, duration=duration, dt=DT)
    return time.perf_counter() - start


def measure(steps: int, rounds: int) -> dict:
    import tempfile

    from cosim.plant.build import build_ssp
    from cosim.plant.system_structure import read_system

    ssp = build_ssp()
    comps = read_system(ssp).components
    folder = Path(tempfile.mkdtemp())
    readable = fmpy_readable(ssp, folder)
    rows: dict[str, list[float]] = {k: [] for k in ("system_c", "system_python", "motor", "load", "fmpy_ssp",
                                                    "cosim_ssp")}
    duration = steps * DT
    for _ in range(rounds):
        rows["system_c"].append(per_step_system(ssp, steps, "c"))
        rows["motor"].append(per_step_component(comps["motor"].source, [100.0, 0.0], steps))
        rows["load"].append(per_step_component(comps["load"].source, [0.0, 0.0, 0.0], steps))
        rows["system_python"].append(per_step_system(ssp, max(steps // 10, 100), "python"))
        rows["fmpy_ssp"].append(whole_run_fmpy(readable, duration))
        rows["cosim_ssp"].append(whole_run_cosim(readable, duration))
    med = {k: float(np.median(v)) for k, v in rows.items()}
    own = med["motor"] + med["load"]
    return {"steps": steps, "rounds": rounds, "dt": DT, "median": med, "rounds_raw": rows,
            "ratio_system_over_own": med["system_c"] / own,
            "ratio_python_master_over_own": med["system_python"] / own,
            "ratio_fmpy_ssp_over_cosim": med["fmpy_ssp"] / med["cosim_ssp"]}


def markdown(r: dict, commit: str) -> str:
    m = r["median"]
    return "\n".join([
        "# A system of FMUs: cost of a step", "",
        f"`python benchmarks/bench_system.py --steps {r['steps']} --rounds {r['rounds']}` at {commit}, "
        f"{platform.machine()}, {time.strftime('%Y-%m-%d')}. The split servo (fmus/two_mass_servo_split), dt = "
        f"1/{round(1 / r['dt'])} s; medians of {r['rounds']} interleaved rounds.", "",
        "| loop | µs per step |", "| --- | --- |",
        f"| `SystemPlant.run`, the compiled master | {1e6 * m['system_c']:.2f} |",
        f"| `SystemPlant.run`, the master in Python (`engine=\"python\"`) | {1e6 * m['system_python']:.2f} |",
        f"| the motor FMU alone, `FmuPlant.run` | {1e6 * m['motor']:.2f} |",
        f"| the shaft-and-load FMU alone, `FmuPlant.run` | {1e6 * m['load']:.2f} |", "",
        f"**System step over the sum of its two FMUs' own steps: {r['ratio_system_over_own']:.2f}** (the issue asks "
        f"at most 1.3; the master in Python: {r['ratio_python_master_over_own']:.1f}).", "",
        f"Whole runs of {r['steps']} steps of the same `.ssp` file: `fmpy.ssp.simulation.simulate_ssp` "
        f"{m['fmpy_ssp']:.3f} s, `cosim.simulate` {m['cosim_ssp']:.3f} s: **FMPy over cosim "
        f"{r['ratio_fmpy_ssp_over_cosim']:.1f}** (the issue asks at least 3).", ""])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = parser.parse_args()
    from cosim.files import write_text_atomic

    result = measure(args.steps, args.rounds)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip() or "unknown"
    write_text_atomic(Path(args.out) / "system_step.json", json.dumps({**result, "commit": commit}, indent=1))
    text = markdown(result, commit)
    write_text_atomic(Path(args.out) / "system_step.md", text)
    print(text)


if __name__ == "__main__":
    main()
