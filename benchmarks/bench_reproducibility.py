"""One answer on every machine: `cosim diagnose` under every BLAS kernel, thread count and a 1e-12 perturbation.

Runs the EMPS default path (the README's line) and benchmark records of ``independent_plants.py`` through the
CLI, once per configuration: ``OPENBLAS_CORETYPE`` Sandybridge, Haswell, SkylakeX with
``OMP_NUM_THREADS=OPENBLAS_NUM_THREADS`` 1 and 2, and the data perturbed by 1e-12 relative (seeded) under the
machine's own kernel. Compares the named effects, their order and places, and their parameters (1e-6
relative) with the first configuration's, and writes ``benchmarks/results/reproducibility.md``.

Usage::

    python benchmarks/bench_reproducibility.py                 # EMPS and records 0-19
    python benchmarks/bench_reproducibility.py --records 0:5   # fewer
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.io

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_diagnosis_generalization as bench  # noqa: E402

EMPS = HERE.parents[1] / "shared" / "data" / "emps" / "DATA_EMPS.mat"
EMPS_OPTIONS = ["--state", "qm,qm_dot", "--derive", "qm", "--input", "force=35.15*vir"]
KERNELS = ("Sandybridge", "Haswell", "SkylakeX")
THREADS = ("1", "2")
#: Parameters agree when within this relative difference.
RTOL = 1e-6


def configurations() -> list[dict[str, str]]:
    """Each run's environment changes and name; the perturbed run last."""
    out = [{"name": f"{k}, {t} thread{'s' if t != '1' else ''}", "OPENBLAS_CORETYPE": k, "OMP_NUM_THREADS": t,
            "OPENBLAS_NUM_THREADS": t} for k in KERNELS for t in THREADS]
    out.append({"name": "data perturbed 1e-12 (own kernel)", "perturb": "1"})
    return out


def _perturbed(path: Path, folder: Path) -> Path:
    """A copy of a record (CSV or .mat) with every value times (1 + 1e-12 e), e standard normal (seed 0)."""
    rng = np.random.default_rng(0)
    target = folder / path.name
    if path.suffix == ".mat":
        raw = scipy.io.loadmat(path)
        out = {k: (v * (1 + 1e-12 * rng.standard_normal(v.shape)) if isinstance(v, np.ndarray)
                   and v.dtype.kind == "f" and v.size > 1 else v) for k, v in raw.items() if not k.startswith("__")}
        scipy.io.savemat(target, out)
        return target
    import pandas as pd

    frame = pd.read_csv(path)
    for col in frame.columns[1:]:
        frame[col] = frame[col] * (1 + 1e-12 * rng.standard_normal(len(frame)))
    frame.to_csv(target, index=False, float_format="%.17g")
    return target


def run_case(data: Path, options: list[str], config: dict[str, str], work: Path) -> dict:
    """One `cosim diagnose --json` run: its effects (name, place, parameters) and seconds."""
    env = dict(os.environ, MPLBACKEND="Agg")
    env.update({k: v for k, v in config.items() if k.isupper()})
    if config.get("perturb"):
        data = _perturbed(data, work)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "cosim.cli", "diagnose", str(data), *options, "--json"],
                          capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or ["?"])[-1], "seconds": seconds}
    payload = json.loads(proc.stdout)
    return {"effects": [(e["name"], e["attached_to"], e["parameters"]) for e in payload["effects"]],
            "ambiguous": [a["effects"] for a in payload.get("ambiguous", [])], "seconds": seconds}


def same(a: dict, b: dict) -> tuple[bool, float]:
    """Whether two runs name the same effects in the same order and places, and the largest relative parameter
    difference."""
    if "error" in a or "error" in b:
        return a.get("error") == b.get("error"), 0.0
    if [e[:2] for e in a["effects"]] != [e[:2] for e in b["effects"]] or a["ambiguous"] != b["ambiguous"]:
        return False, float("inf")
    worst = 0.0
    for (_, _, pa), (_, _, pb) in zip(a["effects"], b["effects"], strict=True):
        for key, va in pa.items():
            vb = pb.get(key, float("nan"))
            worst = max(worst, abs(va - vb) / max(abs(va), abs(vb), 1e-300))
    return worst <= RTOL, worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", default="0:20", help="benchmark records, START:STOP (default 0:20)")
    parser.add_argument("--max-samples", type=int, default=bench.DEFAULT_MAX_SAMPLES)
    parser.add_argument("--data-dir", type=Path, default=Path(tempfile.gettempdir()) / "cosim_generalization")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "reproducibility.md")
    args = parser.parse_args()
    lo, hi = (int(x) for x in args.records.split(":"))
    cases = [("EMPS default path", EMPS, EMPS_OPTIONS)] if EMPS.is_file() else []
    for index in range(lo, hi):
        folder = bench.prepare(index, args.data_dir, args.max_samples)
        cli = json.loads((folder / "truth.json").read_text())["cli"]
        argv = bench.commands(folder, cli, "cosim")["a"][0]
        cases.append((f"record {index}", Path(argv[2]), [a for a in argv[3:] if a != "--json"][:-2]))
    rows, configs = [], configurations()
    with tempfile.TemporaryDirectory() as tmp:
        for name, data, options in cases:
            runs = [run_case(data, options, c, Path(tmp)) for c in configs]
            verdicts = [same(runs[0], r) for r in runs]
            rows.append({"case": name, "runs": runs, "same": [v[0] for v in verdicts],
                         "worst": max(v[1] for v in verdicts)})
            print(f"{name}: {'same' if all(v[0] for v in verdicts) else 'DIFFERENT'}", flush=True)
    lines = ["# One answer on every machine (`benchmarks/bench_reproducibility.py`)", "",
             "Configurations: " + "; ".join(c["name"] for c in configs) + ".", "",
             "| case | effects (first configuration) | identical in all | largest parameter difference | seconds |",
             "| --- | --- | --- | --- | --- |"]
    for row in rows:
        first = row["runs"][0]
        named = first.get("error") or ", ".join(f"{n} on {a}" for n, a, _ in first["effects"]) or "none"
        if first.get("ambiguous"):
            named += " (ambiguous: " + "; ".join(" or ".join(s) for s in first["ambiguous"]) + ")"
        secs = ", ".join(f"{r['seconds']:.1f}" for r in row["runs"])
        lines.append(f"| {row['case']} | {named} | {sum(row['same'])}/{len(row['same'])} | {row['worst']:.2g} | "
                     f"{secs} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = args.out.with_suffix(".tmp")
    tmp_out.write_text("\n".join(lines) + "\n")
    tmp_out.replace(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
