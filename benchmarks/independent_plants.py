"""An independent simulator of the plants `cosim diagnose` is judged on: its own equations, scipy's solve_ivp.

Nothing here imports cosim's model code or the bundled FMU: the plants, the effects, the excitations, the PID
and the noise are written for this benchmark, so that a default tuned to cosim's own simulator shows up as a
failure here. Records are plain CSV (a ``time`` column, then the signals), as a user's logger writes them.

Plants
    ``single``: a mass, states ``x`` (position) and ``v`` (velocity), input force ``u``::

        m v' = u_eff - b v - k x + F_effects(x, v)          (k = 0 for half the records: no spring to ground)

    ``two_mass``: motor ``theta_m, omega_m`` and load ``theta_L, omega_L`` on a shaft, input torque ``Tm``::

        T_s = k * tw + c * (omega_m - omega_L) [+ k3 tw^3]    tw = theta_m - theta_L (dead band: backlash)
        Jm omega_m' = Tm_eff - bm omega_m - T_s + F_motor(theta_m, omega_m)
        JL omega_L' = T_s - bL omega_L + F_load(theta_L, omega_L)

    Inertias over three decades (m 1e-2..10 kg, Jm 1e-4..1e-1 kg m^2), stiffness set by a natural or shaft
    frequency drawn below the record's Nyquist band (so k spans more than three decades too).

Effects (named as cosim's catalogue names them; the main parameter, compared with cosim's, in brackets)
    ``coulomb_friction`` [Fc]: ``-Fc tanh(v/eps)`` with eps = 1e-4 of the speed range (a stiff, sharp switch);
    ``stribeck`` [Fs]: ``-Fs exp(-(v/vs)^2) tanh(v/eps)`` (stiction in excess of the viscous law);
    ``viscous_asymmetry`` [d]: ``-d |v|`` (viscous b+d for v > 0, b-d for v < 0);
    ``cogging`` [amplitude]: ``A sin(n x + phase)``, n whole periods per unit of position;
    ``gravity`` [G]: ``-G sin(x)``; ``offset`` [F0]: ``+F0``;
    ``backlash`` [half_width]: the shaft's stiffness acts on ``tw - clip(tw, w)`` (two-mass only);
    ``cubic_stiffness`` [k3 > 0]: ``+k3 tw^3`` in the shaft torque, hardening (two-mass only: cosim attaches
    it to a pair);
    ``deadzone`` [width]: the plant sees ``u - clip(u, w)``; ``saturation`` [level]: ``clip(u, level)``;
    ``delay`` [delay_s]: the plant sees the (held) input ``delay_s`` later;
    ``none``.
    Every force is in the input's units (N or N m). Each effect's size is calibrated (secant steps on the
    logarithm of its parameter) so that its contribution, the RMS difference of the written signals between
    runs with and without it (same input; same reference in closed loop), is a drawn 3-12 times the noise's
    standard deviation (accepted in 2-20), taken per signal and averaged in square; the noise is that of the
    record with the effect (a share of its range, below).
    An effect the record cannot show as itself is replaced, as one out of reach of the calibration is, by
    another drawn at random (four tries in all), so that the table scores diagnoses, not records no tool could
    answer: a linear model must not take up its whole force over the record (the share it leaves,
    :func:`nonlinear_share`, is above :data:`LINEAR_SHARE`: a dead zone under an input of one magnitude is a
    gain, a Coulomb friction above every command a viscous one), and a cogging's position must turn through at
    least :data:`MIN_PERIODS` of its periods (the issue's floor for a periodic candidate; a strong cogging can
    trap the plant in one well).

Records
    200 Hz-5 kHz, 5-60 s (a record longer than ``max_samples`` is shortened, then its rate lowered, never
    below 5 s); noise 0.2-5 % of each written state's range (as written, with its effects), white Gaussian,
    per signal (the input is a command, written exactly); a quarter of the records write positions only
    (then ``--derive POS``);
    excitation multisine, PRBS, steps, or closed loop (a PID on the position, sampled at the record rate,
    tracking a reference). Record ``i`` is drawn from seed ``i``, fully reproducible; its held-out twin is
    the same plant and effects with another excitation (and noise) seed. Records 200 on are the families of
    ``independent_families.py`` (one-way pairs, saturation and dead zone, Stribeck, gravity, Duffing, two
    tanks, fixed-step Euler), each with its effects' visibility measured from noise-free runs.

Integration: every sample interval separately (the input is held, so the right-hand side is smooth inside it)
with ``solve_ivp(method="LSODA")``'s numbers (stiff-switching: the friction's sharp tanh), ``max_step`` the
interval, through :func:`_held_lsoda.lsoda_interval` (the same bits at half the time: one solver reused).

Example
-------
>>> rec = make_record(3, max_samples=2000)
>>> rec.write("/tmp/rec3")  # doctest: +SKIP
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from _held_lsoda import lsoda_interval

__all__ = ["EFFECT_NAMES", "Plant", "Record", "make_record", "simulate", "PID"]

#: cosim's catalogue names, and "none".
EFFECT_NAMES = ("coulomb_friction", "stribeck", "viscous_asymmetry", "backlash", "deadzone", "saturation",
                "cogging", "gravity", "offset", "delay", "cubic_stiffness")
SINGLE_EFFECTS = tuple(e for e in EFFECT_NAMES if e not in ("backlash", "cubic_stiffness"))
MAIN_PARAMETER = {"coulomb_friction": "Fc", "stribeck": "Fs", "viscous_asymmetry": "d", "backlash": "half_width",
                  "deadzone": "width", "saturation": "level", "cogging": "amplitude", "gravity": "G",
                  "offset": "F0", "delay": "delay_s", "cubic_stiffness": "k3"}
DEFAULT_MAX_SAMPLES = 30_000
RATIO_TARGET = (3.0, 12.0)  # the drawn contribution / noise
RATIO_ACCEPT = (2.0, 20.0)
#: An effect whose force a linear model takes up to this share (RMS) is a linear change over the record.
LINEAR_SHARE = 1e-3
#: Least periods of a cogging over its position's range in the record.
MIN_PERIODS = 2.0
#: Written into truth.json; a record of another version is generated again. Version 3: the noise is a share
#: of the range of each signal as written (with its effects), no longer of the run without them.
GENERATOR_VERSION = 3


# ---------------------------------------------------------------------------------------------- plants
@dataclass(frozen=True)
class Plant:
    """A plant: ``kind`` "single" or "two_mass" and its parameters (SI, forces in the input's units)."""

    kind: str
    p: dict[str, float]

    @property
    def states(self) -> tuple[str, ...]:
        return ("x", "v") if self.kind == "single" else ("theta_m", "omega_m", "theta_L", "omega_L")

    @property
    def positions(self) -> tuple[str, ...]:
        return ("x",) if self.kind == "single" else ("theta_m", "theta_L")

    @property
    def input(self) -> str:
        return "u" if self.kind == "single" else "Tm"

    @property
    def velocity_of(self) -> dict[str, str]:
        return {"x": "v"} if self.kind == "single" else {"theta_m": "omega_m", "theta_L": "omega_L"}


def _dz(x: float, w: float) -> float:
    """Dead zone: ``x - clip(x, -w, w)``."""
    return x - w if x > w else (x + w if x < -w else 0.0)


def _force_terms(effects: list[dict], position: str, velocity: str):
    """The effects' force on the row of `velocity` as a function ``f(x, v)`` (None when there is none)."""
    parts = []
    for e in effects:
        q = e["params"]
        if e.get("row") != velocity:
            continue
        name = e["name"]
        if name == "coulomb_friction":
            parts.append(lambda x, v, Fc=q["Fc"], eps=q["eps"]: -Fc * math.tanh(v / eps))
        elif name == "stribeck":
            parts.append(lambda x, v, Fs=q["Fs"], vs=q["vs"], eps=q["eps"]:
                         -Fs * math.exp(-(v / vs) ** 2) * math.tanh(v / eps))
        elif name == "viscous_asymmetry":
            parts.append(lambda x, v, d=q["d"]: -d * abs(v))
        elif name == "cogging":
            parts.append(lambda x, v, A=q["amplitude"], n=q["periods"], ph=q["phase"]: A * math.sin(n * x + ph))
        elif name == "gravity":
            parts.append(lambda x, v, G=q["G"]: -G * math.sin(x))
        elif name == "offset":
            parts.append(lambda x, v, F0=q["F0"]: F0)
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    return lambda x, v: sum(f(x, v) for f in parts)


def _rhs(plant: Plant, effects: list[dict]):
    """The right-hand side ``f(t, y, u)`` of `plant` with `effects` (u: the input the plant sees)."""
    p = plant.p
    if plant.kind == "single":
        m, b, k = p["m"], p["b"], p["k"]
        fx = _force_terms(effects, "x", "v")
        if fx is None:
            return lambda t, y, u: (y[1], (u - b * y[1] - k * y[0]) / m)
        return lambda t, y, u: (y[1], (u - b * y[1] - k * y[0] + fx(y[0], y[1])) / m)
    Jm, JL, k, c, bm, bL = p["Jm"], p["JL"], p["k"], p["c"], p["bm"], p["bL"]
    fm = _force_terms(effects, "theta_m", "omega_m") or (lambda x, v: 0.0)
    fl = _force_terms(effects, "theta_L", "omega_L") or (lambda x, v: 0.0)
    w = next((e["params"]["half_width"] for e in effects if e["name"] == "backlash"), 0.0)
    k3 = next((e["params"]["k3"] for e in effects if e["name"] == "cubic_stiffness"), 0.0)

    def f(t, y, u):
        tw = y[0] - y[2]
        ts = k * (_dz(tw, w) if w else tw) + c * (y[1] - y[3]) + k3 * tw ** 3
        return (y[1], (u - bm * y[1] - ts + fm(y[0], y[1])) / Jm, y[3], (ts - bL * y[3] + fl(y[2], y[3])) / JL)
    return f


def _input_map(effects: list[dict]):
    """The static input effects (dead zone, saturation) as ``g(u)``, and the delay in s."""
    dead = next((e["params"]["width"] for e in effects if e["name"] == "deadzone"), None)
    sat = next((e["params"]["level"] for e in effects if e["name"] == "saturation"), None)
    delay = next((e["params"]["delay_s"] for e in effects if e["name"] == "delay"), 0.0)

    def g(u: float) -> float:
        if dead is not None:
            u = _dz(u, dead)
        if sat is not None:
            u = min(max(u, -sat), sat)
        return u
    return g, delay


# ---------------------------------------------------------------------------------------------- PID
@dataclass
class PID:
    """A discrete PID on a position, sampled at the record rate: ``u = Kp e + Ki sum(e) dt - Kd d_f``, the
    derivative on the measurement through a first-order filter of time constant ``tau``."""

    kp: float
    ki: float
    kd: float
    tau: float
    dt: float
    _i: float = 0.0
    _d: float = 0.0
    _y: float | None = None

    def step(self, r: float, y: float) -> float:
        e = r - y
        self._i += self.ki * e * self.dt
        raw = 0.0 if self._y is None else (y - self._y) / self.dt
        a = self.dt / (self.tau + self.dt)
        self._d += a * (raw - self._d)
        self._y = y
        return self.kp * e + self._i - self.kd * self._d


# ---------------------------------------------------------------------------------------------- simulation
def simulate(plant: Plant, effects: list[dict], dt: float, n: int, *, u: np.ndarray | None = None,
             reference: np.ndarray | None = None, pid: dict | None = None, x0: np.ndarray | None = None,
             rtol: float = 1e-7, atol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """States at ``k dt`` (n+1 rows) and the commanded input (n rows, held over each step), open loop (`u`)
    or closed loop (a PID, settings `pid`, on the first position tracking `reference`).

    Each step is integrated on its own by LSODA (``_held_lsoda``, solve_ivp's bits): the input is held, so the
    right-hand side is smooth inside it; a delay splits a step where the delayed input changes.
    """
    f = _rhs(plant, effects)
    g, delay = _input_map(effects)
    d_int = int(math.floor(delay / dt + 1e-12))
    frac = delay / dt - d_int
    y = np.zeros(len(plant.states)) if x0 is None else np.asarray(x0, dtype=float).copy()
    out = np.empty((n + 1, len(y)))
    out[0] = y
    cmd = np.empty(n)
    ctrl = PID(**pid, dt=dt) if pid is not None else None

    def held(j: int) -> float:
        return float(cmd[j]) if j >= 0 else 0.0

    for k in range(n):
        cmd[k] = ctrl.step(float(reference[k]), float(y[0])) if ctrl is not None else float(u[k])
        t0, t1 = k * dt, (k + 1) * dt
        if delay > 0.0 and frac > 1e-9:
            pieces = [(t0, t0 + frac * dt, held(k - d_int - 1)), (t0 + frac * dt, t1, held(k - d_int))]
        else:
            pieces = [(t0, t1, held(k - d_int))]
        for a, b, uk in pieces:
            ue = g(uk)
            try:
                # (the state as Python floats: the same arithmetic, without NumPy's per-scalar overhead)
                y = lsoda_interval(lambda t, s, ue=ue: f(t, s.tolist(), ue), a, b, y, rtol=rtol, atol=atol,
                                   max_step=b - a, min_step=1e-9 * (b - a))
            except RuntimeError as exc:
                raise RuntimeError(f"integration failed at t={a:.4g}: {exc}") from None
            if not np.all(np.isfinite(y)) or np.max(np.abs(y)) > 1e9:
                raise RuntimeError(f"integration diverged at t={a:.4g}")
        out[k + 1] = y
    return out, cmd


# ---------------------------------------------------------------------------------------------- excitation
def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def excitation(kind: str, rng: np.random.Generator, n: int, dt: float, f_lo: float, f_hi: float) -> np.ndarray:
    """A unit-size signal of `n` samples: "multisine" (24 log-spaced tones, random phases, unit RMS), "prbs"
    (+-1 held for a clock of about 1/(2.5 f_hi)) or "steps" (levels in [-1, 1] held 0.1-1.5 s)."""
    t = np.arange(n) * dt
    if kind == "multisine":
        freqs = np.geomspace(f_lo, f_hi, 24)
        phases = rng.uniform(0, 2 * np.pi, freqs.size)
        s = np.sin(2 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0)
        return s / np.sqrt(np.mean(s ** 2))
    if kind == "prbs":
        clock = max(1, int(round(1.0 / (2.5 * f_hi * dt))))
        bits = rng.choice([-1.0, 1.0], size=n // clock + 2)
        return np.repeat(bits, clock)[:n]
    if kind == "steps":
        out = np.empty(n)
        k = 0
        while k < n:
            hold = max(1, int(round(rng.uniform(0.1, 1.5) / dt)))
            out[k:k + hold] = rng.uniform(-1, 1)
            k += hold
        return out
    raise ValueError(f"unknown excitation {kind!r}")


def _reference(rng: np.random.Generator, n: int, dt: float, f_c: float) -> np.ndarray:
    """A closed loop's reference, unit size: smoothed random steps or a slow multisine."""
    if rng.uniform() < 0.5:
        raw = excitation("steps", rng, n, dt, 0, 0)
        a = dt / (1.0 / (2 * np.pi * f_c) + dt)  # two first-order filters at the loop's bandwidth
        out = np.empty(n)
        s1 = s2 = 0.0
        for k in range(n):
            s1 += a * (raw[k] - s1)
            s2 += a * (s1 - s2)
            out[k] = s2
        return out / max(np.max(np.abs(out)), 1e-12)
    s = excitation("multisine", rng, n, dt, max(2.0 / (n * dt), 0.05), f_c / 2)
    return s / np.max(np.abs(s))


# ---------------------------------------------------------------------------------------------- the record
@dataclass
class Record:
    """One benchmark record: the spec (truth), the training record and its held-out twin."""

    index: int
    spec: dict[str, Any]
    train: dict[str, np.ndarray]  # written columns (noisy states, exact input), "time" first
    heldout: dict[str, np.ndarray]
    heldout_clean: dict[str, np.ndarray]  # every state, noise-free, and the input
    cli: dict[str, Any] = field(default_factory=dict)

    def write(self, folder: str | Path) -> Path:
        """Write ``train.csv``, ``heldout.csv``, ``heldout_clean.npz`` and ``truth.json`` into `folder`."""
        import pandas as pd

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for name, cols in (("train", self.train), ("heldout", self.heldout)):
            tmp = folder / f".{name}.csv.tmp"
            pd.DataFrame(cols).to_csv(tmp, index=False, float_format="%.12g")
            tmp.replace(folder / f"{name}.csv")
        np.savez(folder / "heldout_clean.npz", **self.heldout_clean)
        tmp = folder / ".truth.json.tmp"
        tmp.write_text(json.dumps({"index": self.index, "generator": GENERATOR_VERSION, "spec": self.spec,
                                   "cli": self.cli}, indent=1) + "\n")
        tmp.replace(folder / "truth.json")
        return folder


def _draw_plant(rng: np.random.Generator, rate: float) -> tuple[Plant, float]:
    """A plant and its characteristic frequency (Hz) for the excitation band."""
    if rng.uniform() < 0.5:
        m = _loguniform(rng, 1e-2, 10.0)
        f_b = _loguniform(rng, 0.05, 2.0)
        spring = rng.uniform() < 0.5
        f_n = _loguniform(rng, 0.5, min(20.0, rate / 50)) if spring else 0.0
        p = {"m": m, "b": m * 2 * np.pi * f_b, "k": m * (2 * np.pi * f_n) ** 2}
        return Plant("single", p), max(f_n, f_b, 1.0)
    Jm = _loguniform(rng, 1e-4, 1e-1)
    JL = Jm * _loguniform(rng, 0.3, 3.0)
    f_r = _loguniform(rng, 3.0, min(40.0, rate / 25))
    Jeq = Jm * JL / (Jm + JL)
    k = (2 * np.pi * f_r) ** 2 * Jeq
    zeta = rng.uniform(0.02, 0.2)
    p = {"Jm": Jm, "JL": JL, "k": k, "c": 2 * zeta * math.sqrt(k * Jeq),
         "bm": Jm * 2 * np.pi * _loguniform(rng, 0.05, 1.0), "bL": JL * 2 * np.pi * _loguniform(rng, 0.05, 1.0)}
    return Plant("two_mass", p), f_r


def _pid_gains(plant: Plant, f_c: float) -> dict:
    wc = 2 * np.pi * f_c
    if plant.kind == "single":
        m, b, k = plant.p["m"], plant.p["b"], plant.p["k"]
    else:
        m, b, k = plant.p["Jm"] + plant.p["JL"], plant.p["bm"] + plant.p["bL"], 0.0
    kp = max(m * wc ** 2 - k, 0.1 * m * wc ** 2)
    return {"kp": kp, "ki": kp * wc / 8, "kd": max(1.4 * m * wc - b, 0.0), "tau": 1 / (10 * wc)}


def _choose_effects(rng: np.random.Generator, plant: Plant) -> list[str]:
    r = rng.uniform()
    pool = list(SINGLE_EFFECTS if plant.kind == "single" else EFFECT_NAMES)
    if r < 0.25:
        return []
    first = str(rng.choice(pool))
    if r < 0.40:
        # a second effect of another kind, not a second input-level one alongside the first
        exclusive = {"deadzone", "saturation", "delay"}
        rest = [e for e in pool if e != first and not (e in exclusive and first in exclusive)
                and {e, first} != {"coulomb_friction", "stribeck"}]
        return [first, str(rng.choice(rest))]
    return [first]


def _place(rng: np.random.Generator, plant: Plant, name: str) -> tuple[str, str | None]:
    """Where an effect acts: (cosim's attachment label, the velocity row its force enters)."""
    if plant.kind == "single":
        at = {"coulomb_friction": "v", "stribeck": "v", "viscous_asymmetry": "v", "cogging": "x", "gravity": "x",
              "offset": "constant", "deadzone": "u", "saturation": "u", "delay": "u"}[name]
        return at, "v" if at in ("v", "x", "constant") else None
    side = "m" if rng.uniform() < 0.5 else "L"
    vel, pos = f"omega_{side}", f"theta_{side}"
    if name in ("coulomb_friction", "stribeck", "viscous_asymmetry"):
        return vel, vel
    if name in ("cogging", "gravity"):
        return pos, vel
    if name == "offset":
        return "constant", vel
    if name in ("backlash", "cubic_stiffness"):
        return "theta_m-theta_L", None
    return "Tm", None


class _Run:
    """Simulations of one record's plant and excitation, with a given effect list."""

    def __init__(self, plant: Plant, dt: float, n: int, u: np.ndarray | None, reference: np.ndarray | None,
                 pid: dict | None, written: list[str], sigma: dict[str, float] | None = None,
                 noise_frac: float | None = None):
        self.plant, self.dt, self.n, self.u, self.ref, self.pid = plant, dt, n, u, reference, pid
        self.written, self.sigma, self.noise_frac = written, sigma, noise_frac

    def run(self, effects: list[dict], n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        n = self.n if n is None else n
        return simulate(self.plant, effects, self.dt, n, u=None if self.u is None else self.u[:n],
                        reference=None if self.ref is None else self.ref[:n], pid=self.pid)

    def ratio(self, base: np.ndarray, with_effect: np.ndarray) -> float:
        """The contribution over the noise: per written signal RMS(difference)/sigma, averaged in square.

        With ``noise_frac`` set, sigma is that share of each signal's range in `with_effect` (the noise of the
        record as it would be written with the effect); otherwise the fixed ``sigma``."""
        idx = [self.plant.states.index(s) for s in self.written]
        m = len(base)
        diff = with_effect[:m, idx] - base[:m, idx]
        if self.noise_frac is not None:
            sig = self.noise_frac * np.ptp(with_effect[:m, idx], axis=0)
        else:
            sig = np.array([self.sigma[s] for s in self.written])
        return float(np.sqrt(np.mean((np.sqrt(np.mean(diff ** 2, axis=0)) / sig) ** 2)))


def _effect_params(name: str, size: float, ctx: dict) -> dict[str, float]:
    """An effect's parameters at calibration variable `size` (its main parameter, or for a saturation the
    clipped share of the input's peak)."""
    if name == "coulomb_friction":
        return {"Fc": size, "eps": ctx["eps"]}
    if name == "stribeck":
        return {"Fs": size, "vs": ctx["vs"], "eps": ctx["eps"]}
    if name == "viscous_asymmetry":
        return {"d": size}
    if name == "cogging":
        return {"amplitude": size, "periods": ctx["periods"], "phase": ctx["phase"]}
    if name == "gravity":
        return {"G": size}
    if name == "offset":
        return {"F0": ctx["sign"] * size}
    if name == "backlash":
        return {"half_width": size}
    if name == "cubic_stiffness":  # hardening: a softening spring turns over and the plant runs away
        return {"k3": size}
    if name == "deadzone":
        return {"width": size}
    if name == "saturation":
        return {"level": (1.0 - size) * ctx["u_peak"]}
    if name == "delay":
        return {"delay_s": size * ctx["dt"]}
    raise ValueError(name)


def _start_and_bounds(name: str, ctx: dict) -> tuple[float, float, float]:
    """First guess and bounds of the calibration variable."""
    u_rms, u_peak = ctx["u_rms"], ctx["u_peak"]
    if name in ("coulomb_friction", "stribeck", "cogging", "gravity", "offset"):
        return 0.05 * u_rms, 1e-6 * u_rms, 5.0 * u_peak
    if name == "deadzone":
        return 0.05 * u_rms, 1e-6 * u_rms, 0.9 * u_peak
    if name == "viscous_asymmetry":
        r = u_rms / max(ctx["v_rms"], 1e-12)
        return 0.05 * r, 1e-6 * r, 10.0 * r
    if name == "backlash":
        return 0.05 * ctx["tw_rms"], 1e-6 * ctx["tw_rms"], 3.0 * ctx["tw_rms"]
    if name == "cubic_stiffness":
        k = ctx["k"] / ctx["tw_rms"] ** 2
        return 0.05 * k, 1e-6 * k, 100.0 * k
    if name == "saturation":
        return 0.05, 1e-4, 0.95
    if name == "delay":
        return 2.0, 1.0, 40.0
    raise ValueError(name)


def _calibrate(run: _Run, base: np.ndarray, name: str, placed: dict, ctx: dict, target: float,
               n_cal: int) -> tuple[dict | None, float]:
    """The effect's parameters whose contribution is close to `target` (secant steps in log-log), first on
    the record's first `n_cal` samples, then corrected on the whole record. None if out of reach."""
    s, lo, hi = _start_and_bounds(name, ctx)
    slope = 1.0

    def effect(size: float) -> dict:
        return {"name": name, **placed, "params": _effect_params(name, size, ctx)}

    ratio = float("nan")
    for n, steps in ((n_cal, 8), (run.n, 4)):
        prev = None
        for _ in range(steps):
            try:
                ratio = run.ratio(base[:n + 1], run.run([effect(s)], n)[0])
            except RuntimeError:  # too large an effect: the plant diverges
                ratio = math.inf
            if ratio == math.inf:
                prev, s = None, max(s / 10, lo)
                continue
            if RATIO_ACCEPT[0] <= ratio <= RATIO_ACCEPT[1] and abs(math.log(ratio / target)) < math.log(1.3):
                break
            if prev is not None and ratio > 0 and prev[1] > 0 and s != prev[0]:
                slope = float(np.clip(math.log(ratio / prev[1]) / math.log(s / prev[0]), 0.3, 3.0))
            new = s * (target / ratio) ** (1.0 / slope) if ratio > 0 else s * 10
            new = float(np.clip(new, lo, hi))
            if name == "delay":
                new = float(np.clip(round(new * 4) / 4, lo, hi))  # quarter samples
            if new == s:
                break
            prev, s = (s, ratio), new
    if not (RATIO_ACCEPT[0] <= ratio <= RATIO_ACCEPT[1]):
        return None, ratio
    return effect(s), ratio


def _not_shown(run: _Run, eff: dict) -> str | None:
    """Why the record could not show `eff` as itself (see Effects in the module notes), or None."""
    states, cmd = run.run([eff])
    plant = run.plant
    clean = {**{s: states[:, i] for i, s in enumerate(plant.states)}, plant.input: np.append(cmd, cmd[-1])}
    if eff["name"] == "cogging":
        turns = eff["params"]["periods"] * float(np.ptp(clean[eff["at"]])) / (2 * math.pi)
        if turns < MIN_PERIODS:
            return f"its position turns through {turns:.2g} periods"
    share = nonlinear_share({"plant": {"kind": plant.kind, **plant.p}, "effects": [eff]}, clean)
    if eff["name"] in share and share[eff["name"]] <= LINEAR_SHARE:
        return f"a linear model takes up all but {share[eff['name']]:.2g} of its force"
    return None


def _draw_sizes(rng: np.random.Generator, max_samples: int) -> tuple[float, float, int]:
    rate = _loguniform(rng, 200.0, 5000.0)
    duration = _loguniform(rng, 5.0, 60.0)
    if rate * duration > max_samples:
        duration = max(5.0, max_samples / rate)
        if rate * duration > max_samples:
            rate = max_samples / duration
    n = int(round(rate * duration))
    return 1.0 / rate, duration, n


def make_record(index: int, *, max_samples: int | None = None, shown_only: bool = True,
                noise_of_effect_free: bool = False) -> Record:
    """Record `index` (seed `index`): plant, effects calibrated to 2-20x the noise, training data and twin.

    Records from 200 on are the families of :mod:`independent_families` (their own lengths, 5 k-50 k samples;
    `max_samples` shortens them). `max_samples` None: :data:`DEFAULT_MAX_SAMPLES` below 200.
    ``shown_only=False`` keeps an effect the record cannot show as itself (the first version's records);
    ``noise_of_effect_free=True`` sizes the noise on the run without effects (the second version's records:
    an effect that shrinks the motion, a saturation, left noise of up to 17 times the written signal's range)."""
    if index >= 200:
        import independent_families

        return independent_families.make_family_record(index, max_samples=max_samples)
    max_samples = DEFAULT_MAX_SAMPLES if max_samples is None else max_samples
    rng = np.random.default_rng([index, 0])
    dt, duration, n = _draw_sizes(rng, max_samples)
    rate = 1.0 / dt
    plant, f_plant = _draw_plant(rng, rate)
    positions_only = bool(rng.uniform() < 0.25)
    kind = str(rng.choice(["multisine", "prbs", "steps", "closed_loop"]))
    noise_frac = _loguniform(rng, 0.002, 0.05)
    wanted = _choose_effects(rng, plant)
    target_range = _loguniform(rng, 1.0, 4.0)  # of the (first) position: rad or m
    f_lo, f_hi = max(2.0 / duration, 0.05), min(rate / 10, max(5.0, 3 * f_plant))

    pid = ref_twin = None

    def open_input(seed: list[int]) -> np.ndarray:
        return excitation(kind, np.random.default_rng(seed), n, dt, f_lo, f_hi)

    if kind == "closed_loop":
        f_c = _loguniform(rng, 0.5, max(0.6, min(5.0, rate / 40, (f_plant / 4) if plant.kind == "two_mass"
                                                  else 5.0)))
        pid = _pid_gains(plant, f_c)
        ref = target_range / 2 * _reference(np.random.default_rng([index, 1]), n, dt, f_c)
        ref_twin = target_range / 2 * _reference(np.random.default_rng([index, 3]), n, dt, f_c)
        u = u_twin = None
        scale = 1.0
    else:
        ref = None
        u0 = open_input([index, 1])
        probe, _ = simulate(plant, [], dt, n, u=u0)
        scale = target_range / max(float(np.ptp(probe[:, 0])), 1e-12)
        u, u_twin = scale * u0, scale * open_input([index, 3])
    written = list(plant.positions) if positions_only else list(plant.states)
    run = _Run(plant, dt, n, u, ref, pid, written, noise_frac=None if noise_of_effect_free else noise_frac)
    base, cmd = run.run([])
    if not np.all(np.isfinite(base)) or np.max(np.abs(base)) > 1e6:
        raise RuntimeError(f"record {index}: the plant without effects diverges")
    run.sigma = {s: noise_frac * float(np.ptp(base[:, plant.states.index(s)])) for s in written}
    vel = base[:, plant.states.index(plant.velocity_of[plant.positions[0]])]
    tw = base[:, 0] - base[:, 2] if plant.kind == "two_mass" else np.zeros(1)
    ctx = {"u_rms": float(np.sqrt(np.mean(cmd ** 2))), "u_peak": float(np.max(np.abs(cmd))), "dt": dt,
           "v_rms": float(np.sqrt(np.mean(vel ** 2))), "tw_rms": float(np.sqrt(np.mean(tw ** 2))) or 1.0,
           "k": plant.p.get("k", 0.0)}
    n_cal = min(n, 6000)
    effects, ratios, rejected = [], [], []
    for name in wanted:
        for _attempt in range(4):
            at, row = _place(rng, plant, name)
            v_name = row if row in plant.states else plant.velocity_of[plant.positions[0]]
            v_ptp = float(np.ptp(base[:, plant.states.index(v_name)]))
            pos_name = at if at in plant.states else plant.positions[0]
            p_ptp = float(np.ptp(base[:, plant.states.index(pos_name)]))
            ctx.update({"eps": 1e-4 * v_ptp, "vs": _loguniform(rng, 0.02, 0.2) * v_ptp,
                        "periods": float(np.clip(math.ceil(rng.uniform(3, 8) * 2 * np.pi / max(p_ptp, 1e-9)),
                                                 2, 64)),
                        "phase": rng.uniform(0, 2 * np.pi), "sign": float(rng.choice([-1.0, 1.0]))})
            target = _loguniform(rng, *RATIO_TARGET)
            eff, ratio = _calibrate(run, base, name, {"at": at, "row": row}, ctx, target, n_cal)
            unseen = _not_shown(run, eff) if eff is not None and shown_only else None
            if unseen is not None:
                rejected.append({"name": name, "not_shown": unseen})
            elif eff is not None:
                effects.append(eff)
                ratios.append(ratio)
                break
            else:
                rejected.append({"name": name, "ratio_reached": ratio})
            name = str(rng.choice([e for e in (SINGLE_EFFECTS if plant.kind == "single" else EFFECT_NAMES)
                                   if e not in [x["name"] for x in effects]]))
    final, cmd_final = run.run(effects) if effects else (base, cmd)
    combined = run.ratio(base, final) if effects else 0.0
    if not noise_of_effect_free:  # the noise: a share of each signal's range as written
        run.sigma = {s: noise_frac * float(np.ptp(final[:, plant.states.index(s)])) for s in written}

    noise_rng = np.random.default_rng([index, 2])
    t = np.arange(n + 1) * dt
    u_col = np.append(cmd_final, cmd_final[-1])  # the last sample's input repeats the held one
    train = {"time": t}
    for s in written:
        train[s] = final[:, plant.states.index(s)] + run.sigma[s] * noise_rng.standard_normal(n + 1)
    train[plant.input] = u_col

    twin = _Run(plant, dt, n, u_twin, ref_twin, pid, written, run.sigma)
    clean_twin, cmd_twin = twin.run(effects)
    noise_twin = np.random.default_rng([index, 4])
    u_twin_col = np.append(cmd_twin, cmd_twin[-1])
    heldout = {"time": t}
    for s in written:
        heldout[s] = clean_twin[:, plant.states.index(s)] + run.sigma[s] * noise_twin.standard_normal(n + 1)
    heldout[plant.input] = u_twin_col
    heldout_clean = {"time": t, **{s: clean_twin[:, i] for i, s in enumerate(plant.states)},
                     plant.input: u_twin_col}

    spec = {"index": index, "plant": {"kind": plant.kind, **plant.p}, "dt": dt, "rate_hz": rate,
            "duration_s": n * dt, "samples": n + 1, "excitation": kind, "input_scale": scale, "pid": pid,
            "positions_only": positions_only, "noise_frac": noise_frac, "sigma": run.sigma,
            "effects": [{**e, "main": MAIN_PARAMETER[e["name"]],
                         "main_value": e["params"][MAIN_PARAMETER[e["name"]]], "ratio": r}
                        for e, r in zip(effects, ratios, strict=True)],
            "combined_ratio": combined, "rejected": rejected, "target_range": target_range}
    states = [*plant.states] if not positions_only else \
        [s for p in plant.positions for s in (p, f"{p}_dot")]
    cli = {"states": states, "input": plant.input, "derive": list(plant.positions) if positions_only else [],
           "velocity_names": {plant.velocity_of[p]: (f"{p}_dot" if positions_only else plant.velocity_of[p])
                              for p in plant.positions}}
    return Record(index, spec, train, heldout, heldout_clean, cli)


def nonlinear_share(spec: dict[str, Any], clean: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Per effect, the share (RMS) of its force that no linear model can take up, along a noise-free run.

    A linear model absorbs the part of an effect's force that is linear in the states, the input and a
    constant: a gravity ``-G sin x`` over a small swing is a spring, a Coulomb friction that never lets go
    (``Fc`` above the input) is a viscous one, a saturation under a one-level input is a gain. That part is
    taken out by least squares in the row the force acts on; what is left, over the force's RMS, is its
    share. An equation-error measure (the output error of the best linear model can be smaller: the share
    can only overstate what is identifiable). Offsets (named from the model's own constant) and delays (a
    linear dynamic) are not rated. `clean` holds every state and the commanded input (``heldout_clean``:
    the record's twin, the same plant, effects and kind of excitation).
    """
    plant = Plant(spec["plant"]["kind"], {k: v for k, v in spec["plant"].items() if k != "kind"})
    u = np.asarray(clean[plant.input], dtype=float)
    states = np.column_stack([np.asarray(clean[s], dtype=float) for s in plant.states])
    regressors = np.column_stack([states, u, np.ones(len(u))])
    out = {}
    for e in spec["effects"]:
        name, q = e["name"], e["params"]
        if name in ("offset", "delay"):
            continue
        if name in ("deadzone", "saturation"):
            g, _ = _input_map([e])
            force = np.array([g(x) for x in u]) - u
        elif name in ("backlash", "cubic_stiffness") and plant.kind == "two_mass":
            tw = states[:, 0] - states[:, 2]
            force = plant.p["k"] * (np.array([_dz(x, q["half_width"]) for x in tw]) - tw) \
                if name == "backlash" else q["k3"] * tw ** 3
        else:
            f = _force_terms([e], "", e["row"])
            if f is None:
                continue
            position = next(p for p, v in plant.velocity_of.items() if v == e["row"])
            x, v = clean[position], clean[e["row"]]
            force = np.array([f(a, b) for a, b in zip(x, v, strict=True)])
        total = float(np.sqrt(np.mean(force ** 2)))
        if total == 0.0:
            out[name] = 0.0
            continue
        coef = np.linalg.lstsq(regressors, force, rcond=None)[0]
        out[name] = float(np.sqrt(np.mean((force - regressors @ coef) ** 2))) / total
    return out


def replay(spec: dict[str, Any], u: np.ndarray) -> dict[str, np.ndarray]:
    """The record's noise-free states again, from its written (exact) commands `u` replayed open loop (a
    closed-loop record's commands came from the noise-free states, so the replay is the same run)."""
    plant = Plant(spec["plant"]["kind"], {k: v for k, v in spec["plant"].items() if k != "kind"})
    n = len(u) - 1
    states, _ = simulate(plant, [{k: v for k, v in e.items() if k not in ("main", "main_value", "ratio")}
                                 for e in spec["effects"]], spec["dt"], n, u=np.asarray(u[:n], dtype=float))
    return {**{s: states[:, i] for i, s in enumerate(plant.states)}, plant.input: np.asarray(u, dtype=float)}


def cosim_name(record_cli: dict, signal: str) -> str:
    """The name cosim gives `signal` in this record (a velocity is ``<pos>_dot`` when it was derived)."""
    if "-" in signal:
        return "-".join(cosim_name(record_cli, s) for s in signal.split("-"))
    return record_cli["velocity_names"].get(signal, signal)


if __name__ == "__main__":
    import argparse
    import time

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("indices", nargs="+", type=int)
    parser.add_argument("--max-samples", type=int, default=None)
    parser.add_argument("--out", default="/tmp/independent_plants")
    args = parser.parse_args()
    for i in args.indices:
        start = time.perf_counter()
        rec = make_record(i, max_samples=args.max_samples)
        folder = rec.write(Path(args.out) / f"record_{i:04d}")
        eff = ", ".join(f"{e['name']}@{e['at']} {e['main']}={e['main_value']:.4g} "
                        f"(x{e['ratio'] if e['ratio'] is not None else e['visibility']:.1f})"
                        for e in rec.spec["effects"]) or "none"
        print(f"{i}: {rec.spec['plant']['kind']} {rec.spec['excitation']} {rec.spec['samples']} samples "
              f"{rec.spec['rate_hz']:.0f} Hz, noise {100 * rec.spec['noise_frac']:.2f} %, "
              f"pos-only={rec.spec['positions_only']}: {eff} [{time.perf_counter() - start:.1f} s] -> {folder}")
