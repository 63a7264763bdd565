"""Is `cosim diagnose`'s answer the same on every machine? (issue 39, item 1)

The default command line (path (a) of ``bench_diagnosis_generalization.py``: ``cosim diagnose DATA --state S
--input U [--derive POS] --json``) runs on the EMPS record (the README's line) and on benchmark records of
``benchmarks/independent_plants.py``, once per configuration, as subprocesses:

* the BLAS kernels the numpy wheel's OpenBLAS can pick (``OPENBLAS_CORETYPE`` = Haswell, SkylakeX,
  Sandybridge), with one BLAS thread and with two (``OPENBLAS_NUM_THREADS`` = ``OMP_NUM_THREADS``);
* the data perturbed by 1e-12 relative (every number of the data files but the time column's times
  ``1 + 1e-12 z``, z standard normal, seed fixed), under the first kernel.

A record is **reproducible** when every configuration names the same effects, in the same order, on the same
attachments, with every parameter within 1e-6 relative of the first configuration's (the issue's tolerance).
The table gives, per record, the configurations that agree with the first one, the answers seen, and the
largest relative parameter difference among configurations that name the same effects.

Results go to benchmarks/results/reproducibility.json and .md.

Run:  python benchmarks/bench_reproducibility.py [--slice 0:20] [--max-samples 4000] [--no-emps]
      [--configs Haswell/1,SkylakeX/2,...] [--cosim PATH]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_diagnosis_generalization import RESULTS, _write, commands, prepare  # noqa: E402

#: The EMPS record (``$COSIM_EMPS_DIR``, else ``../shared/data/emps`` beside the repository, as the tests read it).
EMPS = Path(os.environ.get("COSIM_EMPS_DIR") or Path(__file__).resolve().parents[2] / "shared" / "data" / "emps") \
    / "DATA_EMPS.mat"
EMPS_ARGS = ["--state", "qm,qm_dot", "--derive", "qm", "--input", "force=35.15*vir", "--json"]
KERNELS = ("Haswell", "SkylakeX", "Sandybridge")
#: Kernel/threads configurations, then the perturbed data under the first.
CONFIGS = tuple(f"{k}/{t}" for k in KERNELS for t in (1, 2)) + (f"{KERNELS[0]}/1+1e-12",)
PERTURBATION = 1e-12
#: Columns left as they are (the time: its step is the record's, not a measured value).
TIME_NAMES = ("t", "time")
#: Parameters of two runs agree within this (relative; the issue's tolerance).
RTOL = 1e-6


def _env(config: str) -> dict[str, str]:
    kernel, _, rest = config.partition("/")
    threads = rest.partition("+")[0]
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads,
           "MPLBACKEND": "Agg"}
    env.pop("OPENBLAS_VERBOSE", None)
    return env


def perturbed_copy(path: Path, out: Path, seed: int = 0) -> Path:
    """`path` (CSV or .mat) with every number but the time's times ``1 + 1e-12 z``, written to `out`."""
    rng = np.random.default_rng(seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".mat":
        from scipy.io import loadmat, savemat

        data = {k: v for k, v in loadmat(path).items() if not k.startswith("__")}
        for k, v in data.items():
            if isinstance(v, np.ndarray) and v.dtype.kind == "f" and k not in TIME_NAMES:
                data[k] = v * (1.0 + PERTURBATION * rng.standard_normal(v.shape))
        savemat(out, data)
        return out
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    values = np.array(rows[1:], dtype=float)
    keep = np.array([name.strip().lower() in TIME_NAMES for name in rows[0]])
    values = np.where(keep, values, values * (1.0 + PERTURBATION * rng.standard_normal(values.shape)))
    with out.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(rows[0])
        writer.writerows([[repr(float(x)) for x in row] for row in values])
    return out


def _answer(stdout: str) -> list[dict[str, Any]]:
    payload = json.loads(stdout)
    return [{"name": e["name"], "attached_to": e.get("attached_to"),
             "parameters": {k: float(v) for k, v in e.get("parameters", {}).items()}}
            for e in payload.get("effects", [])]


def run_case(argv: list[str], files: list[str], config: str, scratch: Path, timeout: float) -> dict[str, Any]:
    """One diagnosis (`argv`, whose data files are `files`) under `config`; data perturbed for a ``+`` config."""
    if "+" in config:
        swap = {f: str(perturbed_copy(Path(f), scratch / f"perturbed_{i}{Path(f).suffix}"))
                for i, f in enumerate(files)}
        argv = [swap.get(a, a) for a in argv]
    start = time.perf_counter()
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=_env(config))
    except subprocess.TimeoutExpired:
        return {"config": config, "error": f"timed out after {timeout:.0f} s"}
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        return {"config": config, "error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
    return {"config": config, "effects": _answer(proc.stdout), "seconds": seconds}


def _without_output(argv: list[str]) -> list[str]:
    """`argv` less its ``-o PATH`` (the runs only read the JSON on stdout)."""
    if "-o" not in argv:
        return argv
    at = argv.index("-o")
    return argv[:at] + argv[at + 2:]


def _key(effects: list[dict[str, Any]]) -> tuple:
    return tuple((e["name"], e["attached_to"]) for e in effects)


def _max_rel(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> float:
    worst = 0.0
    for ea, eb in zip(a, b, strict=True):
        for k, va in ea["parameters"].items():
            vb = eb["parameters"].get(k, float("nan"))
            worst = max(worst, abs(va - vb) / max(abs(va), abs(vb), 1e-300))
    return worst


def compare(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Whether `runs` (the first the reference) agree: same effects, order and attachments, parameters within
    :data:`RTOL`."""
    ok = [r for r in runs if "effects" in r]
    ref = runs[0]
    answers: dict[str, list[str]] = {}
    for r in runs:
        label = "error: " + r["error"] if "error" in r else \
            (" + ".join(f"{e['name']}@{e['attached_to']}" for e in r["effects"]) or "no effect")
        answers.setdefault(label, []).append(r["config"])
    same_key = [r for r in ok if "effects" in ref and _key(r["effects"]) == _key(ref["effects"])]
    spreads = [_max_rel(ref["effects"], r["effects"]) for r in same_key]
    agree = [r["config"] for r, s in zip(same_key, spreads, strict=True) if s <= RTOL]
    return {"identical": len(agree) == len(runs), "agree": agree, "answers": answers,
            "max_rel_param_diff": max(spreads) if spreads else None,
            "median_seconds": float(np.median([r["seconds"] for r in ok])) if ok else None}


def cases(indices: list[int], data_dir: Path, max_samples: int | None, cosim: str,
          emps: bool) -> list[tuple[str, list[str], list[str]]]:
    """(label, argv, data files) of every case."""
    out = []
    if emps:
        if not EMPS.is_file():
            raise SystemExit(f"{EMPS} not found: set COSIM_EMPS_DIR to the folder with DATA_EMPS.mat, or --no-emps")
        out.append(("EMPS", [cosim, "diagnose", str(EMPS), *EMPS_ARGS], [str(EMPS)]))
    for index in indices:
        folder = prepare(index, data_dir, max_samples)
        cli = json.loads((folder / "truth.json").read_text())["cli"]
        argv = _without_output(commands(folder, cli, cosim)["a"][0])
        out.append((f"record {index}", argv, [str(folder / f) for f in cli.get("data", ["train.csv"])]))
    return out


def markdown(result: dict[str, Any]) -> str:
    rows = result["rows"]
    n_ok = sum(r["identical"] for r in rows)
    lines = [
        "# Reproducibility of `cosim diagnose`'s default path (issue 39, item 1)", "",
        f"Commit {result['commit']}, {result['machine']}, {result['date']}. Configurations: "
        + ", ".join(f"`{c}`" for c in result["configs"])
        + f" (kernel/BLAS threads; `+1e-12`: the data perturbed by 1e-12 relative). Records "
        f"{result['records']}, at most {result['max_samples'] or 'all'} samples. Same answer: the same effects, "
        f"order and attachments, every parameter within {RTOL:g} relative of the first configuration's.", "",
        f"**{n_ok} of {len(rows)} cases give the same answer under every configuration.**", "",
        "| case | same answer | configs agreeing | largest parameter difference | answers (configs) | median s |",
        "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        spread = "-" if r["max_rel_param_diff"] is None else f"{r['max_rel_param_diff']:.2g}"
        answers = "<br>".join(f"{a} ({', '.join(c)})" for a, c in r["answers"].items())
        secs = "-" if r["median_seconds"] is None else f"{r['median_seconds']:.1f}"
        lines.append(f"| {r['case']} | {'yes' if r['identical'] else 'no'} | {len(r['agree'])}/{len(result['configs'])}"
                     f" | {spread} | {answers} | {secs} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice", default="0:20", help="benchmark records 'A:B' or 'i,j,k' ('' for none)")
    parser.add_argument("--max-samples", type=int, default=4000, help="shorten the records (default 4000)")
    parser.add_argument("--no-emps", action="store_true", help="leave the EMPS case out")
    parser.add_argument("--configs", default=",".join(CONFIGS))
    parser.add_argument("--timeout", type=float, default=600.0)
    parser.add_argument("--data", default=None, help="record folder (default $TMPDIR/cosim-diagnosis-records)")
    parser.add_argument("--out", default=str(RESULTS / "reproducibility"))
    parser.add_argument("--cosim", default=shutil.which("cosim", path=str(Path(sys.executable).parent)) or "cosim")
    args = parser.parse_args()
    if args.slice:
        a, sep, b = args.slice.partition(":")
        indices = list(range(int(a), int(b))) if sep else [int(i) for i in args.slice.split(",")]
    else:
        indices = []
    data = Path(args.data) if args.data else Path(os.environ.get("TMPDIR", "/tmp")) / "cosim-diagnosis-records"
    configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    scratch = data / "perturbed"
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip()
    rows = []
    for label, argv, files in cases(indices, data, args.max_samples, args.cosim, not args.no_emps):
        runs = [run_case(argv, files, c, scratch, args.timeout) for c in configs]
        row = {"case": label, **compare(runs), "runs": runs}
        rows.append(row)
        print(f"{label}: {'same' if row['identical'] else 'DIFFERENT'} {row['answers']}", flush=True)
        _write({"commit": commit, "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                "date": time.strftime("%Y-%m-%d"), "configs": configs, "records": args.slice or "none",
                "max_samples": args.max_samples, "rows": rows}, Path(args.out), markdown)  # partial kept
    print(markdown({"commit": "", "machine": "", "date": "", "configs": configs, "records": args.slice,
                    "max_samples": args.max_samples, "rows": rows}))


if __name__ == "__main__":
    main()
