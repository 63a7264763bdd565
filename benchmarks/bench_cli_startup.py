"""Start-up time of the command line and of ``import cosim``, beside Python's own and FMPy's command line.

Every CLI call and every sweep worker pays the start-up. Each command runs as a fresh process, in interleaved
rounds so that machine noise hits all alike; the figures (median wall time over rounds, and each as a ratio
to ``python -c pass`` and to ``fmpy --help``) go to benchmarks/results/cli_startup.json and .md.

Run:  python benchmarks/bench_cli_startup.py [--rounds 15] [--compare OTHER_VENV/bin/python]

``--compare`` adds the cosim commands of another environment (an older cosim, say) to the same interleaved
rounds, labelled "(compare)": before and after, measured side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from cosim import build_fmu
from cosim.files import write_text_atomic


def cosim_commands(python: str, suffix: str = "") -> dict[str, list[str]]:
    """The cosim command lines of the environment of interpreter `python`, by label."""
    cosim = shutil.which("cosim", path=str(Path(python).parent)) or "cosim"
    return {
        f"python -c 'import cosim'{suffix}": [python, "-c", "import cosim"],
        f"cosim --help{suffix}": [cosim, "--help"],
        f"cosim fmu info bundled{suffix}": [cosim, "fmu", "info", "bundled"],
    }


def commands(compare: str | None = None) -> dict[str, list[str]]:
    """The command lines measured, by label: Python's floor, FMPy's CLI, this environment's cosim and, with
    `compare`, another environment's."""
    fmpy = shutil.which("fmpy", path=str(Path(sys.executable).parent)) or "fmpy"
    runs = {"python -c pass": [sys.executable, "-c", "pass"], "fmpy --help": [fmpy, "--help"],
            **cosim_commands(sys.executable)}
    if compare:
        runs.update(cosim_commands(compare, " (compare)"))
    return runs


def wall_time(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=os.environ)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--compare", default=None, help="another environment's python, measured alongside")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "cli_startup"))
    args = parser.parse_args()
    build_fmu()  # `fmu info bundled` measures the lookup of the cached FMU, not its first build
    runs = commands(args.compare)
    for argv in runs.values():  # warm-up: page cache, .pyc files
        wall_time(argv)
    times: dict[str, list[float]] = {label: [] for label in runs}
    for _ in range(args.rounds):
        for label, argv in runs.items():
            times[label].append(wall_time(argv))
    median = {label: statistics.median(values) for label, values in times.items()}
    floor, fmpy = median["python -c pass"], median["fmpy --help"]
    result = {
        "benchmark": "wall time of a fresh process, median over interleaved rounds",
        "rounds": args.rounds,
        "compare": args.compare,
        "median_s": median,
        "ratio_to_python": {label: value / floor for label, value in median.items()},
        "ratio_to_fmpy_help": {label: value / fmpy for label, value in median.items()},
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
    }
    out = Path(args.out)
    write_text_atomic(out.with_suffix(".json"), json.dumps(result, indent=2) + "\n")
    table = "| command | median s | x python -c pass | x fmpy --help |\n| --- | --- | --- | --- |\n"
    for label, value in median.items():
        table += (f"| `{label}` | {value:.3f} | {result['ratio_to_python'][label]:.2f} | "
                  f"{result['ratio_to_fmpy_help'][label]:.2f} |\n")
    table += f"\n{args.rounds} interleaved rounds, Python {result['python']}, {result['cpus']} CPUs."
    table += f" (compare): the environment of {args.compare}.\n" if args.compare else "\n"
    write_text_atomic(out.with_suffix(".md"), table)
    print(table)


if __name__ == "__main__":
    main()
