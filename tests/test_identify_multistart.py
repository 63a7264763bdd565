"""The default identification (multi-start output-error refinement) on data from independent simulators.

The records come from this file's own plants, integrated by scipy's ``solve_ivp`` (not cosim's model code,
not the bundled FMU): a two-mass drive (motor and load on a shaft) and a single mass (with or without a
spring to ground), inertias and stiffness over decades, 200 Hz-5 kHz, 0.2-5 % noise, multisine, PRBS or a
closed loop (a PID on the noisy measured position), some with positions only (velocities derived). The
README tour's data (the bundled servo, square wave, 2 % and 10 % noise) is checked against the linearised
FMU as well. Each default fit must give a stable model, and a free run that follows the data.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosim import SINDYc
from cosim.data.trajectory import Trajectory
from cosim.identify.metrics import r2

DEFAULTS = {"library": "linear", "threshold": "auto", "differentiation": "integral", "noise_compensation": True,
            "kinematics": "auto", "refine": "output_error"}


# ------------------------------------------------------------------------------------ independent records
def _plant(rng: np.random.Generator, rate: float) -> dict:
    """A two-mass drive or a single mass, parameters over decades; modes below rate / 25."""
    if rng.uniform() < 0.6:
        jm = math.exp(rng.uniform(math.log(1e-4), math.log(1e-1)))
        jl = jm * math.exp(rng.uniform(math.log(0.3), math.log(3.0)))
        f_r = math.exp(rng.uniform(math.log(3.0), math.log(min(40.0, rate / 25))))
        jeq = jm * jl / (jm + jl)
        k = (2 * math.pi * f_r) ** 2 * jeq
        zeta = rng.uniform(0.02, 0.2)
        return {"kind": "two_mass", "Jm": jm, "JL": jl, "k": k, "c": 2 * zeta * math.sqrt(k * jeq),
                "bm": jm * 2 * math.pi * math.exp(rng.uniform(math.log(0.05), 0.0)),
                "bL": jl * 2 * math.pi * math.exp(rng.uniform(math.log(0.05), 0.0)), "f": f_r}
    m = math.exp(rng.uniform(math.log(1e-2), math.log(10.0)))
    f_b = math.exp(rng.uniform(math.log(0.05), math.log(2.0)))
    f_n = math.exp(rng.uniform(math.log(0.5), math.log(min(20.0, rate / 50)))) if rng.uniform() < 0.5 else 0.0
    return {"kind": "single", "m": m, "b": m * 2 * math.pi * f_b, "k": m * (2 * math.pi * f_n) ** 2,
            "f": max(f_n, f_b, 1.0)}


def _rhs(p: dict):
    if p["kind"] == "two_mass":
        def f(_t, y, u):
            tm, wm, tl, wl = y
            ts = p["k"] * (tm - tl) + p["c"] * (wm - wl)
            return [wm, (u - p["bm"] * wm - ts) / p["Jm"], wl, (ts - p["bL"] * wl) / p["JL"]]
    else:
        def f(_t, y, u):
            x, v = y
            return [v, (u - p["b"] * v - p["k"] * x) / p["m"]]
    return f


def _simulate(p: dict, dt: float, u: np.ndarray | None, pid: dict | None, ref: np.ndarray | None,
              noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clean states (n+1 rows) and the held input (n rows): open loop, or a PID on the noisy first state."""
    f = _rhs(p)
    n = len(u) if u is not None else len(ref)
    y = np.zeros(4 if p["kind"] == "two_mass" else 2)
    out = np.empty((n + 1, y.size))
    out[0] = y
    cmd = np.empty(n)
    integral = prev = 0.0
    k = 0
    while k < n:
        if pid is not None:
            meas = y[0] + noise[k, 0]
            e = ref[k] - meas
            integral += e * dt
            deriv = 0.0 if k == 0 else (meas - prev) / dt
            prev = meas
            cmd[k] = pid["kp"] * e + pid["ki"] * integral - pid["kd"] * deriv
            j = k + 1
        else:
            j = k + 1
            while j < n and u[j] == u[k]:  # one solve over a run of equal held inputs
                j += 1
            cmd[k:j] = u[k]
        t_eval = dt * np.arange(k, j + 1)
        sol = solve_ivp(f, (t_eval[0], t_eval[-1]), y, method="RK45", t_eval=t_eval, args=(cmd[k],),
                        rtol=1e-9, atol=1e-12, max_step=dt)
        out[k + 1:j + 1] = sol.y.T[1:]
        y = sol.y[:, -1]
        k = j
    return out, cmd


