"""MPC call time in a closed loop against the bundled FMU: compiled DAQP, DAQP through casadi's Python API, and a
casadi Opti + IPOPT formulation of the same QP, side by side.

The problem is the reference application: the true linear two-mass model (cosim.study.two_mass_matrices) at the
study's 2257 Hz, horizon 20, |Tm| <= 5000 N m, default weights, theta_m and theta_L measured, theta_L tracked,
a 0.01 rad setpoint step at 0.05 s, Coulomb friction Fc = 100 N m on in the FMU. The three controllers share the
design (observer, target, cost, terminal Riccati cost, bounds); they differ in how the QP is solved:

* ``ours``: ``MPC(...)`` - the whole step generated as C, compiled, called through ctypes;
* ``python_daqp``: ``MPC(..., codegen=False)`` - the same casadi Function evaluated from Python on the bound
  buffers through casadi's ``Function.buffer()`` (the MPC's path when nothing can be compiled);
* ``python_daqp_call``: the same, but called the plain way, ``out, state = f(meas, state)`` with conversions
  from and to numpy on each call (for reference: what a straightforward casadi MPC in Python costs);
* ``ipopt``: the same QP written with ``casadi.Opti`` (states and inputs as variables, dynamics as equality
  constraints), solved by IPOPT, warm-started with the previous primal and dual solution; the observer and target
  are the MPC's own, in numpy.

Each formulation runs its own closed loop against a fresh FmuPlant; rounds alternate between them so that machine
noise hits all alike. Reported: per-call time (``perf_counter_ns`` around ``u = controller(t, y)``) median and
99th percentile over all calls, their ratios against ``ours`` (median over rounds of the per-round ratio), the
largest difference of the applied torque between formulations, and the real-time factor of the whole loop
(simulated seconds / wall seconds, FMU included). Results go to benchmarks/results/mpc_speed.json and .md.

Run:  python benchmarks/bench_mpc.py [--seconds 2] [--rounds 3] [--quick]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import casadi as ca
import control
import numpy as np

from controllers.mpc import MPC
from cosim import FmuPlant, build_fmu
from cosim.files import write_text_atomic
from cosim.study.paper import STATES, STUDY_DT, two_mass_matrices

DT = STUDY_DT
HORIZON = 20
T_MAX = 5000.0  # N m
REF, T_STEP = 0.01, 0.05  # rad, s
FC = 100.0  # N m, Coulomb friction in the FMU
MEASURED = ["theta_m", "theta_L"]


def design(cls: type[MPC] = MPC, **kw) -> MPC:
    A, B = two_mass_matrices()
    sys = control.ss(A, B[:, :1], np.eye(4), 0, states=list(STATES), inputs=["Tm"], outputs=list(STATES))
    return cls(sys, dt=DT, horizon=HORIZON, outputs=MEASURED, tracked=["theta_L"], u_min=-T_MAX, u_max=T_MAX, **kw)


class PlainCallMPC(MPC):
    """The MPC with its casadi Function called as ``f(meas, state)`` and the results copied back."""

    def _call_python(self, k: int) -> int:
        try:
            out, state_next = self._fun(self._meas, self._states[k])
        except RuntimeError:
            return 1
        self._out[:] = out.full().ravel()
        self._states[1 - k][:] = state_next.full().ravel()
        return 0


class IpoptMPC:
    """The MPC's QP written with casadi.Opti and solved by IPOPT; observer and target taken from `mpc`."""

    def __init__(self, mpc: MPC) -> None:
        sp = mpc.design
        self.sp, self.setpoint = sp, np.zeros(1)
        n, m, N = sp.B.shape[0], sp.B.shape[1], sp.N
        opti = ca.Opti()
        X, U = opti.variable(n, N + 1), opti.variable(m, N)
        dx0, du_prev, us = opti.parameter(n), opti.parameter(m), opti.parameter(m)
        opti.subject_to(X[:, 0] == dx0)
        cost, prev = 0, du_prev
        for k in range(N):  # deviations from the target: dx+ = A dx + B du
            opti.subject_to(X[:, k + 1] == ca.mtimes(ca.DM(sp.A), X[:, k]) + ca.mtimes(ca.DM(sp.B), U[:, k]))
            d = U[:, k] - prev
            cost += ca.bilin(ca.DM(sp.Q), X[:, k], X[:, k]) + ca.bilin(ca.DM(sp.R), U[:, k], U[:, k])
            cost += ca.bilin(ca.DM(sp.S), d, d)
            opti.subject_to(opti.bounded(ca.DM(sp.u_min) - us, U[:, k], ca.DM(sp.u_max) - us))
            if np.all(np.isfinite(sp.du_max)):
                opti.subject_to(opti.bounded(-ca.DM(sp.du_max), d, ca.DM(sp.du_max)))
            prev = U[:, k]
        z_end = ca.vertcat(X[:, N], U[:, N - 1])
        opti.minimize(cost + ca.bilin(ca.DM(sp.P), z_end, z_end))
        opti.solver("ipopt", {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes",
                              "ipopt.hessian_constant": "yes", "ipopt.jac_c_constant": "yes",
                              "ipopt.jac_d_constant": "yes", "ipopt.tol": 1e-10,
                              "ipopt.warm_start_init_point": "yes", "ipopt.mu_strategy": "adaptive"})
        self.opti, self.X, self.U, self.dx0, self.du_prev, self.us = opti, X, U, dx0, du_prev, us
        self.n, self.m, self.N = n, m, N
        self.reset()

    def reset(self) -> None:
        self.xa_prior = np.zeros(self.sp.Ao.shape[0])
        self.u_prev = np.zeros(self.m)
        self.sol = None

    def __call__(self, t: float, y: np.ndarray) -> np.ndarray:
        sp, n = self.sp, self.n
        xa = self.xa_prior + sp.L @ (y - sp.Co @ self.xa_prior - sp.fo)
        target = sp.T @ np.concatenate([np.atleast_1d(self.setpoint), xa[n:]]) + sp.t0
        xs, us = target[:n], target[n:]
        opti = self.opti
        opti.set_value(self.dx0, xa[:n] - xs)
        opti.set_value(self.du_prev, self.u_prev - us)
        opti.set_value(self.us, us)
        if self.sol is not None:  # warm start: previous primal solution shifted, previous duals
            Xp, Up = self.sol.value(self.X), np.atleast_2d(self.sol.value(self.U))
            opti.set_initial(self.X, np.hstack([Xp[:, 1:], Xp[:, -1:]]))
            opti.set_initial(self.U, np.hstack([Up[:, 1:], Up[:, -1:]]))
            opti.set_initial(opti.lam_g, self.sol.value(opti.lam_g))
        self.sol = opti.solve()
        u0 = np.atleast_1d(self.sol.value(self.U[:, 0])) + us
        lo = np.maximum(sp.u_min, self.u_prev - sp.du_max)
        hi = np.minimum(sp.u_max, self.u_prev + sp.du_max)
        u = np.clip(u0, lo, hi)
        self.xa_prior = sp.Ao @ xa + sp.Bo @ u + sp.eo
        self.u_prev = u
        return u


