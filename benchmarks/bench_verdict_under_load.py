"""The same ``cosim validate`` command, run several times while other processes load every core: the verdicts
must be identical (issue 14: default specs judge the loop, not the machine).

The controller is a PID designed the README tour's way (simulate the bundled FMU, identify, ``design pid``);
``cosim validate bundled pid.json`` then runs with its default specs, alone once and ``--runs`` times beside
``--load`` busy-looping processes (default: one per core). The figures written: each run's verdict, its checks'
values (which must be equal: the loop is deterministic) and its compute-time median and p99 (which may differ:
they are measured, and reported, not judged).

Results: benchmarks/results/verdict_under_load.json and .md.

Run:  python benchmarks/bench_verdict_under_load.py [--runs 5] [--load 2]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _busy(stop: multiprocessing.Event) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF


def _cosim(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], cwd=cwd, capture_output=True, text=True,
                          check=False, timeout=600)


def _validate(folder: Path) -> dict:
    result = _cosim("validate", "bundled", "pid.json", "--json", cwd=folder)
    if result.returncode not in (0, 1):
        raise SystemExit(f"bench_verdict_under_load: validate failed: {result.stderr.strip()}")
    payload = json.loads(result.stdout)
    return {"exit": result.returncode, "passed": payload["passed"],
            "checks": [(c["spec"], c["value"], c["passed"]) for c in payload["checks"]],
            "solve_time_us": payload.get("solve_time_us", {})}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--load", type=int, default=os.cpu_count() or 2, help="Busy processes beside the runs.")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for step in (("simulate", "bundled", "--input", "Tm=square:amp=500,freq=2", "--duration", "4", "--dt",
                      "1/2257", "--set", "Fc=0.3", "--noise", "0.1", "--seed", "0", "-o", "data.csv"),
                     ("identify", "data.csv", "--state", "theta_m,omega_m,theta_L,omega_L", "--input", "Tm",
                      "-o", "model.json"),
                     ("design", "pid", "model.json", "--input", "Tm", "--tracked", "theta_L", "--velocity",
                      "omega_m", "--u-max", "5000", "-o", "pid.json")):
            done = _cosim(*step, cwd=folder)
            if done.returncode:
                raise SystemExit(f"bench_verdict_under_load: {step[0]} failed: {done.stderr.strip()}")
        alone = _validate(folder)
        stop = multiprocessing.Event()
        workers = [multiprocessing.Process(target=_busy, args=(stop,), daemon=True) for _ in range(args.load)]
        for w in workers:
            w.start()
        try:
            loaded = [_validate(folder) for _ in range(args.runs)]
        finally:
            stop.set()
            for w in workers:
                w.join(timeout=5)
    identical = all(run["exit"] == alone["exit"] and run["checks"] == alone["checks"] for run in loaded)
    summary = {"machine": platform.platform(), "cores": os.cpu_count(), "load_processes": args.load,
               "runs": args.runs, "alone": alone, "loaded": loaded, "identical_verdicts": identical}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "verdict_under_load.json").write_text(json.dumps(summary, indent=1) + "\n")
    rows = []
    for i, run in enumerate([alone, *loaded]):
        times = run["solve_time_us"]
        rows.append(f"| {'alone' if i == 0 else f'loaded {i}'} | {run['exit']} | {run['passed']} | "
                    f"{times.get('median', float('nan')):.2f} | {times.get('p99', float('nan')):.2f} |")
    (args.out / "verdict_under_load.md").write_text(
        "# The same `cosim validate` under load\n\n"
        f"`cosim validate bundled pid.json --json` (default specs), alone then {args.runs} times beside "
        f"{args.load} busy-looping processes on {os.cpu_count()} cores ({platform.platform()}).\n\n"
        "| run | exit | passed | compute median [µs] | compute p99 [µs] |\n| --- | --- | --- | --- | --- |\n"
        + "\n".join(rows) + f"\n\nIdentical verdicts and check values: **{identical}**.\n")
    print(f"identical verdicts: {identical}; exits {[alone['exit']] + [r['exit'] for r in loaded]}")
    return summary


if __name__ == "__main__":
    main()