def make_record(index: int, max_samples: int = 12000) -> dict:
    """Record `index` (seed `index`): train data as a Trajectory, the states to fit, derived velocities."""
    rng = np.random.default_rng([index, 17])
    rate = math.exp(rng.uniform(math.log(200.0), math.log(5000.0)))
    duration = min(math.exp(rng.uniform(math.log(4.0), math.log(30.0))), max_samples / rate)
    n = int(duration * rate)
    dt = 1.0 / rate
    p = _plant(rng, rate)
    kind = ["multisine", "prbs", "closed_loop"][index % 3]
    positions_only = index % 4 == 3
    noise_frac = math.exp(rng.uniform(math.log(0.002), math.log(0.05)))
    n_states = 4 if p["kind"] == "two_mass" else 2
    white = rng.standard_normal((n + 1, n_states))
    f_hi = min(rate / 10, max(5.0, 3 * p["f"]))
    if kind == "closed_loop":
        n = min(n, 4000)
        white = white[:n + 1]
        mass = p["Jm"] + p["JL"] if p["kind"] == "two_mass" else p["m"]
        wc = 2 * math.pi * min(2.0, p["f"] / 4, rate / 40)
        pid = {"kp": mass * wc ** 2, "ki": mass * wc ** 3 / 8, "kd": 1.4 * mass * wc}
        t = dt * np.arange(n)
        freqs = np.geomspace(0.1, wc / (2 * math.pi), 8)
        ref = np.sin(2 * np.pi * freqs[:, None] * t + rng.uniform(0, 2 * np.pi, (8, 1))).sum(axis=0) / 4
        # the PID sees the measured (noisy) position: noise scaled to the reference's range
        noise0 = noise_frac * float(np.ptp(ref)) * white
        clean, cmd = _simulate(p, dt, None, pid, ref, noise0)
    else:
        t = dt * np.arange(n)
        if kind == "multisine":
            freqs = np.geomspace(max(2.0 / duration, 0.05), f_hi, 24)
            s = np.sin(2 * np.pi * freqs[:, None] * t + rng.uniform(0, 2 * np.pi, (24, 1))).sum(axis=0)
        else:
            clock = max(1, round(1.0 / (2.5 * f_hi * dt)))
            s = np.repeat(rng.choice([-1.0, 1.0], size=n // clock + 2), clock)[:n]
        s = s / np.sqrt(np.mean(s ** 2))
        clean, cmd = _simulate(p, dt, s, None, None, white)
        scale = 1.0 / max(float(np.ptp(clean[:, 0])), 1e-300)  # about a unit of position
        clean, cmd = clean * scale, cmd * scale
    sigma = noise_frac * np.ptp(clean, axis=0)
    noisy = clean + sigma * white
    names = ("theta_m", "omega_m", "theta_L", "omega_L") if p["kind"] == "two_mass" else ("x", "v")
    u_col = np.append(cmd, cmd[-1])
    columns = {"Tm" if p["kind"] == "two_mass" else "u": u_col}
    velocities = {}
    if positions_only:
        for i in range(0, n_states, 2):
            columns[names[i]] = noisy[:, i]
            velocities[f"{names[i]}_dot"] = names[i]
        states = [s for i in range(0, n_states, 2) for s in (names[i], f"{names[i]}_dot")]
    else:
        for i, name in enumerate(names):
            columns[name] = noisy[:, i]
        states = list(names)
    t = dt * np.arange(n + 1)
    traj = Trajectory.from_arrays(t, columns, roles={**{s: "state" for s in columns if s not in ("Tm", "u")},
                                                     ("Tm" if p["kind"] == "two_mass" else "u"): "input"})
    return {"index": index, "plant": p, "kind": kind, "positions_only": positions_only, "rate": rate,
            "samples": n + 1, "noise": noise_frac, "traj": traj, "states": states,
            "input": "Tm" if p["kind"] == "two_mass" else "u", "velocities": velocities, "clean": clean}


def fit_record(rec: dict, **settings) -> SINDYc:
    est = SINDYc(**{**DEFAULTS, "velocities": rec["velocities"] or None, **settings})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return est.fit(rec["traj"], states=rec["states"], inputs=[rec["input"]])


def free_run_r2(est: SINDYc, traj: Trajectory) -> np.ndarray:
    """R² per state of the model's free run (from its estimated initial state) against the fitted data."""
    model = est.model_
    x, u = est._arrays(traj)
    x0 = np.asarray(model.meta["x0"][0]) if "x0" in model.meta else x[0]
    sim = model.simulate(x0, u[:-1], dt=traj.dt)
    return np.asarray(r2(x, sim.states)) if sim.ok else np.full(x.shape[1], -np.inf)


# ------------------------------------------------------------------------------------------- the tour
def _tour(noise: float) -> Trajectory:
    from cosim import build_fmu, simulate

    return simulate(build_fmu(), {"Tm": "square:amp=500,freq=2"}, duration=4.0, dt=1 / 2257,
                    parameters={"Fc": 0.3}).with_noise(noise, seed=0)


@pytest.mark.parametrize("noise", [0.02, 0.1])
def test_readme_tour_default_fit_is_stable_and_follows_the_data(noise):
    from cosim.study.paper import two_mass_matrices

    traj = _tour(noise)
    states = ["theta_m", "omega_m", "theta_L", "omega_L"]
    est = SINDYc(**DEFAULTS).fit(traj, states=states, inputs=["Tm"])
    model = est.model_
    assert model.meta["stable"] is True
    ms = model.meta["multistart"]
    assert ms["chosen"] in [{"start": r["start"], "prior": r["prior"]} for r in ms["runs"]]
    # (the runs' costs are of the decimated records the multi-start works on: compared with the winner's there)
    refinement = model.meta["refinement"]
    assert refinement.get("analysis_cost", refinement["cost"]) <= min(r["cost"] for r in ms["runs"]) * 1.5
    a = model.coef[:, [model.terms.index(s) for s in states]]
    b = model.coef[:, model.terms.index("Tm")]
    assert a[0].tolist() == [0.0, 1.0, 0.0, 0.0] and a[2].tolist() == [0.0, 0.0, 0.0, 1.0]  # kinematic rows
    a_true, b_true = two_mass_matrices({"Fc": 0.3})
    spring = [(1, 0), (1, 2), (3, 0), (3, 2)]
    for i, j in spring:
        assert a[i, j] == pytest.approx(a_true[i, j], rel=0.05 if noise <= 0.02 else 0.1)
    assert b[1] == pytest.approx(b_true[1, 0], rel=0.05)
    if noise <= 0.02:
        for i in (1, 3):
            for j in range(4):
                assert a[i, j] == pytest.approx(a_true[i, j], rel=0.05), (i, j)
        assert abs(b[3]) < 0.05 * b_true[1, 0]
    assert np.min(free_run_r2(est, traj)) >= 0.98


# ------------------------------------------------------------------------------------------ a sample
@pytest.mark.parametrize("index", [0, 1, 2, 3, 5, 7, 10, 14])
def test_independent_records_give_stable_models(index):
    rec = make_record(index, max_samples=6000)
    est = fit_record(rec)  # raises UnstableModelError if the model is unstable
    assert est.model_.meta["stable"] is True
    assert np.min(free_run_r2(est, rec["traj"])) > 0.9


def _benchmark_record(index: int, version: int = 2):
    """Record `index` of the generalisation benchmark's simulator (benchmarks/independent_plants.py), as its
    second version drew it (the noise a share of the effect-free run's range), or its third."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # benchmarks/ is not a package
    import independent_plants as ip

    return ip.make_record(index, max_samples=4000, noise_of_effect_free=version == 2)


def _identified(index: int, tmp_path, version: int = 2) -> tuple:
    """Benchmark record `index` and the meta of ``cosim identify``'s model of it (signal names only, exit 0)."""
    import json

    from click.testing import CliRunner

    from cosim.cli import main

    record = _benchmark_record(index, version)
    folder = record.write(tmp_path / "record")
    derive = [f"{p}_dot={p}" for p in record.cli["derive"]]  # positions only: the benchmark's own option
    result = CliRunner().invoke(main, ["identify", str(folder / "train.csv"), "--state",
                                       ",".join(record.cli["states"]), "--input", record.cli["input"], "-o",
                                       str(tmp_path / "model.json"), *(["--derive", ",".join(derive)] if derive
                                                                        else [])], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return record, json.loads((tmp_path / "model.json").read_text())["meta"]


@pytest.mark.slow
def test_a_stable_refinement_is_preferred_to_an_unexcited_unstable_one(tmp_path):
    """Record 61 of benchmarks/independent_plants.py (a two-mass drive in closed loop, nothing else): the first
    refinement reaches the noise floor with an unstable mode the data do not excite; the multi-start goes on
    while its best is unstable, and a stable refinement of no more cost is the answer (`cosim identify` used to
    refuse this record as unstable)."""
    _, meta = _identified(61, tmp_path)
    assert meta["stable"] is True
    runs = meta["multistart"]["runs"]
    chosen = next(r for r in runs if r["start"] == meta["multistart"]["chosen"]["start"]
                  and r["prior"] == meta["multistart"]["chosen"]["prior"])
    assert chosen["stable"] and any(not r["stable"] for r in runs)  # an unstable one was tried, and passed over
    assert chosen["cost"] <= 2.0 * min(r["cost"] for r in runs)


@pytest.mark.slow
def test_prefer_stable_keeps_an_unstable_model_allowed_but_not_preferred():
    """Record 129 of benchmarks/independent_plants.py (a linear two-mass drive in closed loop), with unstable models
    allowed: the least-cost refinement is unstable; with ``prefer_stable=True`` a stable one of at most twice its
    cost is the answer, and nothing is refused either way. (Record 112, used before, identifies stable since
    the multi-start no longer stops 1.5 times above the noise floor.)"""
    record = _benchmark_record(129)
    states, u = list(record.cli["states"]), record.cli["input"]
    assert not record.cli["derive"]  # (every state measured)
    traj = Trajectory.from_arrays(record.train["time"], {k: record.train[k] for k in [*states, u]},
                                  roles={**dict.fromkeys(states, "state"), u: "input"})
    settings = {"library": "linear", "include_constant": True, "threshold": 0.0, "kinematics": "auto",
                "refine": "output_error", "allow_unstable": True}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        least = SINDYc(**settings).fit(traj, states=states, inputs=[u])
        stable = SINDYc(**settings, prefer_stable=True).fit(traj, states=states, inputs=[u])
    assert least.model_.meta["stable"] is False
    meta = stable.model_.meta
    assert meta["stable"] is True
    runs = meta["multistart"]["runs"]
    chosen = next(r for r in runs if (r["start"], r["prior"]) == (meta["multistart"]["chosen"]["start"],
                                                                  meta["multistart"]["chosen"]["prior"]))
    assert chosen["cost"] <= 2.0 * min(r["cost"] for r in runs)


def test_the_fit_runs_with_one_blas_thread_so_a_record_gives_the_same_model_every_run(monkeypatch):
    """Two OpenBLAS threads split sums in an order that varies from run to run: the timing record of
    benchmarks/bench_diagnosis.py gave models 1e-9 apart and, from them, two different diagnoses. The fit asks
    for one thread whatever the caller set."""
    from threadpoolctl import threadpool_info, threadpool_limits

    import cosim.identify.sindyc as sindyc

    seen = []
    original = sindyc._sparse_fit

    def spy(*args, **kwargs):
        seen.append(max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
        return original(*args, **kwargs)

    monkeypatch.setattr(sindyc, "_sparse_fit", spy)
    t = np.arange(0.0, 4.0, 0.01)
    u = np.sign(np.sin(2 * np.pi * 0.5 * t))
    x = np.zeros_like(t)
    for k in range(len(t) - 1):
        x[k + 1] = x[k] + 0.01 * (-2.0 * x[k] + 3.0 * u[k])
    data = Trajectory.from_arrays(t, {"x": x, "u": u}, roles={"x": "state", "u": "input"})
    with threadpool_limits(limits=2, user_api="blas"):
        first = SINDYc(include_constant=False).fit(data).coef_
        again = SINDYc(include_constant=False).fit(data).coef_
        assert max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas") == 2  # restored
    assert seen == [1, 1]
    np.testing.assert_array_equal(first, again)
    np.testing.assert_allclose(first, [[-2.0, 3.0]], rtol=0.02)


def test_an_unexcited_unstable_mode_is_reflected_where_the_data_do_not_pin_the_model():
    """Two masses that move together (the shaft's twist stays at the noise) on a shaft of negative stiffness:
    the twist mode grows (+9.5 1/s) but nothing in the data shows it. The stabilised start reflects it by
    changing what the data cannot see (the twist's coefficients, equal and opposite on the two positions and on
    the two velocities), not the common motion the data pin down."""
    from cosim.identify._stability import stabilised
    from cosim.identify.model import IdentifiedModel

    states = ("theta_m", "omega_m", "theta_L", "omega_L")
    kt, c = -50.0, 0.5  # twist stiffness and damping per unit inertia
    coef = np.array([[0, 1, 0, 0, 0], [-kt, -c, kt, c, 1.0], [0, 0, 0, 1, 0], [kt, c, -kt, -c, 0.0]], dtype=float)
    model = IdentifiedModel(states=states, inputs=("u",), terms=(*states, "u"), coef=coef, dt=0.01)
    assert np.max(np.linalg.eigvals(model.linear_matrices()[0]).real) > 9.0
    t = np.arange(0.0, 10.0, 0.01)
    twist = 1e-4 * np.random.default_rng(0).standard_normal((t.size, 2))
    X = np.column_stack([np.sin(t), np.cos(t), np.sin(t) + twist[:, 0], np.cos(t) + twist[:, 1]])
    movable = coef != 0.0
    movable[[0, 2]] = False  # kinematic rows
    out = stabilised(model, coef, movable, limit=0.1, states=X)
    assert out is not None
    fixed = IdentifiedModel(states=states, inputs=("u",), terms=(*states, "u"), coef=out, dt=0.01)
    assert np.max(np.linalg.eigvals(fixed.linear_matrices()[0]).real) <= 0.1
    change = out - coef
    for row in (1, 3):  # the common motion's coefficients (the sums over the two bodies) have not moved
        assert abs(change[row, 0] + change[row, 2]) < 1e-3 * abs(change[row, 0])
        assert abs(change[row, 1] + change[row, 3]) < 1e-3 * max(abs(change[row, 1]), abs(change[row, 0]))
    assert np.array_equal(out[[0, 2]], coef[[0, 2]]) and np.array_equal(out[:, 4], coef[:, 4])


@pytest.mark.slow
def test_a_linear_plant_whose_twist_the_steps_do_not_excite_identifies_stable(tmp_path):
    """Record 9 of benchmarks/independent_plants.py: a linear two-mass drive (no effect) under steps, 0.25 %
    noise, whose 26 Hz shaft mode the steps hardly excite. Every start's refinement reaches the noise floor with
    an unstable twist mode (+1.8 to +2.7 1/s) and `cosim identify` refused the record; the start with that mode
    reflected (``_stability.stabilised``) fits within twice the least cost and is the answer."""
    record, meta = _identified(9, tmp_path)
    assert not record.spec["effects"]
    assert meta["stable"] is True and meta["multistart"]["chosen"]["start"] == "stabilised"
    runs = meta["multistart"]["runs"]
    assert all(not r["stable"] for r in runs if r["start"] != "stabilised")
    assert min(r["cost"] for r in runs if r["start"] == "stabilised") <= 2.0 * min(r["cost"] for r in runs)


@pytest.mark.slow
def test_the_reflected_start_is_kept_stable_while_it_is_refined(tmp_path):
    """Record 75 of benchmarks/independent_plants.py (version 3: a linear two-mass drive, positions only, no
    effect): every start's refinement grows a 14 rad/s mode at +1.5 1/s. Refined unconstrained, the start with
    it reflected slid back to that optimum and `cosim identify` refused the record; kept stable
    (``stability_limit``) it is the answer, within twice the least cost."""
    record, meta = _identified(75, tmp_path, version=3)
    assert not record.spec["effects"]
    assert meta["stable"] is True and meta["multistart"]["chosen"]["start"] == "stabilised"
    runs = meta["multistart"]["runs"]
    assert all(not r["stable"] for r in runs if r["start"] != "stabilised")
    assert min(r["cost"] for r in runs if r["start"] == "stabilised") <= 2.0 * min(r["cost"] for r in runs)
    limit = meta["marginal_limit"]
    assert max(re for re, _ in meta["eigenvalues"]) <= limit


@pytest.mark.slow
def test_the_multi_start_goes_on_past_a_refinement_a_quarter_above_the_noise_floor():
    """Record 196 of benchmarks/independent_plants.py (a two-mass drive under steps, a dead zone on the torque),
    with the diagnosis' base settings: the first start's refinement ends 1.27 times the white-noise floor,
    unstable (+1.06 1/s); the velocity-integral start reaches 0.99 times it, stable. The multi-start used to
    stop at 1.5 times the floor, with the first."""
    from cosim.diagnose.diagnosis import BASE_SETTINGS
    from cosim.identify._refinement import _FLOOR_MARGIN

    record = _benchmark_record(196, version=3)
    states, u = list(record.cli["states"]), record.cli["input"]
    traj = Trajectory.from_arrays(record.train["time"], {k: record.train[k] for k in [*states, u]},
                                  roles={**dict.fromkeys(states, "state"), u: "input"})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = SINDYc(**BASE_SETTINGS).fit(traj, states=states, inputs=[u]).model_
    multistart = model.meta["multistart"]
    floor, runs = multistart["noise_floor"], multistart["runs"]
    assert runs[0]["cost"] > 1.2 * floor  # (below 1.5: the old margin stopped here)
    chosen = next(r for r in runs if (r["start"], r["prior"]) == (multistart["chosen"]["start"],
                                                                  multistart["chosen"]["prior"]))
    assert chosen["cost"] == min(r["cost"] for r in runs) <= _FLOOR_MARGIN * floor
    assert chosen["cost"] < 0.85 * runs[0]["cost"]
    assert model.meta["stable"] is True
