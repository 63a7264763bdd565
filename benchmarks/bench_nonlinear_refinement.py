"""Output-error refinement of a nonlinear model: exact sensitivities (CasADi) beside forward differences.

Data: a two-mass drive with a cogging torque on the load (``A sin(n theta_L + phase)``) and Coulomb friction
on the motor, simulated by scipy's solve_ivp sample by sample (its own equations, the input held), 2 % noise.
The model: SINDYc's linear library plus the effects' terms, identified with ``refine="output_error"`` (the
multi-start of cosim.identify) once with ``exact_jacobian=True`` (the default) and once with forward
differences (``refine_options={"exact_jacobian": False}``), in the same run; the figures are the wall times,
their ratio and both fits' costs (they must agree). Written to benchmarks/results/nonlinear_refinement.json and .md.

Run:  python benchmarks/bench_nonlinear_refinement.py [--sizes 2000,4000,8000]
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from cosim.data.trajectory import Trajectory
from cosim.files import write_text_atomic
from cosim.identify.sindyc import SINDYc

JM, JL, K, C, BM, BL = 0.015, 0.018, 260.0, 0.19, 0.02, 0.02
COG, PERIODS, PHASE, FC = 0.08, 17.0, 1.0, 0.05
TERMS = [f"sin({PERIODS:g}*theta_L)", f"cos({PERIODS:g}*theta_L)", "tanh(omega_m/0.01)"]


def record(n: int, dt: float = 1e-3, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    t = np.arange(n + 1) * dt
    u = 0.3 * np.sign(np.sin(2 * np.pi * 0.7 * t[:-1])) + 0.2 * np.sin(2 * np.pi * 3.1 * t[:-1])

    def rhs(time_s, s, uk):
        tm, wm, tl, wl = s
        shaft = K * (tm - tl) + C * (wm - wl)
        return [wm, (uk - shaft - BM * wm - FC * np.tanh(wm / 0.01)) / JM, wl,
                (shaft - BL * wl + COG * np.sin(PERIODS * tl + PHASE)) / JL]

    x = np.empty((n + 1, 4))
    x[0] = 0.0
    for k in range(n):
        x[k + 1] = solve_ivp(rhs, (t[k], t[k + 1]), x[k], args=(u[k],), rtol=1e-9, atol=1e-12).y[:, -1]
    x += 0.02 * np.ptp(x, axis=0) * rng.normal(size=x.shape)
    names = ("theta_m", "omega_m", "theta_L", "omega_L")
    return Trajectory.from_arrays(t, {**dict(zip(names, x.T, strict=True)), "Tm": np.append(u, u[-1])},
                                  roles={**dict.fromkeys(names, "state"), "Tm": "input"})


def identify(data: Trajectory, exact: bool) -> tuple[float, float]:
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = SINDYc(threshold=0.0, kinematics="auto", refine="output_error", allow_unstable=True,
                       refine_options={"exact_jacobian": exact}, terms=TERMS).fit(
            data, states=["theta_m", "omega_m", "theta_L", "omega_L"], inputs=["Tm"])
    return time.perf_counter() - start, float(model.model_.meta["refinement"]["cost"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="2000,4000,8000")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "nonlinear_refinement"))
    args = parser.parse_args()
    rows = []
    for n in (int(s) for s in args.sizes.split(",")):
        data = record(n)
        exact_s, exact_cost = identify(data, True)
        fd_s, fd_cost = identify(data, False)
        rows.append({"samples": n, "exact_s": exact_s, "forward_differences_s": fd_s, "ratio": fd_s / exact_s,
                     "exact_cost": exact_cost, "forward_differences_cost": fd_cost})
        print(rows[-1], flush=True)
    out = Path(args.out)
    write_text_atomic(out.with_suffix(".json"), json.dumps({"benchmark": __doc__.splitlines()[0], "rows": rows},
                                                           indent=2) + "\n")
    lines = ["| samples | exact sensitivities s | forward differences s | speed-up | cost exact | cost FD |",
             "| --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {r['samples']:,} | {r['exact_s']:.1f} | {r['forward_differences_s']:.1f} | {r['ratio']:.1f} | "
              f"{r['exact_cost']:.4g} | {r['forward_differences_cost']:.4g} |" for r in rows]
    write_text_atomic(out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
