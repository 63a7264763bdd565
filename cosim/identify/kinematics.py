"""Which states are positions and which their velocities: :func:`detect_kinematics`.

A mechanical model's rows ``d position/dt = velocity`` are known exactly; fixing them (coefficient 1, not
regressed) removes a quarter to a half of the unknowns of a SINDYc fit and the slow drifting modes that
noisy data puts there. :class:`~cosim.identify.sindyc.SINDYc` finds them with this function by default
(``kinematics="auto"``).

How a pair is found
-------------------
* **By the names** (``found="name"``): ``x``/``x_dot``, ``x``/``xdot``, ``x``/``dx``, ``x``/``x_d``,
  ``q``/``qd``, ``qm``/``qm_dot``, and a position prefix (``theta``, ``phi``, ``psi``, ``angle``, ``pos``,
  ``position``, ``x``, ``q``) swapped for a velocity prefix (``omega``, ``w``, ``vel``, ``velocity``, ``v``,
  ``speed``) with the same rest: ``theta_m``/``omega_m``, ``pos``/``vel``, ``x1``/``v1``; names as FMUs write
  them: ``x``/``der(x)``, and the last part of a dotted name so (``shaft.phi``/``shaft.w``), or ``mass.s``/
  ``mass.v`` (Modelica's translational position and velocity). A name pair is
  kept unless the data contradict it (they may be unable to tell: a position that barely moves); when they
  do (a velocity in other units, rpm for rad/s, or a signal that is not the derivative: gain off 1 by more
  than `tolerance` and three standard errors, or a residual three times the noise) it is dropped with an
  :class:`~cosim.errors.IdentificationWarning` naming both.
* **By the data** (``found="data"``): a state that equals the running integral of another state (plus a
  constant per block of samples, see :func:`_test`), with gain within `tolerance` of 1, known to a third of
  it, and a residual no larger than the measurement noise explains (1.5 times its estimate, or 0.2 % of the
  signal). The integral (trapezoids with their end correction, O(dt^4)) averages the noise that a derivative
  would amplify. Each state is the position of one pair at most and the velocity of one at most; competing
  pairs are settled by the smaller relative residual.

The noise of each signal is estimated from its fourth differences (median absolute deviation). Signals
that are not kinematically related (two coupled velocities, a low-pass filtered signal and its input, a
position and a velocity in other units) give no pair.

Examples
--------
>>> import numpy as np
>>> t = np.arange(4000) * 1e-3
>>> x, v, f = np.sin(3 * t), 3 * np.cos(3 * t), np.cos(7 * t)
>>> pairs = detect_kinematics(["x", "v", "f"], np.column_stack([x, v, f]), 1e-3)
>>> [str(p) for p in pairs]
["x' = v (names)"]
>>> [str(p) for p in detect_kinematics(["s1", "s2"], np.column_stack([x, v]), 1e-3)]
["s1' = s2 (data)"]
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import DataError, IdentificationWarning, InvalidSettingError
from ._settings import _kinematics_setting

__all__ = ["KinematicPair", "detect_kinematics"]

_POSITION_PREFIXES = ("position", "theta", "angle", "phi", "psi", "pos", "x", "q")
_VELOCITY_PREFIXES = ("velocity", "omega", "speed", "vel", "w", "v")
_SUFFIXES = ("_dot", "dot", "_d", "d")


@dataclass(frozen=True)
class KinematicPair:
    """A kinematic row ``d position/dt = velocity`` and how it was found.

    Attributes
    ----------
    position, velocity : str
        The state names.
    found : str
        ``"name"`` (a name pair the data confirm or cannot judge), ``"data"`` (from the data only),
        ``"given"`` (the user's mapping) or ``"derived"`` (a velocity derived from its position).
    gain : float or None
        Least-squares gain of the position's increments on the velocity's integral (1 for a true pair); None
        when not measured.
    r2 : float or None
        Share of the increments' variance that the velocity's integral explains.
    """

    position: str
    velocity: str
    found: str
    gain: float | None = None
    r2: float | None = None

    def __str__(self) -> str:
        how = {"name": "names"}.get(self.found, self.found)
        return f"{self.position}' = {self.velocity} ({how})"

    def to_dict(self) -> dict[str, Any]:
        """The pair as a JSON-ready mapping."""
        return {"position": self.position, "velocity": self.velocity, "found": self.found, "gain": self.gain,
                "r2": self.r2}


@dataclass(frozen=True)
class _Test:
    gain: float
    se: float           # standard error of the gain
    r2: float
    ratio: float        # residual RMS over what the noise explains
    relative: float     # residual RMS over the increments' RMS

    def confirms(self, tolerance: float) -> bool:
        """The data show the pair: gain within `tolerance` of 1, known to a third of it, residual = noise."""
        return (abs(self.gain - 1.0) <= tolerance and self.se <= tolerance / 3.0
                and (self.ratio <= 1.5 or self.relative <= 2e-3))

    def contradicts(self, tolerance: float) -> bool:
        """The data rule the pair out: gain beyond `tolerance` by 3 standard errors, or residual far above noise."""
        return abs(self.gain - 1.0) > tolerance + 3.0 * self.se or (self.ratio > 3.0 and self.relative > 0.05)


def _velocity_names(position: str) -> list[str]:
    """Lower-case velocity names that go with a lower-case `position` name."""
    out = [position + s for s in _SUFFIXES] + ["d" + position, "d_" + position]
    for pre in _POSITION_PREFIXES:
        if position.startswith(pre):
            rest = position[len(pre):]
            if rest and rest[0].isalpha():
                continue
            out += [v + rest for v in _VELOCITY_PREFIXES]
            out += [pre + s + rest for s in _SUFFIXES] + ["d" + pre + rest]
    head, dot, last = position.rpartition(".")
    if dot:  # a Modelica component's: mass.s/mass.v, shaft.phi/shaft.w, body.x/body.x_dot
        out += [f"{head}.{v}" for v in [*_velocity_names(last), *(["v"] if last == "s" else [])]]
    return [*out, f"der({position})"]


def _name_pairs(names: Sequence[str]) -> list[tuple[str, str]]:
    lower = {n.lower(): n for n in names}
    pairs = []
    for pos in names:
        for cand in dict.fromkeys(_velocity_names(pos.lower())):
            vel = lower.get(cand)
            if vel is not None and vel != pos:
                pairs.append((pos, vel))
    return pairs


def _noise_std(runs: Sequence[np.ndarray]) -> np.ndarray:
    """White-noise standard deviation of each column, from fourth differences (robust MAD)."""
    d = np.vstack([np.diff(x, n=4, axis=0) for x in runs if len(x) > 8] or [np.zeros((1, runs[0].shape[1]))])
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return 1.4826 * mad / math.sqrt(70.0)


def _integral(v: np.ndarray, dt: float) -> np.ndarray:
    """Cumulative integral of samples `v`: trapezoids with their end correction (O(dt^4))."""
    cum = np.concatenate([[0.0], np.cumsum(0.5 * dt * (v[1:] + v[:-1]))])
    slope = np.gradient(v, dt, edge_order=2) if len(v) > 2 else np.zeros_like(v)
    return cum - dt ** 2 / 12.0 * (slope - slope[0])


def _blocks(x: np.ndarray, m: int) -> np.ndarray:
    """`x` less its mean over each block of `m` samples (the last block takes the remainder)."""
    out = np.empty_like(x)
    for start in range(0, len(x), m):
        part = x[start:start + m] if len(x) - start >= 2 * m else x[start:]
        out[start:start + len(part)] = part - part.mean()
        if len(part) > m:
            break
    return out


def _test(p_runs: Sequence[np.ndarray], v_runs: Sequence[np.ndarray], dt: float, sigma_p: float,
          sigma_v: float) -> _Test:
    """Regress the position on the running integral of the velocity, block by block (a constant per block).

    The integral's own noise is a random walk (variance ``sigma_v^2 dt^2 k`` after k samples) that correlates
    by chance with a drifting position over long blocks, while short blocks leave little signal: the block
    length (16 samples to the whole record, log-spaced) is the one with the smallest standard error of the gain
    counting both, ``se^2 = (sigma_p^2 + sigma_v^2 dt^2 m^2 / 6) / sum(integral^2)``.
    """
    longest = max(len(p) for p in p_runs)
    integrals = [_integral(v, dt) for v in v_runs]
    best: tuple[float, int, float] | None = None
    for m in sorted({*np.geomspace(16, longest, 12).astype(int).tolist(), longest}):
        m = max(min(m, longest), 1)
        iv = np.concatenate([_blocks(c, m) for c in integrals])
        denom = float(iv @ iv)
        walk = sigma_v ** 2 * dt ** 2 * m / 6.0
        se2 = (sigma_p ** 2 + walk * m) / denom if denom > 0 else math.inf
        if best is None or se2 < best[0]:
            best = (se2, m, walk)
    se2, m, walk = best
    dp = np.concatenate([_blocks(p, m) for p in p_runs])
    iv = np.concatenate([_blocks(c, m) for c in integrals])
    denom = float(iv @ iv)
    gain = float(dp @ iv) / denom if denom > 0 else 0.0
    resid = dp - gain * iv
    rss, tss = float(resid @ resid), float(dp @ dp)
    noise = sigma_p ** 2 + gain ** 2 * walk
    rms = math.sqrt(rss / len(dp))
    ratio = rms / math.sqrt(noise) if noise > 0 else (0.0 if rms == 0 else math.inf)
    relative = rms / math.sqrt(tss / len(dp)) if tss > 0 else math.inf
    r2 = 1.0 - rss / tss if tss > 0 else 0.0
    # the white part of the residual from the data, the random walk's share of the gain's error on top
    se = math.sqrt(rms ** 2 / denom + gain ** 2 * walk * (m - 1) / denom) if denom > 0 else math.inf
    return _Test(gain=gain, se=se, r2=r2, ratio=ratio, relative=relative)


def _as_runs(names: Sequence[str], data: Any) -> list[np.ndarray]:
    items = [data] if isinstance(data, np.ndarray) else list(data)
    if items and not isinstance(data, np.ndarray) and np.ndim(items[0]) == 1:
        items = [items]  # rows of samples: one record (np.ndim of the whole would fail on records of unequal lengths)
    runs = []
    for item in items:
        x = np.asarray(item, dtype=float)
        if x.ndim != 2 or x.shape[1] != len(names):
            raise DataError(f"detect_kinematics needs samples x {len(names)} states ({', '.join(names)}) per "
                            f"record, got shape {x.shape}; give one column per name")
        if len(x) < 9:
            raise DataError(f"a record has {len(x)} samples; detecting kinematics needs at least 9")
        if not np.all(np.isfinite(x)):
            raise DataError("the data hold NaN or inf; drop or fill the bad samples before detecting kinematics")
        runs.append(x)
    return runs


def detect_kinematics(names: Sequence[str], data: Any, dt: float, *, tolerance: float = 0.03,
                      exclude: Sequence[str] = ()) -> tuple[KinematicPair, ...]:
    """Position -> velocity pairs among states, from their names and their sampled data.

    Parameters
    ----------
    names : sequence of str
        The state names, one per column of `data`.
    data : array_like, shape (n_samples, n_states), or a sequence of them
        The sampled states (several records: one array each, same step).
    dt : float
        Sampling step in s.
    tolerance : float
        A pair's gain (position increments over the velocity's integral) must lie within this of 1 (3 %).
    exclude : sequence of str
        States that take part in no detected pair (e.g. velocities already derived from their positions).

    Returns
    -------
    tuple of KinematicPair
        In the order of the positions in `names`; a name pair the data contradict is left out with an
        :class:`~cosim.errors.IdentificationWarning`.

    Raises
    ------
    DataError
        Data not of one column per name, fewer than 9 samples, NaN or inf.
    InvalidSettingError
        `dt` not positive, repeated names, `tolerance` not in (0, 1).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(2000) * 1e-3
    >>> theta, omega = np.sin(5 * t), 5 * np.cos(5 * t)
    >>> rpm = omega * 60 / (2 * np.pi)
    >>> [p.to_dict()["found"] for p in detect_kinematics(["theta_m", "omega_m"], np.c_[theta, omega], 1e-3)]
    ['name']
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     detect_kinematics(["theta_m", "omega_m"], np.c_[theta, rpm], 1e-3)
    ()
    >>> "omega_m is not the derivative of theta_m" in str(caught[0].message)
    True
    """
    names = [str(n) for n in names]
    if len(set(names)) != len(names):
        raise InvalidSettingError(f"detect_kinematics got repeated names: {names}")
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not (math.isfinite(dt) and dt > 0):
        raise InvalidSettingError(f"dt must be a positive time step in s, got {dt!r}")
    if not 0.0 < tolerance < 1.0:
        raise InvalidSettingError(f"tolerance must lie between 0 and 1, got {tolerance!r}")
    runs = _as_runs(names, data)
    sigma = _noise_std(runs)
    columns = {n: [x[:, j] for x in runs] for j, n in enumerate(names)}
    tests: dict[tuple[str, str], _Test] = {}

    def test(pos: str, vel: str) -> _Test:
        if (pos, vel) not in tests:
            tests[pos, vel] = _test(columns[pos], columns[vel], float(dt), float(sigma[names.index(pos)]),
                                    float(sigma[names.index(vel)]))
        return tests[pos, vel]

    skip = set(exclude)
    found: dict[str, KinematicPair] = {}
    used_vel: set[str] = set()
    candidates: list[tuple[float, str, str]] = []
    for pos, vel in _name_pairs(names):
        if pos in skip or vel in skip:
            continue
        result = test(pos, vel)
        if not result.contradicts(tolerance):
            candidates.append((result.relative, pos, vel))
        else:
            warnings.warn(f"{vel} is not the derivative of {pos} by the data (gain {result.gain:.4g}, "
                          f"R2 {result.r2:.4g}), though the names pair them; no kinematic row {pos}' = {vel} "
                          f"(give kinematics={{'{pos}': '{vel}'}} to force it)", IdentificationWarning,
                          stacklevel=2)
    for _, pos, vel in sorted(candidates):
        if pos not in found and vel not in used_vel:
            result = test(pos, vel)
            found[pos] = KinematicPair(pos, vel, "name", result.gain, result.r2)
            used_vel.add(vel)
    data_candidates = []
    for pos in names:
        if pos in found or pos in skip:
            continue
        for vel in names:
            if vel == pos or vel in used_vel or vel in skip:
                continue
            result = test(pos, vel)
            if result.confirms(tolerance):
                data_candidates.append((result.relative, pos, vel))
    for _, pos, vel in sorted(data_candidates):
        if pos not in found and vel not in used_vel:
            result = test(pos, vel)
            found[pos] = KinematicPair(pos, vel, "data", result.gain, result.r2)
            used_vel.add(vel)
    return tuple(found[n] for n in names if n in found)



def _find_kinematics(setting: Any, velocities: Any, states: Sequence[str], runs: Sequence[tuple[np.ndarray, Any]],
                     dt: float) -> tuple[KinematicPair, ...]:
    """The kinematic rows of a SINDYc fit: detected (``"auto"``), none, or the user's mapping, plus a pair for
    each velocity derived from its position (``velocities=``)."""
    mode = _kinematics_setting(setting)
    derived = dict(velocities or {})
    pairs: list[KinematicPair] = []
    if mode == "auto":
        busy = [*derived, *derived.values()]
        pairs = list(detect_kinematics(states, [x for x, _ in runs], dt, exclude=busy))
    elif mode != "none":
        pairs = [KinematicPair(pos, vel, "given") for pos, vel in mode.items()]
    given = {p.position for p in pairs}
    pairs += [KinematicPair(pos, vel, "derived") for vel, pos in derived.items() if pos not in given]
    return tuple(pairs)
