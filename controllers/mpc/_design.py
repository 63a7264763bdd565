"""The MPC's design from its settings (private to :mod:`controllers.mpc`): weights and vectors read from the
user's forms, the terminal cost (Riccati), the disturbance model, the observer gain, the steady-state target
map, the state constraints and the inputs' scale in the QP; with the defaults of the weights and the observer.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import scipy.linalg

from cosim.errors import ControllerError, InvalidSettingError, UnknownVariableError
from cosim.numbers import finite_number as _number

from ..base import KNOWN_CONSTANT_INPUTS, DesignModel

#: Default weights, tuned on the reference application (two-mass servo in rad and N m at 2257 Hz, torque
#: bounded to 5000 N m: a 0.01 rad step settles within 2 % in about 0.25 s without overshoot, also with
#: Coulomb friction). Cost per sample: ``q (y - r)^2 + q_rate (dy/dt)^2 + r (u - us)^2 + r_delta (u - u_prev)^2``
#: for a tracked output y: 1 mrad of error costs as much as 1000 N m of torque (bandwidth about 28 rad/s), and
#: the weight on the speed of the tracked output damps the loop (no overshoot, no friction hunting). Scale them
#: for other units.
DEFAULT_WEIGHTS = {"q": 1e6, "q_rate": 3e3, "r": 1e-6, "r_delta": 1e-6}
#: Default observer (steady-state Kalman filter) noise standard deviations, tuned on the same application:
#: process noise entering through the manipulated inputs (1 N m), per-sample drift of the input disturbances
#: (100 N m: friction is picked up within about 10 ms) and of the output disturbances (1e-8 rad: slow, they
#: are there to give one disturbance per measured output), measurement noise (1 urad, an encoder), extra
#: process noise on each state (none).
DEFAULT_OBSERVER = {"input_noise": 1.0, "disturbance_noise": 100.0, "output_disturbance_noise": 1e-8,
                    "measurement_noise": 1e-6, "state_noise": 0.0}
_OBSERVER_KEYS = (*DEFAULT_OBSERVER, "gain")
_RANK_TOL = 1e-9


def _equilibrated_rank(M: np.ndarray) -> int:
    """Rank of `M` after scaling rows and columns to unit norm (the scaling leaves the rank unchanged)."""
    if M.size == 0:
        return 0
    rows = np.linalg.norm(M, axis=1)
    rows[rows == 0] = 1.0
    Ms = M / rows[:, None]
    cols = np.linalg.norm(Ms, axis=0)
    cols[cols == 0] = 1.0
    s = np.linalg.svd(Ms / cols[None, :], compute_uv=False)
    return int(np.sum(s > _RANK_TOL * max(s[0], 1.0)))


def _square_matrix(value: Any, names: Sequence[str], what: str, *, allow_matrix: bool) -> np.ndarray:
    """A weight given as a number, one number per name, a mapping name -> number, or (if allowed) a matrix."""
    n = len(names)
    if isinstance(value, Mapping):
        diag = np.zeros(n)
        for key, v in value.items():
            if key not in names:
                raise UnknownVariableError(f"{what} names {key!r}, which is not one of {list(names)}")
            diag[names.index(key)] = _number(v, f"{what}[{key!r}]")
        M = np.diag(diag)
    else:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"{what} must be a number, one number per {list(names)}, or a mapping, "
                                      f"got {value!r}") from None
        if arr.ndim == 0:
            M = np.eye(n) * float(arr)
        elif arr.shape == (n,):
            M = np.diag(arr)
        elif allow_matrix and arr.shape == (n, n):
            M = (arr + arr.T) / 2
        else:
            shapes = f"({n},)" + (f" or ({n}, {n})" if allow_matrix else "")
            raise InvalidSettingError(f"{what} has shape {arr.shape}; expected a number or shape {shapes} for "
                                      f"{list(names)}")
    if not np.all(np.isfinite(M)):
        raise InvalidSettingError(f"{what} has NaN or infinite entries")
    if np.min(np.linalg.eigvalsh(M)) < -1e-12 * max(1.0, float(np.max(np.abs(M)))):
        raise InvalidSettingError(f"{what} must be non-negative (positive semi-definite)")
    return M


def _vector(value: Any, names: Sequence[str], what: str, default: float) -> np.ndarray:
    if value is None:
        return np.full(len(names), default)
    if isinstance(value, Mapping):
        out = np.full(len(names), default)
        for key, v in value.items():
            if key not in names:
                raise UnknownVariableError(f"{what} names {key!r}, which is not one of {list(names)}")
            out[names.index(key)] = _number(v, f"{what}[{key!r}]")
        return out
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidSettingError(f"{what} must be numbers, got {value!r}") from None
    if arr.size == 1:
        arr = np.full(len(names), arr[0])
    if arr.shape != (len(names),) or not np.all(np.isfinite(arr)):
        raise InvalidSettingError(f"{what} needs {len(names)} finite value(s) for {list(names)}, got {value!r}")
    return arr


def _names(value: Any, role: str) -> tuple[str, ...]:
    names = (value,) if isinstance(value, str) else tuple(value)
    if not all(isinstance(v, str) for v in names):
        raise InvalidSettingError(f"{role} must be signal names (strings), got {value!r}")
    if len(set(names)) != len(names):
        raise InvalidSettingError(f"{role} has repeated names: {list(names)}")
    return names


def _terminal_cost(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray,
                   S: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Riccati solution of the infinite-horizon cost on ``z = [x; u_prev]`` with input ``u``.

    Returns ``P`` (on z), the LQR gain ``K`` (``u = -K z``) and the spectral radius of ``Az - Bz K``.
    """
    n, m = B.shape
    Az = np.block([[A, np.zeros((n, m))], [np.zeros((m, n + m))]])
    Bz = np.vstack([B, np.eye(m)])
    Qz = scipy.linalg.block_diag(Q, S)
    Nz = np.vstack([np.zeros((n, m)), -S])
    try:
        P = scipy.linalg.solve_discrete_are(Az, Bz, Qz, R + S, s=Nz)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ControllerError(f"the Riccati equation of the MPC cost has no stabilising solution ({exc}); check that "
                              "the inputs can stabilise the model and that q/q_states see its unstable modes") from None
    P = (P + P.T) / 2
    K = np.linalg.solve(R + S + Bz.T @ P @ Bz, Bz.T @ P @ Az + Nz.T)
    rho = float(np.max(np.abs(np.linalg.eigvals(Az - Bz @ K))))
    if not rho < 1:
        raise ControllerError(f"the unconstrained MPC loop is not stable (spectral radius {rho:.6g}); check the model "
                              "and the weights")
    return P, K, rho


