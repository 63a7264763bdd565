"""Wall time of `cosim reproduce paper` on this machine with local processes (and its results).

Runs the full reproduction (both excitations, six noise levels, --seeds seeds) through the sweep engine with
--workers local processes and writes the wall time, the per-case fit time and the Table 1 analogue to
benchmarks/results/reproduce_paper.json and .md.

Run:  python benchmarks/bench_reproduce.py [--seeds 3] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
from pathlib import Path

from cosim.files import write_text_atomic
from cosim.study.paper import STATES
from cosim.study.reproduce import reproduce_paper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "reproduce_paper"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        result = reproduce_paper(seeds=args.seeds, workers=args.workers, out_dir=folder, progress=True)
    s = result.summary
    fit_times = [r["fit_seconds"] for r in result.sweep.results if r]
    figures = {"cases": len(result.sweep.cases), "workers": args.workers, "cores": os.cpu_count(),
               "wall_s": s["wall_s"], "failed_cases": s["failed_cases"],
               "fit_seconds_median": statistics.median(fit_times), "fit_seconds_max": max(fit_times),
               "summary": s}
    out = Path(args.out)
    write_text_atomic(out.with_suffix(".json"), json.dumps(figures, indent=1) + "\n")
    lines = [f"`cosim reproduce paper --seeds {args.seeds}`: {figures['cases']} cases on {args.workers} local "
             f"processes ({os.cpu_count()} cores): wall {s['wall_s']:.0f} s; fit per case median "
             f"{figures['fit_seconds_median']:.1f} s, max {figures['fit_seconds_max']:.1f} s; "
             f"failed cases {s['failed_cases']}.", "",
             "| noise | " + " | ".join(f"{st} cosim | {st} study" for st in STATES) + " |",
             "| --- |" + " --- |" * (2 * len(STATES))]
    for i, level in enumerate(s["noise_levels"]):
        cells = [f"{s['max_dev_pct'][st][i]:.4g} | {s['study_max_dev_pct'][st][i]}" for st in STATES]
        lines.append(f"| {level:.0%} | " + " | ".join(cells) + " |")
    lines += ["", "R² (worse excitation, mean over seeds):", "",
              "| noise | " + " | ".join(STATES) + " |", "| --- |" + " --- |" * len(STATES)]
    for i, level in enumerate(s["noise_levels"]):
        lines.append(f"| {level:.0%} | " + " | ".join(f"{s['r2'][st][i]:.6f}" for st in STATES) + " |")
    write_text_atomic(out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
