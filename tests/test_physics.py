"""The bundled FMU against independent solutions of the same equations.

Linear plant: exact zero-order-hold discretisation (matrix exponential). Each undeclared effect alone:
scipy's solve_ivp (DOP853) at tight tolerance, restarted at every input switch. Agreement is measured per
state as max |fmu - reference| / max |reference| and must be 1e-6 or better.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from cosim import build_fmu, simulate

DT = 1e-3
X0 = {"theta_m": -2.0, "omega_m": 0.0, "theta_L": 2.0, "omega_L": 1.0}
STATES = ("theta_m", "omega_m", "theta_L", "omega_L")
NOMINAL = {"Jm": 250.0, "JL": 1000.0, "KL": 2.5e6, "Bm": 50.0, "BL": 500.0}
OFF = {"Fc": 0.0, "Fs": 0.0, "vs": 0.01, "vsmooth": 1e-3, "Bm_asym": 0.0, "backlash": 0.0, "Tcog": 0.0,
       "ncog": 12, "Tmax": 0.0, "mgl": 0.0, "Toffset": 0.0, "delay": 0.0}


def rhs(x: np.ndarray, tm: float, tl: float, p: dict) -> np.ndarray:
    """The plant's equations, written again from the FMU's README (not from its C source)."""
    thm, wm, thl, wl = x
    ta = float(np.clip(tm, -p["Tmax"], p["Tmax"])) if p["Tmax"] > 0 else tm
    twist, b = thm - thl, p["backlash"]
    spring = twist - b if twist > b else twist + b if twist < -b else 0.0
    tc = p["KL"] * spring + p["BL"] * (wm - wl)
    sgn = np.tanh(wm / p["vsmooth"])
    tf = (p["Bm"] * wm + p["Bm_asym"] * wm * sgn + p["Fc"] * sgn
          + p["Fs"] * np.exp(-(wm / p["vs"]) ** 2) * sgn)
    tcog = p["Tcog"] * np.sin(p["ncog"] * thm)
    dwm = (ta + p["Toffset"] - tf - tcog - tc) / p["Jm"]
    dwl = (tl + tc - p["mgl"] * np.sin(thl)) / p["JL"]
    return np.array([wm, dwm, wl, dwl])


def square_inputs(n: int, amp: float, every: int) -> np.ndarray:
    """Tm: a square wave switching every `every` steps; TL: a smaller step half-way."""
    k = np.arange(n)
    tm = amp * np.where((k // every) % 2 == 0, 1.0, -1.0)
    tl = np.where(k >= n // 2, -0.2 * amp, 0.0)
    return np.column_stack([tm, tl])


def reference_ivp(u: np.ndarray, p: dict, x0: np.ndarray) -> np.ndarray:
    """solve_ivp over the piecewise-constant applied inputs, restarted at every change (and delay shift)."""
    n = u.shape[0]
    t_samples = DT * np.arange(n + 1)
    # applied inputs as piecewise-constant functions: Tm delayed by p["delay"], held at u[0] before t=0+delay
    def tm_at(s):
        k = int(np.floor((s - p["delay"]) / DT + 1e-9))
        return 0.0 if k < 0 else u[min(k, n - 1), 0]

    def tl_at(s):
        return u[min(int(np.floor(s / DT + 1e-9)), n - 1), 1]

    breaks = set(np.round(t_samples[np.flatnonzero(np.diff(u[:, 0]) != 0) + 1] + p["delay"], 12))
    breaks |= set(np.round(t_samples[np.flatnonzero(np.diff(u[:, 1]) != 0) + 1], 12))
    breaks |= {round(p["delay"], 12), 0.0, round(t_samples[-1], 12)}
    edges = sorted(b for b in breaks if 0.0 <= b <= t_samples[-1])
    out = np.empty((n + 1, 4))
    out[0] = x0
    x = np.array(x0, dtype=float)
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        mid = 0.5 * (a + b)
        tm, tl = tm_at(mid), tl_at(mid)
        inside = np.flatnonzero((t_samples > a + 1e-12) & (t_samples < b - 1e-12))
        t_eval = np.append(t_samples[inside], b)
        sol = solve_ivp(lambda s, x, tm=tm, tl=tl: rhs(x, tm, tl, p), (a, b), x, method="DOP853",
                        rtol=1e-12, atol=1e-14, t_eval=t_eval)
        assert sol.success, sol.message
        out[inside] = sol.y[:, :-1].T
        x = sol.y[:, -1]
        at_b = np.flatnonzero(np.abs(t_samples - b) < 1e-12)
        out[at_b] = x
    return out


def relative_error(fmu_states: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.max(np.abs(fmu_states - ref), axis=0) / np.max(np.abs(ref), axis=0)


def run_fmu(fmu, u: np.ndarray, parameters: dict, start: dict = X0) -> np.ndarray:
    traj = simulate(fmu, {"Tm": u[:, 0], "TL": u[:, 1]}, duration=u.shape[0] * DT, dt=DT,
                    parameters=parameters, start=start)
    return traj[list(STATES)]


@pytest.fixture(scope="module")
def fmu2():
    return build_fmu(fmi_version="2.0")


@pytest.mark.parametrize("fmi_version", ["2.0", "3.0"])
def test_linear_plant_matches_exact_zoh_discretisation(fmi_version):
    fmu = build_fmu(fmi_version=fmi_version)
    p = NOMINAL
    a = np.array([[0, 1, 0, 0],
                  [-p["KL"] / p["Jm"], -(p["Bm"] + p["BL"]) / p["Jm"], p["KL"] / p["Jm"], p["BL"] / p["Jm"]],
                  [0, 0, 0, 1],
                  [p["KL"] / p["JL"], p["BL"] / p["JL"], -p["KL"] / p["JL"], -p["BL"] / p["JL"]]])
    b = np.array([[0, 0], [1 / p["Jm"], 0], [0, 0], [0, 1 / p["JL"]]])
    big = np.zeros((6, 6))
    big[:4, :4], big[:4, 4:] = a, b
    phi = expm(big * DT)
    ad, bd = phi[:4, :4], phi[:4, 4:]
    rng = np.random.default_rng(1)
    u = np.column_stack([rng.choice([-500.0, 500.0], 800), rng.normal(0, 100, 800)])  # random ZOH inputs
    x = np.empty((801, 4))
    x[0] = [X0[s] for s in STATES]
    for k in range(800):
        x[k + 1] = ad @ x[k] + bd @ u[k]
    err = relative_error(run_fmu(fmu, u, NOMINAL), x)
    assert np.all(err < 1e-6), dict(zip(STATES, err, strict=True))


EFFECTS = {
    "coulomb": {"Fc": 150.0},
    "stribeck": {"Fs": 120.0, "vs": 0.05},
    "viscous_asymmetry": {"Bm_asym": 30.0},
    "backlash": {"backlash": 2e-4},
    "cogging": {"Tcog": 80.0, "ncog": 24},
    "saturation": {"Tmax": 300.0},
    "gravity": {"mgl": 400.0},
    "offset": {"Toffset": -60.0},
    "delay": {"delay": 0.005},
}


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_each_effect_alone_matches_solve_ivp(fmu2, effect):
    params = {**NOMINAL, **OFF, **EFFECTS[effect]}
    # a slow start (small twist, small speeds) so that friction and backlash are visited, not swamped
    start = {"theta_m": 0.0, "omega_m": 0.0, "theta_L": 0.0, "omega_L": 0.02}
    x0 = np.array([start[s] for s in STATES])
    u = square_inputs(600, 500.0, 100)
    fmu_params = {k: v for k, v in params.items()}
    fmu_params["nsub"] = 40 if effect == "backlash" else 10  # RK4 loses order at the dead-band kinks
    got = run_fmu(fmu2, u, fmu_params, start)
    ref = reference_ivp(u, params, x0)
    err = relative_error(got, ref)
    assert np.all(err < 1e-6), dict(zip(STATES, err, strict=True))


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_each_effect_changes_the_trajectory(fmu2, effect):
    """The effect is really switched on: the trajectory differs from the linear plant's."""
    start = {"theta_m": 0.0, "omega_m": 0.0, "theta_L": 0.0, "omega_L": 0.02}
    u = square_inputs(600, 500.0, 100)
    linear = run_fmu(fmu2, u, NOMINAL, start)
    with_effect = run_fmu(fmu2, u, {**NOMINAL, **EFFECTS[effect]}, start)
    assert np.max(np.abs(with_effect - linear)) > 1e-3 * np.max(np.abs(linear))
