"""Record families of the independent benchmark, records 200 on: the classes of plant issue 39 saw break.

Like :mod:`independent_plants` (records 0-199), its own equations and scipy (:mod:`_family_system`), nothing of
cosim. Record ``i >= 200`` belongs to family ``FAMILIES[(i - 200) % 7]``, its variant is ``(i - 200) // 7``
(mod the family's variants), and it is drawn from seed ``i``, fully reproducible. Each is written as records
0-199 are (``train.csv`` with a ``time`` column, the command written exactly, the states with white Gaussian
noise of a drawn 0.2-5 % of each written state's range; ``heldout.csv``, its twin with another excitation and
noise seed; ``heldout_clean.npz``; ``truth.json`` with ``spec`` and ``cli``). Lengths 5 k-50 k samples
(``max_samples`` shortens, then lowers the rate, never below 5 s), 100 Hz-5 kHz, 10-120 s.

Families (parameter ranges; forces in the input's units)
    ``one_way_pair``: a mass (m 1e-2..10, no spring, damping corner 2/T..2 Hz) with ``coulomb_friction``
    (Fc 0.15-0.4 of the largest command), ``viscous_asymmetry`` (d 0.2-0.6 of b) and an ``offset`` (|F0|
    0.2-0.6 Fc, either sign) together, as two records (``train.csv``, ``train_b.csv``), each of force steps
    from rest one way only (the first positive, the second negative; every level keeps the mass moving, so
    the velocity never changes sign and never stops after the start). The pair is diagnosed together; each
    alone shows only an offset (``shows_alone_as``).
    ``saturation_deadzone``: a mass (a spring on half of them) under a multisine or steps; the plant sees the
    command clipped (variant 0: 5-40 % of the samples) or dead-zoned (variant 1: 5-30 % inside the band).
    ``stribeck``: Coulomb (Fc) and Stribeck (Fs 0.5-1.5 Fc) friction; variant 0 ``slow`` (slow reversals, vs
    0.05-0.2 of the speed range), variant 1 ``fast`` (a drive one way that never slows below 3-6 vs: the
    Stribeck term is invisible and the Coulomb friction a constant: ``shows_as`` offset).
    ``gravity``: a pendulum ``J w' = tau - b w - G sin(theta)`` (0.3-3 Hz, damping 0.05-0.4), swings
    1.2-2.5 rad (variant 0) or 0.08-0.18 rad (variant 1: gravity is a spring there).
    ``duffing``: a mass on a spring (0.5-10 Hz) and a hardening ``k3 x^3`` to ground, 0.5-3 times the linear
    force at the largest excursion (0.5-3), measured by position only (the CLI then derives).
    ``two_tank``: ``A1 h1' = u - a1 sqrt(h1)``, ``A2 h2' = a1 sqrt(h1) - a2 sqrt(h2)`` (time constants
    T/60-T/10, levels 0.2-2 at the mean inflow, the inflow swinging 50-90 % about it), truth
    ``sqrt_outflow`` on h1 and h2 (``a`` = a_i/A_i, the coefficient of sqrt in the level's own row); variant
    1 adds an overflow, ``hard_stop`` (``bound``, 0.6-0.85 of the level's peak without it) on one tank.
    ``euler``: one of saturation_deadzone, gravity, duffing, two_tank (by index) integrated by forward Euler
    at the sample step or 2-10 substeps (at least enough for a stable step), as an FMU's fixed-step solver.

Every effect in ``spec["effects"]`` carries its ``visibility``, measured here from noise-free runs
(:func:`_family_system.visibility`: its non-linear part over the noise); ``spec["visibility"]`` holds the
combined and the largest. A pair's effects also carry ``visibility_alone`` (each record diagnosed alone).

Example
-------
>>> rec = make_family_record(205, max_samples=2000)  # doctest: +SKIP
>>> rec.spec["family"], [e["name"] for e in rec.spec["effects"]]  # doctest: +SKIP
('two_tank', ['sqrt_outflow', 'sqrt_outflow'])
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import _family_system as fs
import independent_plants as ip
import numpy as np

__all__ = ["FAMILIES", "FIRST_INDEX", "family_of", "make_family_record", "PairRecord"]

FIRST_INDEX = 200
FAMILIES = ("one_way_pair", "saturation_deadzone", "stribeck", "gravity", "duffing", "two_tank", "euler")
VARIANTS = {"one_way_pair": ("pair",), "saturation_deadzone": ("saturation", "deadzone"),
            "stribeck": ("slow", "fast"), "gravity": ("large", "small"), "duffing": ("large",),
            "two_tank": ("sqrt", "overflow")}
EULER_INNER = ("saturation_deadzone", "gravity", "duffing", "two_tank")
MAIN = {"coulomb_friction": "Fc", "stribeck": "Fs", "viscous_asymmetry": "d", "offset": "F0", "gravity": "G",
        "cubic_stiffness": "k3", "saturation": "level", "deadzone": "width", "sqrt_outflow": "a",
        "hard_stop": "bound"}
#: Written into truth.json's spec; a family record of another version is generated again.
FAMILIES_VERSION = 1
SIZES = {"samples": (5_000, 50_000), "duration_s": (10.0, 120.0), "rate_hz": (100.0, 5000.0)}


def family_of(index: int) -> dict[str, Any]:
    """Record `index`'s family, variant and (Euler records) the family it integrates."""
    if index < FIRST_INDEX:
        raise ValueError(f"records below {FIRST_INDEX} are independent_plants.make_record's")
    j = index - FIRST_INDEX
    family = FAMILIES[j % len(FAMILIES)]
    inner = EULER_INNER[(j // (2 * len(FAMILIES))) % len(EULER_INNER)] if family == "euler" else family
    variants = VARIANTS[inner]
    return {"family": family, "inner": inner, "variant": variants[(j // len(FAMILIES)) % len(variants)]}


# ---------------------------------------------------------------------------------------------- records
@dataclass
class PairRecord(ip.Record):
    """Two records of one plant (``train.csv`` and ``train_b.csv``, each with its twin), diagnosed together."""

    second: ip.Record | None = None

    def write(self, folder: str | Path) -> Path:
        """Write the second record's files (``*_b``) and then the first's (``truth.json`` last)."""
        import pandas as pd

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for name, cols in (("train_b", self.second.train), ("heldout_b", self.second.heldout)):
            tmp = folder / f".{name}.csv.tmp"
            pd.DataFrame(cols).to_csv(tmp, index=False, float_format="%.12g")
            tmp.replace(folder / f"{name}.csv")
        np.savez(folder / "heldout_b_clean.npz", **self.second.heldout_clean)
        return super().write(folder)


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _sizes(rng: np.random.Generator, max_samples: int | None) -> tuple[float, int]:
    """The sample step and the number of intervals."""
    n = _loguniform(rng, *SIZES["samples"])
    duration = _loguniform(rng, *SIZES["duration_s"])
    rate = float(np.clip(n / duration, *SIZES["rate_hz"]))
    n = int(np.clip(round(rate * duration), *SIZES["samples"]))
    if max_samples is not None and n > max_samples:  # shortened, then the rate lowered, never below 5 s
        duration = max(5.0, max_samples / rate)
        rate = min(rate, max_samples / duration)
        n = int(max_samples)
    return 1.0 / rate, n


def _steps(rng: np.random.Generator, n: int, dt: float, hold: tuple[float, float], level) -> np.ndarray:
    """Held levels ``level(rng)``, each for a drawn ``hold`` (s, at least 3 samples)."""
    out = np.empty(n)
    k = 0
    while k < n:
        m = max(3, int(round(rng.uniform(*hold) / dt)))
        out[k:k + m] = level(rng)
        k += m
    return out


def _scale(system: fs.System, u0: np.ndarray, dt: float, x0: np.ndarray, measure, target: float,
           n_cal: int) -> float:
    """The factor on the commands `u0` that brings ``measure(states)`` near `target` (secant steps on the
    record's first `n_cal` samples)."""
    s, prev = 1.0, None
    for _ in range(10):
        try:
            got = measure(fs.simulate(system, s * u0[:n_cal], dt, x0))
        except RuntimeError:
            got = math.inf
        if not math.isfinite(got):
            prev, s = None, s / 4
            continue
        if abs(math.log(max(got, 1e-300) / target)) < 0.03:
            break
        slope = 1.0
        if prev is not None and prev[1] > 0 and got > 0 and prev[0] != s:
            slope = float(np.clip(math.log(got / prev[1]) / math.log(s / prev[0]), 0.3, 3.0))
        prev, s = (s, got), s * (target / max(got, 1e-300)) ** (1.0 / slope)
    return s


def _mass(rng: np.random.Generator, dt: float, n: int, spring: bool) -> tuple[dict, float]:
    """A mass's parameters and its characteristic frequency (Hz)."""
    duration = n * dt
    m = _loguniform(rng, 1e-2, 10.0)
    f_b = _loguniform(rng, min(max(0.05, 2.0 / duration), 1.0), 2.0)
    f_n = _loguniform(rng, 0.5, min(10.0, 1.0 / (50 * dt))) if spring else 0.0
    return {"m": m, "b": m * 2 * math.pi * f_b, "k": m * (2 * math.pi * f_n) ** 2}, max(f_b, f_n, 0.5)


def _stable_substeps(omega: float, zeta: float, dt: float, drawn: int) -> int:
    """Forward Euler's substeps: `drawn`, raised until the step is below ``zeta / omega``."""
    return max(drawn, int(math.ceil(dt * omega / max(zeta, 1e-3))))


# ---------------------------------------------------------------------------------------------- families
def _one_way_pair(rng, dt, n, variant, integrator, index) -> dict:
    p, _ = _mass(rng, dt, n, spring=False)
    tau = p["m"] / p["b"]
    u_max = p["m"] * _loguniform(rng, 0.5, 20.0)
    fc = rng.uniform(0.15, 0.4) * u_max
    f0 = float(rng.choice([-1.0, 1.0])) * rng.uniform(0.2, 0.6) * fc
    d = rng.uniform(0.2, 0.6) * p["b"]
    eps = 1e-3 * u_max / p["b"]  # a sharp switch: 0.1 % of the speed scale
    effects = [{"name": "coulomb_friction", "at": "v", "row": "v", "params": {"Fc": fc, "eps": eps}},
               {"name": "viscous_asymmetry", "at": "v", "row": "v", "params": {"d": d}},
               {"name": "offset", "at": "constant", "row": "v", "params": {"F0": f0}}]

    def one_way(sign: float, seed: list[int]) -> np.ndarray:
        u_min = max(0.0, -sign * f0) * 1.05 + 0.02 * fc  # the load never turns the motion back
        stick = fc - sign * f0  # below this the mass comes to rest

        def level(r):
            return sign * r.uniform(max(1.2 * stick, u_min), u_max)  # moving from the first step on
        return _steps(np.random.default_rng(seed), n, dt, (0.5 * tau, 3 * tau), level)

    parts = [{"u": one_way(s, [index, 1 + 10 * j]), "u_twin": one_way(s, [index, 3 + 10 * j]), "x0": np.zeros(2),
              "direction": s} for j, s in enumerate((1.0, -1.0))]
    for e in effects:
        e["shows_alone_as"] = "offset"  # in either record alone
    return {"system": fs.System("mass", p, effects, integrator), "parts": parts, "excitation": "one-way steps"}


def _saturation_deadzone(rng, dt, n, variant, integrator, index) -> dict:
    p, f_c = _mass(rng, dt, n, spring=bool(rng.uniform() < 0.5))
    kind = str(rng.choice(["multisine", "steps"]))
    f_lo, f_hi = max(2.0 / (n * dt), 0.05), min(1 / (10 * dt), 3 * f_c)
    u0, u0_twin = (ip.excitation(kind, np.random.default_rng([index, s]), n, dt, f_lo, f_hi) for s in (1, 3))
    system = fs.System("mass", p, [], integrator)
    if integrator["method"] == "euler":
        zeta = p["b"] / (2 * math.sqrt(p["m"] * p["k"])) if p["k"] else 1.0
        integrator["substeps"] = _stable_substeps(math.sqrt(p["k"] / p["m"]) + p["b"] / p["m"], min(zeta, 1.0),
                                                  dt, integrator["substeps"])
    scale = _scale(system, u0, dt, np.zeros(2), lambda s: float(np.ptp(s[:, 0])), _loguniform(rng, 1.0, 4.0),
                   min(n, 4000))
    u, u_twin = scale * u0, scale * u0_twin
    size = np.abs(np.concatenate([u, u_twin]))
    if variant == "saturation":  # clipping 5-40 % of the samples
        level = float(np.quantile(size, 1 - rng.uniform(0.05, 0.4)))
        eff = {"name": "saturation", "at": "u", "row": None, "params": {"level": level}}
    else:  # 5-30 % of the samples inside the dead band
        width = float(np.quantile(size, rng.uniform(0.05, 0.3)))
        eff = {"name": "deadzone", "at": "u", "row": None, "params": {"width": width}}
    return {"system": system.with_effects([eff]), "parts": [{"u": u, "u_twin": u_twin, "x0": np.zeros(2)}],
            "excitation": kind}


def _stribeck(rng, dt, n, variant, integrator, index) -> dict:
    p, f_c = _mass(rng, dt, n, spring=variant == "slow" and bool(rng.uniform() < 0.5))
    f_lo = max(2.0 / (n * dt), 0.05)
    if variant == "slow":
        kind = str(rng.choice(["multisine", "steps"]))
        u0, u0_twin = (ip.excitation(kind, np.random.default_rng([index, s]), n, dt, f_lo,
                                     min(1 / (10 * dt), max(3 * f_lo, f_c))) for s in (1, 3))
        base = fs.System("mass", p, [], integrator)
        scale = _scale(base, u0, dt, np.zeros(2), lambda s: float(np.ptp(s[:, 0])), _loguniform(rng, 1.0, 4.0),
                       min(n, 4000))
        u, u_twin = scale * u0, scale * u0_twin
        v_range = float(np.ptp(fs.simulate(base, u[:min(n, 4000)], dt)[:, 1]))
        fc = rng.uniform(0.1, 0.4) * float(np.sqrt(np.mean(u ** 2)))
        vs = rng.uniform(0.05, 0.2) * v_range
        x0 = np.zeros(2)
    else:  # one way, never slower than a few vs
        kind = "one-way multisine"
        sign = float(rng.choice([-1.0, 1.0]))
        u_mean = p["m"] * _loguniform(rng, 0.5, 20.0)
        fc = rng.uniform(0.2, 0.5) * u_mean
        ripple = rng.uniform(0.2, 0.5) * (u_mean - fc)
        u0, u0_twin = (ip.excitation("multisine", np.random.default_rng([index, s]), n, dt, f_lo,
                                     min(1 / (10 * dt), 5 * f_c)) for s in (1, 3))
        u, u_twin = (sign * (u_mean + ripple * x / np.max(np.abs(x))) for x in (u0, u0_twin))
        x0 = np.array([0.0, sign * (u_mean - fc) / p["b"]])
        coulomb = fs.System("mass", p, [{"name": "coulomb_friction", "at": "v", "row": "v",
                                         "params": {"Fc": fc, "eps": 1e-4 * abs(x0[1])}}], integrator)
        slowest = min(float(np.min(np.abs(fs.simulate(coulomb, w, dt, x0)[:, 1]))) for w in (u, u_twin))
        vs = slowest / rng.uniform(3.0, 6.0)
        v_range = abs(x0[1])
    fs_ = rng.uniform(0.5, 1.5) * fc
    eps = 1e-4 * v_range
    effects = [{"name": "coulomb_friction", "at": "v", "row": "v", "params": {"Fc": fc, "eps": eps}},
               {"name": "stribeck", "at": "v", "row": "v", "params": {"Fs": fs_, "vs": vs, "eps": eps}}]
    if variant == "fast":
        effects[0]["shows_as"] = "offset"
    return {"system": fs.System("mass", p, effects, integrator), "parts": [{"u": u, "u_twin": u_twin, "x0": x0}],
            "excitation": kind}


def _gravity(rng, dt, n, variant, integrator, index) -> dict:
    J = _loguniform(rng, 1e-3, 1.0)
    f0 = _loguniform(rng, 0.3, min(3.0, 1 / (50 * dt)))
    zeta = rng.uniform(0.1 if integrator["method"] == "euler" else 0.05, 0.4)
    omega0 = 2 * math.pi * f0
    p = {"m": J, "b": 2 * zeta * J * omega0, "k": 0.0}
    if integrator["method"] == "euler":
        integrator["substeps"] = _stable_substeps(omega0, zeta, dt, integrator["substeps"])
    kind = str(rng.choice(["multisine", "steps"]))
    f_lo = max(2.0 / (n * dt), 0.05)
    u0, u0_twin = (ip.excitation(kind, np.random.default_rng([index, s]), n, dt, f_lo,
                                 min(1 / (10 * dt), 2 * f0)) for s in (1, 3))
    eff = {"name": "gravity", "at": "theta", "row": "omega", "params": {"G": J * omega0 ** 2}}
    system = fs.System("pendulum", p, [eff], integrator)
    lo, hi = (1.2, 2.5) if variant == "large" else (0.08, 0.18)
    target = rng.uniform(lo, hi)

    def swing(s):
        return float(np.max(np.abs(s[:, 0])))
    scale = _scale(system, u0, dt, np.zeros(2), swing, target, n)
    u, u_twin = scale * u0, scale * u0_twin
    for _ in range(6):  # the bound holds on the whole record and its twin
        got = max(swing(fs.simulate(system, w, dt)) for w in (u, u_twin))
        if variant == "small" and got >= 0.2:
            u, u_twin = u * 0.17 / got, u_twin * 0.17 / got
        elif variant == "large" and got <= 1.0:
            u, u_twin = u * 1.2 / got, u_twin * 1.2 / got
        else:
            break
    return {"system": system, "parts": [{"u": u, "u_twin": u_twin, "x0": np.zeros(2)}], "excitation": kind}


def _duffing(rng, dt, n, variant, integrator, index) -> dict:
    m = _loguniform(rng, 1e-2, 10.0)
    f_n = _loguniform(rng, 0.5, min(10.0, 1 / (50 * dt)))
    zeta = rng.uniform(0.1 if integrator["method"] == "euler" else 0.05, 0.3)
    k = m * (2 * math.pi * f_n) ** 2
    p = {"m": m, "b": 2 * zeta * math.sqrt(k * m), "k": k}
    amp = rng.uniform(0.5, 3.0)
    c = rng.uniform(0.5, 3.0)
    if integrator["method"] == "euler":
        integrator["substeps"] = _stable_substeps(math.sqrt(k * (1 + 3 * c) / m), zeta, dt, integrator["substeps"])
    kind = str(rng.choice(["multisine", "steps"]))
    f_lo = max(2.0 / (n * dt), 0.05)
    u0, u0_twin = (ip.excitation(kind, np.random.default_rng([index, s]), n, dt, f_lo,
                                 min(1 / (10 * dt), 2 * f_n)) for s in (1, 3))
    eff = {"name": "cubic_stiffness", "at": "x", "row": "v", "params": {"k3": c * k / amp ** 2}}
    system = fs.System("mass", p, [eff], integrator)
    scale = _scale(system, u0, dt, np.zeros(2), lambda s: float(np.max(np.abs(s[:, 0]))), amp, min(n, 4000))
    return {"system": system, "parts": [{"u": scale * u0, "u_twin": scale * u0_twin, "x0": np.zeros(2)}],
            "excitation": kind, "positions_only": True}


def _two_tank(rng, dt, n, variant, integrator, index) -> dict:
    duration = n * dt
    h01, h02 = _loguniform(rng, 0.2, 2.0), _loguniform(rng, 0.2, 2.0)
    tau1, tau2 = (_loguniform(rng, duration / 60, duration / 10) for _ in range(2))
    A1 = _loguniform(rng, 0.2, 5.0)
    a1 = 2 * A1 * math.sqrt(h01) / tau1
    q0 = a1 * math.sqrt(h01)
    a2 = q0 / math.sqrt(h02)
    A2 = tau2 * q0 / (2 * h02)
    p = {"A1": A1, "A2": A2, "a1": a1, "a2": a2, "h1_mean": h01, "h2_mean": h02}
    swing = rng.uniform(0.5, 0.9)
    kind = str(rng.choice(["multisine", "steps"]))

    def inflow(seed):
        r = np.random.default_rng(seed)
        if kind == "steps":
            s = _steps(r, n, dt, (0.3 * tau1, 2 * tau1), lambda g: g.uniform(-1, 1))
        else:
            s = ip.excitation("multisine", r, n, dt, max(2.0 / duration, 1e-3), 2.0 / min(tau1, tau2))
            s = s / np.max(np.abs(s))
        return q0 * (1 + swing * s)
    u, u_twin = inflow([index, 1]), inflow([index, 3])
    effects = [{"name": "sqrt_outflow", "at": "h1", "row": "h1", "params": {"a": a1 / A1, "a_flow": a1, "A": A1}},
               {"name": "sqrt_outflow", "at": "h2", "row": "h2", "params": {"a": a2 / A2, "a_flow": a2, "A": A2}}]
    system = fs.System("tanks", p, effects, integrator)
    x0 = np.array([h01, h02])
    if variant == "overflow":
        r = int(rng.integers(2))
        peak = min(float(np.max(fs.simulate(system, w, dt, x0)[:, r])) for w in (u, u_twin))
        bound = float(max(rng.uniform(0.6, 0.85) * peak, 1.05 * x0[r]))
        effects.append({"name": "hard_stop", "at": f"h{r + 1}", "row": f"h{r + 1}", "params": {"bound": bound}})
    return {"system": fs.System("tanks", p, effects, integrator), "parts": [{"u": u, "u_twin": u_twin, "x0": x0}],
            "excitation": kind, "positions_only": False}


BUILDERS = {"one_way_pair": _one_way_pair, "saturation_deadzone": _saturation_deadzone, "stribeck": _stribeck,
            "gravity": _gravity, "duffing": _duffing, "two_tank": _two_tank}


# ---------------------------------------------------------------------------------------------- assembly
def make_family_record(index: int, *, max_samples: int | None = None) -> ip.Record:
    """Record `index` (>= 200) of its family (:func:`family_of`), with its twin and its effects' visibility."""
    which = family_of(index)
    rng = np.random.default_rng([index, 0])
    dt, n = _sizes(rng, max_samples)
    integrator = {"method": "lsoda"}
    if which["family"] == "euler":
        integrator = {"method": "euler", "substeps": int(rng.choice([1, 1, 2, 5, 10]))}
    noise_frac = _loguniform(rng, 0.002, 0.05)
    draft = BUILDERS[which["inner"]](rng, dt, n, which["variant"], integrator, index)
    system: fs.System = draft["system"]
    positions_only = draft.get("positions_only", system.kind != "tanks" and bool(rng.uniform() < 0.25))
    pos, vel, inp = fs.NAMES[system.kind]
    written = [pos] if positions_only else [pos, vel]
    t = np.arange(n + 1) * dt
    records, runs, sigmas = [], [], []
    for j, part in enumerate(draft["parts"]):
        clean = fs.simulate(system, part["u"], dt, part["x0"])
        clean_twin = fs.simulate(system, part["u_twin"], dt, part["x0"])
        sigma = {s: noise_frac * float(np.ptp(clean[:, system.states.index(s)])) for s in written}
        cols = {}
        for name, states, u, seed in (("train", clean, part["u"], 2), ("heldout", clean_twin, part["u_twin"], 4)):
            noise = np.random.default_rng([index, seed + 10 * j])
            cols[name] = {"time": t, **{s: states[:, system.states.index(s)]
                                        + sigma[s] * noise.standard_normal(n + 1) for s in written},
                          inp: np.append(u, u[-1])}
        u_twin_col = np.append(part["u_twin"], part["u_twin"][-1])
        twin_clean = {"time": t, **{s: clean_twin[:, i] for i, s in enumerate(system.states)}, inp: u_twin_col}
        records.append((cols["train"], cols["heldout"], twin_clean))
        runs.append({"u": part["u"], "x0": part["x0"], "dt": dt, "states": clean,
                     "written": [system.states.index(s) for s in written], "sigma": [sigma[s] for s in written]})
        sigmas.append(sigma)
    vis = fs.visibility(system, runs)
    alone = [fs.visibility(system, [r]) for r in runs] if len(runs) > 1 else None
    effects = []
    for i, e in enumerate(system.effects):
        e = {**e, "main": MAIN[e["name"]], "main_value": e["params"][MAIN[e["name"]]], "ratio": None,
             "visibility": vis["effects"][i]}
        if alone is not None:
            e["visibility_alone"] = [a["effects"][i] for a in alone]
        effects.append(e)
    spec = {"index": index, "family": which["family"], "inner_family": which["inner"], "variant": which["variant"],
            "families_version": FAMILIES_VERSION, "plant": {"kind": system.kind, **system.p},
            "names": {"position": pos, "velocity": vel, "input": inp}, "integrator": system.integrator,
            "dt": dt, "rate_hz": 1.0 / dt, "duration_s": n * dt, "samples": n + 1, "excitation": draft["excitation"],
            "x0": [list(map(float, part["x0"])) for part in draft["parts"]], "positions_only": positions_only,
            "noise_frac": noise_frac, "sigma": sigmas[0], "effects": effects,
            "visibility": {"combined": vis["combined"], "largest": max(vis["effects"], default=0.0)},
            "combined_ratio": vis["combined"], "pid": None}
    if alone is not None:
        spec["sigma_b"] = sigmas[1]
        spec["directions"] = [part["direction"] for part in draft["parts"]]
        spec["visibility_alone"] = [{"combined": a["combined"], "largest": max(a["effects"])} for a in alone]
    cli = _cli(system, positions_only, pair=len(records) > 1)
    first = ip.Record(index, spec, *records[0], cli)
    if len(records) == 1:
        return first
    return PairRecord(index, spec, *records[0], cli, second=ip.Record(index, spec, *records[1], cli))


def _cli(system: fs.System, positions_only: bool, pair: bool) -> dict[str, Any]:
    """How the record is diagnosed: its states, input, derived positions and data files."""
    pos, vel, inp = fs.NAMES[system.kind]
    if system.kind == "tanks":
        cli = {"states": [pos, vel], "input": inp, "derive": [], "velocity_names": {}}
    else:
        cli = {"states": [pos, f"{pos}_dot"] if positions_only else [pos, vel], "input": inp,
               "derive": [pos] if positions_only else [], "velocity_names": {vel: f"{pos}_dot" if positions_only
                                                                             else vel}}
    cli["data"] = ["train.csv", "train_b.csv"] if pair else ["train.csv"]
    cli["heldout_clean"] = ["heldout_clean.npz", "heldout_b_clean.npz"] if pair else ["heldout_clean.npz"]
    if pair:
        cli["alone"] = ["train.csv", "train_b.csv"]
    return cli