def closed_loop(controller, fmu: Path, seconds: float) -> dict:
    """One closed loop of `seconds` against a fresh plant: per-call times [ns], applied inputs, wall time."""
    steps = int(round(seconds / DT))
    times = np.empty(steps, dtype=np.int64)
    applied = np.empty(steps)
    k_step = int(round(T_STEP / DT))
    controller.setpoint = 0.0
    with FmuPlant(fmu, dt=DT, parameters={"Fc": FC}) as plant:
        y = plant.read_outputs()
        start = time.perf_counter()
        for k in range(steps):
            t = k * DT
            if k == k_step:
                controller.setpoint = REF
            measured = y[[0, 2]]
            t0 = time.perf_counter_ns()
            u = controller(t, measured)
            times[k] = time.perf_counter_ns() - t0
            y = plant.step([u[0], 0.0])
            applied[k] = u[0]
        wall = time.perf_counter() - start
        final_error = abs(y[2] - REF)
    return {"times": times, "u": applied, "rtf": seconds / wall, "final_error": final_error}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per closed loop")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds")
    parser.add_argument("--quick", action="store_true", help="0.3 s, 1 round: a smoke run")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "mpc_speed"))
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.rounds = 0.3, 1
    fmu = build_fmu()
    ours, python_daqp = design(), design(codegen=False)
    if not ours.info["solver_path"].startswith("c:"):
        raise SystemExit(f"the compiled path is not available here: {ours.info.get('codegen_unavailable')}")
    ipopt = IpoptMPC(ours)
    plain = design(PlainCallMPC, codegen=False)
    controllers = {"ours": ours, "python_daqp": python_daqp, "python_daqp_call": plain, "ipopt": ipopt}
    for c in controllers.values():  # warm-up: imports, page cache, first solves
        closed_loop(c, fmu, 0.02)
    runs: dict[str, list[dict]] = {name: [] for name in controllers}
    for _ in range(args.rounds):
        for name, c in controllers.items():
            c.reset()
            runs[name].append(closed_loop(c, fmu, args.seconds))

    # the product's own loop, cosim.loop.closed_loop.closed_loop (bookkeeping, metrics): what users run
    from cosim.loop.closed_loop import closed_loop as product_loop

    product = [product_loop(ours, fmu, duration=args.seconds, reference=lambda t: REF * (t >= T_STEP),
                            parameters={"Fc": FC}, model=None, progress=False) for _ in range(args.rounds)]
    product_ct = np.concatenate([r.compute_time for r in product]) * 1e6

    def us(name: str) -> np.ndarray:
        return np.concatenate([r["times"] for r in runs[name]]) / 1e3

    figures = {}
    for name in controllers:
        t = us(name)
        figures[name] = {"median_us": float(np.median(t)), "p99_us": float(np.percentile(t, 99)),
                         "max_us": float(t.max()), "rtf_median": statistics.median(r["rtf"] for r in runs[name]),
                         "final_error_rad": max(r["final_error"] for r in runs[name])}

    def ratio(name: str, stat) -> float:
        return statistics.median(float(stat(a["times"]) / stat(b["times"])) for a, b in zip(runs[name], runs["ours"],
                                                                                            strict=True))

    def p99(x: np.ndarray) -> float:
        return float(np.percentile(x, 99))

    du = {name: max(float(np.max(np.abs(a["u"] - b["u"]))) for a, b in zip(runs[name], runs["ours"], strict=True))
          for name in ("python_daqp", "python_daqp_call", "ipopt")}
    result = {
        "benchmark": (f"MPC call in closed loop with the bundled two_mass_servo FMU (Fc={FC} N m), dt=1/2257 s, "
                      f"N={HORIZON}, |Tm|<={T_MAX} N m, setpoint step {REF} rad at {T_STEP} s"),
        "seconds_per_loop": args.seconds,
        "calls_per_loop": int(round(args.seconds / DT)),
        "rounds": args.rounds,
        "solver_path_ours": ours.info["solver_path"],
        "solver_path_python_daqp": python_daqp.info["solver_path"],
        "formulations": figures,
        "ratio_median_python_daqp_over_ours": ratio("python_daqp", np.median),
        "ratio_median_python_daqp_call_over_ours": ratio("python_daqp_call", np.median),
        "ratio_median_ipopt_over_ours": ratio("ipopt", np.median),
        "ratio_p99_python_daqp_over_ours": ratio("python_daqp", p99),
        "ratio_p99_python_daqp_call_over_ours": ratio("python_daqp_call", p99),
        "ratio_p99_ipopt_over_ours": ratio("ipopt", p99),
        "max_abs_du_python_daqp_vs_ours_Nm": du["python_daqp"],
        "max_abs_du_python_daqp_call_vs_ours_Nm": du["python_daqp_call"],
        "max_abs_du_ipopt_vs_ours_Nm": du["ipopt"],
        "product_loop": {"median_us": float(np.median(product_ct)), "p99_us": float(np.percentile(product_ct, 99)),
                         "rtf_median": statistics.median(r.metrics["realtime_factor"] for r in product),
                         "settling_time_s": product[0].metrics["settling_time"],
                         "steady_state_error_rad": product[0].metrics["steady_state_error"]},
        "target_p99_us": 50.0,
        "target_rtf": 20.0,
        "python": platform.python_version(),
        "casadi": ca.__version__,
        "machine": platform.machine(),
        "processor": platform.processor() or "unknown",
    }
    out = Path(args.out)
    write_text_atomic(out.with_suffix(".json"), json.dumps(result, indent=2) + "\n")
    rows = [("ours", "compiled C (casadi codegen + DAQP), ctypes"),
            ("python_daqp", "casadi Function from Python (Function.buffer), DAQP"),
            ("python_daqp_call", "casadi Function from Python (plain call), DAQP"),
            ("ipopt", "casadi Opti + IPOPT, warm-started")]
    table = "| formulation | median us/call | p99 us/call | max us | real-time factor | ratio (median) vs ours |\n"
    table += "| --- | --- | --- | --- | --- | --- |\n"
    for name, label in rows:
        f = figures[name]
        r = 1.0 if name == "ours" else result[f"ratio_median_{name}_over_ours"]
        table += (f"| {label} | {f['median_us']:.1f} | {f['p99_us']:.1f} | {f['max_us']:.0f} | "
                  f"{f['rtf_median']:.1f} | {r:.1f} |\n")
    table += (f"\n{args.rounds} interleaved round(s) of {args.seconds:g} s simulated "
              f"({result['calls_per_loop']} calls) per formulation. Largest |Tm| difference against ours: "
              f"python DAQP {du['python_daqp']:.3g} N m "
              f"(buffer) and {du['python_daqp_call']:.3g} N m (plain call), IPOPT {du['ipopt']:.3g} N m. "
              "Targets: p99 <= 50 us, real-time factor >= 20.\n")
    pl = result["product_loop"]
    table += (f"\nThe same compiled MPC in cosim's own loop (`cosim.loop.closed_loop.closed_loop`, with its "
              f"bookkeeping and metrics): median {pl['median_us']:.1f} us, p99 {pl['p99_us']:.1f} us per call, "
              f"real-time factor "
              f"{pl['rtf_median']:.1f}; step settled in {pl['settling_time_s']:.3f} s, steady-state error "
              f"{pl['steady_state_error_rad']:.2g} rad.\n")
    write_text_atomic(out.with_suffix(".md"), table)
    print(table)


if __name__ == "__main__":
    main()
