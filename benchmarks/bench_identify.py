"""Identification time against record length: cosim's SINDYc beside a bare pysindy fit, in the same run.

Data: the bundled FMU from the study's X0, square wave on Tm, sampled at 2257 Hz, 5 % noise; 1e4, 1e5 and
1e6 samples. Timed: `SINDYc(refine=None)` (equation error, the integral formulation, BIC threshold path),
`SINDYc(refine="output_error")` (only up to --refine-max samples: it simulates the model many times), and
pysindy's `SINDy` with a degree-1 polynomial library, STLSQ and finite differences (the study's method as
pysindy does it out of the box). Each timing is the best of --repeat runs. Figures go to
benchmarks/results/identify_time.json and .md.

Run:  python benchmarks/bench_identify.py [--sizes 10000,100000,1000000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
import warnings
from pathlib import Path

import numpy as np
import pysindy as ps

from cosim import SINDYc, build_fmu, simulate
from cosim.files import write_text_atomic
from cosim.study.paper import STATES, STUDY_DT, STUDY_X0


def best_of(repeat: int, func) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def time_one_size(fmu: Path, n: int, repeat: int, refine_max: int) -> dict:
    traj = simulate(fmu, {"Tm": "square:amp=500,freq=1"}, duration=n * STUDY_DT, dt=STUDY_DT,
                    start=STUDY_X0).with_noise(0.05, seed=0)
    x, u = traj[list(STATES)], traj[["Tm"]]

    def bare() -> None:
        model = ps.SINDy(feature_library=ps.PolynomialLibrary(degree=1), optimizer=ps.STLSQ(threshold=1e-3),
                         differentiation_method=ps.FiniteDifference())
        model.fit(x, t=STUDY_DT, u=u)

    def cosim_fit(refine: str | None) -> None:
        SINDYc(refine=refine).fit(traj, states=list(STATES), inputs=["Tm"])

    row = {"samples": n, "pysindy_s": best_of(repeat, bare)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        row["cosim_equation_error_s"] = best_of(repeat, lambda: cosim_fit(None))
        if n <= refine_max:
            row["cosim_output_error_s"] = best_of(1, lambda: cosim_fit("output_error"))
    row["ratio_equation_error_to_pysindy"] = row["cosim_equation_error_s"] / row["pysindy_s"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000,1000000")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--refine-max", type=int, default=100_000)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "identify_time"))
    args = parser.parse_args()
    fmu = build_fmu()
    rows = []
    for n in (int(s) for s in args.sizes.split(",")):
        rows.append(time_one_size(fmu, n, args.repeat if n <= 100_000 else 1, args.refine_max))
        print(rows[-1], flush=True)
    result = {"benchmark": "identification time, bundled FMU data, 5 % noise", "rows": rows,
              "python": platform.python_version(), "pysindy": ps.__version__ if hasattr(ps, "__version__") else "",
              "numpy": np.__version__}
    out = Path(args.out)
    write_text_atomic(out.with_suffix(".json"), json.dumps(result, indent=2) + "\n")
    lines = ["| samples | pysindy SINDy (FD, STLSQ) s | cosim SINDYc equation error s | ratio "
             "| cosim + output error s |",
             "| --- | --- | --- | --- | --- |"]
    for r in rows:
        oe = f"{r['cosim_output_error_s']:.2f}" if "cosim_output_error_s" in r else "not run"
        lines.append(f"| {r['samples']:,} | {r['pysindy_s']:.3f} | {r['cosim_equation_error_s']:.3f} | "
                     f"{r['ratio_equation_error_to_pysindy']:.2f} | {oe} |")
    write_text_atomic(out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
