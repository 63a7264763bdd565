"""Would the generalisation benchmark's bins change if an effect's visibility were rated with the initial state
fitted, as ``cosim diagnose`` fits it? (docs/issue39_selection.md, "Three misses looked at closely")

The generator rates an effect (records 0-199) by its contribution over the noise in the calibration's runs
with and without it (closed loop: the same reference), from the true initial state, times the share of its
force no linear model takes up. This script rates it instead by its open-loop contribution under the command
as written, less the part the effect-free plant's free responses to its initial state take up (least squares,
every written signal over its noise), times the same share; offsets and delays by the contribution alone, as
the benchmark does. It then counts, against a result file of ``bench_diagnosis_generalization.py``, the
records at >= 2x named right first or in a set under both ratings.

    python benchmarks/bench_visibility_x0.py --result benchmarks/results/diagnosis_generalization.json \
        --data /tmp/cosim-diagnosis-records

Writes ``results/visibility_x0.json`` (per record and effect: both ratings) and ``.md`` (the counts).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _generalization_scoring as scoring  # noqa: E402
import bench_diagnosis_generalization as bench  # noqa: E402
import independent_plants as ip  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: Relative size of the initial-state perturbations (of each state's range) whose runs give the free responses.
PERTURBATION = 1e-3


def contributions(folder: Path) -> tuple[dict, dict[str, tuple[float, float]]]:
    """The record's spec and, per effect, its open-loop contribution over the noise (RMS per written signal,
    averaged in square) without and with the initial state fitted."""
    truth = json.loads((folder / "truth.json").read_text())
    spec = truth["spec"]
    plant = ip.Plant(spec["plant"]["kind"], {k: v for k, v in spec["plant"].items() if k != "kind"})
    data = np.genfromtxt(folder / "train.csv", delimiter=",", names=True)
    u = np.asarray(data[plant.input], dtype=float)
    n, dt = len(u) - 1, spec["dt"]
    written = [s for s in plant.states if s in spec["sigma"]]
    idx = [plant.states.index(s) for s in written]
    sigma = np.array([spec["sigma"][s] for s in written])
    base, _ = ip.simulate(plant, [], dt, n, u=u[:n])
    step = np.maximum(np.ptp(base, axis=0), 1e-9) * PERTURBATION
    responses = []
    for i in range(len(plant.states)):
        x0 = base[0].copy()
        x0[i] += step[i]
        moved, _ = ip.simulate(plant, [], dt, n, u=u[:n], x0=x0)
        responses.append(((moved - base)[:, idx] / sigma).ravel())
    free = np.column_stack(responses)
    out = {}
    for e in spec["effects"]:
        effect = {k: v for k, v in e.items() if k not in ("main", "main_value", "ratio")}
        run, _ = ip.simulate(plant, [effect], dt, n, u=u[:n])
        d = (run - base)[:, idx] / sigma
        left = d.ravel() - free @ np.linalg.lstsq(free, d.ravel(), rcond=None)[0]
        out[e["name"]] = (float(np.sqrt(np.mean(d ** 2))), float(np.sqrt(np.mean(left ** 2))))
    return spec, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--result", type=Path, default=RESULTS / "diagnosis_generalization.json")
    ap.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "cosim-diagnosis-records")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    result = json.loads(args.result.read_text())
    rows = [r for r in result["rows"] if r["index"] < 200]
    table, counts = {}, {"generator": [0, 0], "x0_fitted": [0, 0]}
    for r in rows:
        spec, contrib = contributions(bench.prepare(r["index"], args.data, result["max_samples"]))
        visibility = r["record"].get("visibility") or {}
        effects = {}
        for e in spec["effects"]:
            full, fitted = contrib[e["name"]]
            share = visibility.get(e["name"], 0.0) / e["ratio"] if e["ratio"] else 0.0
            effects[e["name"]] = {"generator": visibility.get(e["name"], 0.0), "open_loop": full,
                                  "x0_fitted": fitted if e["name"] in scoring.PLAIN else fitted * share}
        right = bool(r["a"].get("right_first") or r["a"].get("right_ambiguous"))
        for rating in counts:
            if effects and max(v[rating] for v in effects.values()) >= 2.0:
                counts[rating][0] += 1
                counts[rating][1] += right
        table[r["index"]] = {"effects": effects, "right": right, "excitation": r["record"]["excitation"]}
    args.out.mkdir(parents=True, exist_ok=True)
    lines = ["# Visibility with the initial state fitted", "",
             f"Records 0..199 of `{args.result.name}` (cosim {result.get('cosim')}); the records in `{args.data}`.",
             "", "| rating | records >= 2x | right first or in a set | % |", "| --- | --- | --- | --- |"]
    lines += [f"| {k} | {n} | {ok} | {100.0 * ok / max(n, 1):.1f} |" for k, (n, ok) in counts.items()]
    for suffix, text in ((".json", json.dumps({"counts": counts, "records": table}, indent=1)),
                         (".md", "\n".join(lines) + "\n")):
        tmp = (args.out / "visibility_x0").with_suffix(suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace((args.out / "visibility_x0").with_suffix(suffix))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