def _disturbance_model(A: np.ndarray, B: np.ndarray, C: np.ndarray, inputs: Sequence[str], outputs: Sequence[str],
                       tracked: set[int], kind: str | None) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``Bd, Cd`` and the disturbance labels: one disturbance per measured output, augmented model detectable."""
    n, m = B.shape
    p = C.shape[0]
    if kind not in ("input", "output", None, "none"):
        raise InvalidSettingError(f"disturbance must be 'input', 'output' or None, got {kind!r}")
    eig = np.linalg.eigvals(A)
    for lam in eig[(np.abs(eig) >= 1 - 1e-9)]:
        if _equilibrated_rank(np.vstack([lam * np.eye(n) - A, C])) < n:
            raise ControllerError(f"the measured outputs {list(outputs)} do not see the model mode at z={lam:.6g}; "
                                  "measure more outputs")
    cols: list[tuple[np.ndarray, np.ndarray, str]] = []
    if kind in (None, "none"):
        return np.zeros((n, 0)), np.zeros((p, 0)), []

    def rank_with(extra: list[tuple[np.ndarray, np.ndarray, str]]) -> int:
        Bd = np.column_stack([c[0] for c in extra]) if extra else np.zeros((n, 0))
        Cd = np.column_stack([c[1] for c in extra]) if extra else np.zeros((p, 0))
        return _equilibrated_rank(np.block([[A - np.eye(n), Bd], [C, Cd]]))

    candidates = []
    if kind == "input":
        candidates += [(B[:, i], np.zeros(p), f"input:{inputs[i]}") for i in range(m)]
    order = [j for j in range(p) if j not in tracked] + [j for j in range(p) if j in tracked]
    candidates += [(np.zeros(n), np.eye(p)[j], f"output:{outputs[j]}") for j in order]
    for cand in candidates:
        if len(cols) == p:
            break
        if rank_with([*cols, cand]) == n + len(cols) + 1:
            cols.append(cand)
    if len(cols) < p:
        raise ControllerError(f"cannot build a detectable {kind} disturbance model with one disturbance per measured "
                              f"output ({p}); found {[c[2] for c in cols]}. Use disturbance='input' (an integrating "
                              "plant cannot take output disturbances on all outputs) or measure fewer outputs")
    return (np.column_stack([c[0] for c in cols]), np.column_stack([c[1] for c in cols]), [c[2] for c in cols])


def _observer_gain(Ao: np.ndarray, Bo: np.ndarray, Co: np.ndarray, spec: Mapping[str, Any] | None,
                   states: Sequence[str], inputs: Sequence[str], outputs: Sequence[str],
                   labels: list[str]) -> tuple[np.ndarray, float]:
    """Steady-state Kalman filter gain (filter form) on the augmented model, or a given gain; its spectral radius."""
    spec = dict(spec or {})
    unknown = [k for k in spec if k not in _OBSERVER_KEYS]
    if unknown:
        raise InvalidSettingError(f"observer has no setting {unknown[0]!r}; settings are {list(_OBSERVER_KEYS)}")
    na, p = Co.shape[1], Co.shape[0]
    if spec.get("gain") is not None:
        try:
            L = np.array(spec["gain"], dtype=float).reshape(na, p)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"observer gain must have shape ({na}, {p}) (states + disturbances, measured "
                                      f"outputs), got {np.shape(spec['gain'])}") from None
        if not np.all(np.isfinite(L)):
            raise InvalidSettingError("observer gain has NaN or infinite entries")
    else:
        cfg = {**DEFAULT_OBSERVER, **{k: v for k, v in spec.items() if v is not None}}
        su = _vector(cfg["input_noise"], inputs, "observer input_noise", 0.0)
        sd_in = _vector(cfg["disturbance_noise"], inputs, "observer disturbance_noise", 0.0)
        sd_out = _vector(cfg["output_disturbance_noise"], outputs, "observer output_disturbance_noise", 0.0)
        sd = np.array([sd_in[list(inputs).index(lab[6:])] if lab.startswith("input:")
                       else sd_out[list(outputs).index(lab[7:])] for lab in labels])
        sy = _vector(cfg["measurement_noise"], outputs, "observer measurement_noise", 0.0)
        n = len(states)
        sx = _vector(cfg["state_noise"], states, "observer state_noise", 0.0)
        if np.any(sy <= 0):
            raise InvalidSettingError("observer measurement_noise must be positive for every measured output")
        Bu = Bo[:n]
        W = scipy.linalg.block_diag(Bu @ np.diag(su ** 2) @ Bu.T + np.diag(sx ** 2), np.diag(sd ** 2))
        V = np.diag(sy ** 2)
        try:
            P = scipy.linalg.solve_discrete_are(Ao.T, Co.T, W, V)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise ControllerError(f"the Kalman filter has no stabilising solution ({exc}); give every disturbance "
                                  "and input a positive noise level") from None
        L = P @ Co.T @ np.linalg.inv(Co @ P @ Co.T + V)
    rho = float(np.max(np.abs(np.linalg.eigvals(Ao - Ao @ L @ Co))))
    if not rho < 1:
        raise ControllerError(f"the observer is not stable (spectral radius {rho:.6g}); the measured outputs "
                              f"{list(outputs)} with disturbances {labels} are not detectable, or the gain is wrong")
    return L, rho


def _target_map(A: np.ndarray, B: np.ndarray, Ct: np.ndarray, ft: np.ndarray, Bd: np.ndarray, Cdt: np.ndarray,
                e: np.ndarray, inputs: Sequence[str], tracked: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """``[xs; us] = T [r; d] + t0`` solving ``xs = A xs + B us + Bd d + e``, ``Ct xs + Cdt d + ft = r``."""
    n, m = B.shape
    nt = Ct.shape[0]
    M = np.block([[A - np.eye(n), B], [Ct, np.zeros((nt, m))]])
    if _equilibrated_rank(M) < n + nt:
        raise ControllerError(f"the inputs {list(inputs)} cannot hold the tracked outputs {list(tracked)} at any "
                              "setpoint in steady state (too few inputs, or a zero at z=1); track fewer outputs")
    rows = np.linalg.norm(M, axis=1)
    cols = np.linalg.norm(M / rows[:, None], axis=0)
    cols[cols == 0] = 1.0
    X = np.linalg.pinv(M / rows[:, None] / cols[None, :]) / cols[:, None] / rows[None, :]
    nd = Bd.shape[1]
    T = X @ np.block([[np.zeros((n, nt)), -Bd], [np.eye(nt), -Cdt]]) if nd else X[:, n:]
    t0 = X @ np.concatenate([-e, -ft])
    return T, t0


_Constraint = tuple[np.ndarray, float, float, float]


def _state_constraints(bounds: Mapping[str, Any] | None, dm: DesignModel) -> tuple[_Constraint, ...]:
    """``(c, c0, lo, hi)`` for each bounded state or model output: ``lo <= c x + c0 <= hi``."""
    if not bounds:
        return ()
    if not isinstance(bounds, Mapping):
        raise InvalidSettingError(f"state_bounds must be a mapping name -> (lo, hi), got {bounds!r}")
    ic = [k for k, name in enumerate(dm.inputs) if name in KNOWN_CONSTANT_INPUTS]
    out = []
    for name, pair in bounds.items():
        if name in dm.states:
            c, c0 = np.eye(len(dm.states))[dm.states.index(name)], 0.0
        elif name in dm.outputs:
            j = dm.outputs.index(name)
            if np.any(np.delete(dm.D[j], ic) != 0):
                raise InvalidSettingError(f"output {name!r} depends directly on the inputs; bound a state instead")
            c, c0 = dm.C[j], float(dm.D[j, ic].sum()) if ic else 0.0
        else:
            raise UnknownVariableError(f"state_bounds names {name!r}, which is neither a model state {list(dm.states)} "
                                       f"nor an output {list(dm.outputs)}")
        try:
            lo, hi = pair
            lo = -np.inf if lo is None else float(lo)
            hi = np.inf if hi is None else float(hi)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"state_bounds[{name!r}] must be a pair (lo, hi), got {pair!r}") from None
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise InvalidSettingError(f"state_bounds[{name!r}] needs lo < hi, got ({lo}, {hi})")
        if math.isfinite(lo) or math.isfinite(hi):
            out.append((c, c0, lo, hi))
    return tuple(out)


def _input_scale(u_min: np.ndarray, u_max: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray,
                 P: np.ndarray, n: int) -> np.ndarray:
    """Scale of each input in the QP: half its range when bounded, else from the curvature of the cost."""
    curvature = np.diag(R + S + B.T @ P[:n, :n] @ B)
    scale = 1.0 / np.sqrt(np.maximum(curvature, 1e-300))
    both = np.isfinite(u_min) & np.isfinite(u_max)
    scale[both] = (u_max[both] - u_min[both]) / 2
    return scale
