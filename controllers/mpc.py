"""Linear MPC: condensed QP solved by DAQP inside one casadi Function, compiled to C and called through ctypes.

Each call of :class:`MPC` does, in one compiled function:

1. **observer** - a steady-state Kalman filter (or a given Luenberger gain) on the model augmented with
   constant disturbances, so that unmeasured states (e.g. velocities when only encoders are read) and the
   disturbances are estimated;
2. **target** - the steady state ``(xs, us)`` at which the tracked outputs equal the setpoint under the
   estimated disturbance (offset-free tracking);
3. **condensed QP** over ``N`` moves: stage cost on the state and input deviations from the target and on
   the input rate, terminal cost from the discrete algebraic Riccati equation, input and input-rate bounds,
   soft (or hard) state constraints; solved by DAQP;
4. the first move, clipped to the bounds, and the prediction of the next estimate.

The function is generated as C by casadi, compiled once into ``fmu_cache_dir()/"mpc"`` and called with
numpy buffers bound once: 5-10 microseconds per call for N = 20 (benchmarks/results/mpc_speed.md). Without a
C compiler (or with ``codegen=False``) the same function is evaluated through casadi's Python API instead
(slower, same result).
Inputs are held between calls (zero-order hold) and ``t = t0 + k*dt`` as everywhere in cosim.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import casadi as ca
import control
import numpy as np
import scipy.linalg

from cosim.errors import BuildError, ControllerError, InvalidSettingError, UnknownVariableError
from cosim.numbers import finite_number as _number

from ._qp_codegen import BoundFunction, StepProblem, codegen_support, compile_function, condense, step_function
from .base import KNOWN_CONSTANT_INPUTS, Controller, DesignModel, register

__all__ = ["MPC", "DEFAULT_WEIGHTS", "DEFAULT_OBSERVER"]

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
_ON_INFEASIBLE = ("previous_plan", "hold", "raise")
_SOLVERS = ("daqp", "qrqp")
_VIOLATION_TOL = 1e-4  # in the scaled QP (inputs scaled to their range, rows to unit norm)
_RANK_TOL = 1e-9
_MACHINE_INFO = ("solver_path", "library", "compile_seconds", "codegen_unavailable")


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


@register("mpc")
class MPC(Controller):
    """Linear model predictive controller with offset-free tracking, compiled to C for sample rates in the kHz.

    The controller is designed on a linear model ``x+ = A x + B u`` (a ``control.StateSpace``, discretised by
    zero-order hold at `dt` when continuous, or a :class:`~controllers.base.DesignModel`). At every call it

    * updates a **steady-state Kalman filter** on the model augmented with constant disturbances (filter
      form: the estimate uses the measurement of the current sample). Only the outputs in `outputs` are
      measured; the other states (velocities, say) are estimated. With ``observer={"gain": L}`` a given
      Luenberger gain replaces the Kalman gain: ``xa = xa_prior + L (y - C xa_prior)``;
    * computes the **steady-state target** ``(xs, us)``: ``xs = A xs + B us + Bd d``, tracked outputs at the
      setpoint, for the current disturbance estimate ``d``. With ``disturbance="input"`` (default) the model
      is augmented with a constant disturbance on each manipulated input, plus output disturbances on
      measured outputs until there is one disturbance per measured output, chosen so that the augmented
      model stays detectable. The tracked outputs then reach the setpoint without offset whenever the closed
      loop settles, even if the plant has friction, offsets or gains the model lacks;
    * solves the **condensed QP** over `horizon` moves ``u_0..u_N-1`` (and one slack per soft constraint)::

          min  sum_k (x_k - xs)' Q (x_k - xs) + (u_k - us)' R (u_k - us) + (u_k - u_k-1)' S (u_k - u_k-1)
               + [x_N - xs; u_N-1 - us]' P [x_N - xs; u_N-1 - us] + soft_weight penalty of the slacks
          s.t. u_min <= u_k <= u_max,  |u_k - u_k-1| <= du_max (u_-1 = the input applied last),
               lo - slack <= state/output <= hi + slack  for the names in `state_bounds`, k = 1..N

      with ``Q = Ct' diag(q) Ct + Cv' diag(q_rate) Cv + q_states`` (``Ct`` selects the tracked outputs,
      ``Cv = Ct (A - I) / dt`` their rate of change), ``R = diag(r)``,
      ``S = diag(r_delta)`` and ``P`` the solution of the discrete algebraic Riccati equation of the same
      cost over an infinite horizon (model augmented with the previous input, so that the input-rate
      penalty is included). Without active constraints the first move therefore equals the infinite-horizon
      LQR law for any horizon;
    * returns the first move, always within ``[u_min, u_max]`` and ``|u - u_prev| <= du_max``.

    The whole step is one casadi Function solved by DAQP. With ``codegen=True`` it is generated as C,
    compiled once into the cache ``fmu_cache_dir()/"mpc"`` and called through ctypes (5-10 us per call
    for N = 20); without a C compiler or casadi's ``libdaqpstat.a``, or with ``codegen=False``, the same
    Function is evaluated through casadi's Python API on the same buffers (``Function.buffer``, 10-20 us).
    ``info["solver_path"]`` says which (``"c:daqp"`` or ``"python:daqp"``).

    Warm start: the previous plan, shifted by one move, is passed as the primal start. casadi's DAQP
    interface sets the problem up afresh at each call and does not use it (DAQP keeps no working set
    between calls there); it is kept for solvers that do and serves as the fallback plan.

    Parameters
    ----------
    model : control.StateSpace or DesignModel
        Design model. Inputs named in ``KNOWN_CONSTANT_INPUTS`` (``"const"``) are held at 1; other inputs
        that are not manipulated are unmeasured disturbances taken as 0.
    dt : float, optional
        Sample time [s]; required for a continuous `model`.
    horizon : int
        Number of moves N (>= 1).
    inputs : sequence of str, optional
        Manipulated model inputs; default the first model input that is not a constant.
    outputs : sequence of str, optional
        Measured model outputs, in the order of ``y``; default all model outputs.
    tracked : sequence of str, optional
        Outputs that follow :attr:`setpoint`; default the first measured output.
    q : float, sequence, mapping or matrix
        Weight on the tracking error of the tracked outputs [1/output unit^2]. Defaults of all weights in
        :data:`DEFAULT_WEIGHTS`.
    q_rate : float, sequence, mapping or matrix
        Weight on the rate of change of the tracked outputs [s^2/output unit^2]: damping.
    q_states : float, sequence, mapping or matrix, optional
        Extra weight on the deviation of the states from the target.
    r, r_delta : float, sequence, mapping or matrix
        Weights on the input deviation from the target and on the input change per sample; ``r + r_delta``
        must be positive for every input.
    u_min, u_max, du_max : float or sequence, optional
        Input bounds and largest input change per sample (default none).
    u0 : float or sequence, optional
        The input assumed applied before the first call (default 0, or the nearest bound).
    x0 : sequence or mapping, optional
        Initial state estimate (default zeros).
    state_bounds : mapping, optional
        ``{name: (lo, hi)}`` for model states or outputs; ``None`` or ``inf`` for no bound on one side.
    hard_state_bounds : bool
        Enforce `state_bounds` as hard constraints (the QP may then be infeasible) instead of soft ones.
    soft_weight : float or (float, float)
        Linear and quadratic penalty of the slack of soft state bounds (both > 0).
    disturbance : {"input", "output", None}
        Disturbance model for offset-free tracking (see above); ``None`` for none.
    observer : mapping, optional
        Kalman filter noise standard deviations: ``input_noise`` (process noise through each manipulated
        input), ``disturbance_noise`` (per-sample drift of each input disturbance), ``output_disturbance_noise``
        (per-sample drift of each output disturbance, by measured output), ``measurement_noise`` (each
        measured output), ``state_noise`` (each state); each a number, one number per signal or a mapping by
        name. Or ``gain``: a Luenberger gain of shape (states + disturbances, measured outputs) used as
        ``xa = xa_prior + gain (y - Co xa_prior)``. Defaults in :data:`DEFAULT_OBSERVER`.
    solver : {"daqp", "qrqp"}
        casadi QP solver: DAQP (dual active set, fast) or casadi's own qrqp (much slower).
    codegen : bool
        Compile the step to C (falls back to the Python call, with a warning, when that is impossible).
    on_infeasible : {"previous_plan", "hold", "raise"}
        When the QP has no solution: apply the next move of the last good plan (clipped to the bounds and
        the rate bound), hold the previous input, or raise :class:`~cosim.errors.ControllerError` at once.
        Each occurrence is recorded in :attr:`events`.
    max_fallbacks : int, optional
        Consecutive failures tolerated before :class:`~cosim.errors.ControllerError` (default `horizon`).

    Attributes
    ----------
    model : DesignModel
        The discrete design model.
    estimate, disturbance_estimate : numpy.ndarray
        Filtered state and disturbance estimates of the last call.
    target : (numpy.ndarray, numpy.ndarray)
        Steady-state target ``(xs, us)`` of the last call.
    plan : numpy.ndarray
        The moves planned for the next calls.
    info : dict
        ``horizon``, ``dt``, ``solver``, ``solver_path`` (``"c:daqp"`` or ``"python:daqp"``), ``library``
        (the compiled step) or ``codegen_unavailable`` (why not), ``qp_variables``, ``qp_constraints``,
        ``closed_loop_spectral_radius`` (unconstrained loop, state feedback), ``observer_spectral_radius``,
        ``lqr_gain`` (the unconstrained law ``u - us = -K [x - xs; u_prev - us]``), ``disturbances`` (e.g.
        ``["input:Tm", "output:theta_m"]``), ``weights``.

    Examples
    --------
    A double integrator, position measured, force bounded; the tracked position settles on the setpoint:

    >>> import control
    >>> plant = control.ss([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], 0, states=["x", "v"], inputs=["F"],
    ...                    outputs=["x"])
    >>> mpc = MPC(plant, dt=0.05, horizon=10, q=1.0, q_rate=0.0, r=0.01, r_delta=0.0, u_min=-1, u_max=1)
    >>> model = mpc.model
    >>> mpc.setpoint = 1.0
    >>> x = np.zeros(2)
    >>> for k in range(200):
    ...     u = mpc(k * model.dt, model.C @ x)
    ...     assert -1 <= u[0] <= 1
    ...     x = model.A @ x + model.B @ u
    >>> round(float(x[0]), 6)
    1.0
    """

    def __init__(self, model: control.StateSpace | DesignModel, *, dt: float | None = None, horizon: int = 20,
                 inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
                 tracked: Sequence[str] | None = None, q: Any = DEFAULT_WEIGHTS["q"],
                 q_rate: Any = DEFAULT_WEIGHTS["q_rate"], q_states: Any = None,
                 r: Any = DEFAULT_WEIGHTS["r"], r_delta: Any = DEFAULT_WEIGHTS["r_delta"], u_min: Any = None,
                 u_max: Any = None, du_max: Any = None, u0: Any = None, x0: Any = None,
                 state_bounds: Mapping[str, Any] | None = None, hard_state_bounds: bool = False,
                 soft_weight: Any = (1e6, 1e10), disturbance: str | None = "input",
                 observer: Mapping[str, Any] | None = None, solver: str = "daqp", codegen: bool = True,
                 on_infeasible: str = "previous_plan", max_fallbacks: int | None = None) -> None:
        dm = self._design_model(model, dt)
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
            raise InvalidSettingError(f"horizon must be an integer >= 1 (moves), got {horizon!r}")
        self.horizon = int(horizon)
        manipulable = [name for name in dm.inputs if name not in KNOWN_CONSTANT_INPUTS]
        if inputs is None:
            if not manipulable:
                raise InvalidSettingError(f"the model has no input to manipulate (inputs {list(dm.inputs)})")
            inputs = manipulable[:1]
        inputs, outputs = _names(inputs, "inputs"), _names(outputs if outputs is not None else dm.outputs, "outputs")
        tracked = _names(tracked if tracked is not None else outputs[:1], "tracked")
        iu, io = dm.index(inputs, "inputs"), dm.index(outputs, "outputs")
        dm.index(tracked, "outputs")
        constant = [name for name in inputs if name in KNOWN_CONSTANT_INPUTS]
        if constant:
            raise InvalidSettingError(f"input {constant[0]!r} is the model's constant term (held at 1); it cannot "
                                      "be manipulated")
        super().__init__(dt=dm.dt, inputs=inputs, outputs=outputs, tracked=tracked, u_min=u_min, u_max=u_max,
                         du_max=du_max)
        self.model = self.design_model = dm
        if on_infeasible not in _ON_INFEASIBLE:
            raise InvalidSettingError(f"on_infeasible must be one of {list(_ON_INFEASIBLE)}, got {on_infeasible!r}")
        self.on_infeasible = on_infeasible
        if max_fallbacks is None:
            max_fallbacks = self.horizon
        if isinstance(max_fallbacks, bool) or not isinstance(max_fallbacks, (int, np.integer)) or max_fallbacks < 0:
            raise InvalidSettingError(f"max_fallbacks must be an integer >= 0, got {max_fallbacks!r}")
        self.max_fallbacks = int(max_fallbacks)
        if solver not in _SOLVERS or not ca.has_conic(solver):
            raise InvalidSettingError(f"solver must be one of {list(_SOLVERS)} (casadi QP solvers that are exact, "
                                      f"silent and can be compiled), got {solver!r}")
        if state_bounds is not None and not isinstance(state_bounds, Mapping):
            raise InvalidSettingError(f"state_bounds must be a mapping name -> (lo, hi), got {state_bounds!r}")
        if observer is not None and not isinstance(observer, Mapping):
            raise InvalidSettingError(f"observer must be a mapping of settings, got {observer!r}")
        self._config = {"q": q, "q_rate": q_rate, "q_states": q_states, "r": r, "r_delta": r_delta, "u0": u0, "x0": x0,
                        "state_bounds": dict(state_bounds) if state_bounds is not None else None,
                        "hard_state_bounds": bool(hard_state_bounds), "soft_weight": soft_weight,
                        "disturbance": disturbance, "observer": dict(observer) if observer is not None else None,
                        "solver": solver, "codegen": bool(codegen)}
        m = len(inputs)
        # plant matrices seen by the controller: x+ = A x + B u + e, y = C x + f
        ic = [k for k, name in enumerate(dm.inputs) if name in KNOWN_CONSTANT_INPUTS]
        A, B = dm.A, dm.B[:, iu]
        e = dm.B[:, ic].sum(axis=1) if ic else np.zeros(dm.A.shape[0])
        C, f = dm.C[io], (dm.D[io][:, ic].sum(axis=1) if ic else np.zeros(len(io)))
        if np.any(dm.D[io][:, iu] != 0):
            raise InvalidSettingError("the model has direct feedthrough from the manipulated inputs to the measured "
                                      "outputs (D != 0); the MPC needs a strictly proper model")
        it = [outputs.index(name) for name in tracked]
        states = dm.states
        # ---- weights and terminal cost
        Qy = _square_matrix(q, tracked, "q", allow_matrix=True)
        Qv = _square_matrix(q_rate, tracked, "q_rate", allow_matrix=True)
        Qx = _square_matrix(0.0 if q_states is None else q_states, states, "q_states", allow_matrix=True)
        R = _square_matrix(r, inputs, "r", allow_matrix=True)
        S = _square_matrix(r_delta, inputs, "r_delta", allow_matrix=True)
        if np.min(np.linalg.eigvalsh(R + S)) <= 0:
            raise InvalidSettingError("r + r_delta must be positive for every input (the QP needs a strictly "
                                      f"convex cost); got r={np.diag(R).tolist()}, r_delta={np.diag(S).tolist()}")
        Cv = C[it] @ (A - np.eye(A.shape[0])) / dm.dt  # rate of change of the tracked outputs
        Q = C[it].T @ Qy @ C[it] + Cv.T @ Qv @ Cv + Qx
        P, K, rho = _terminal_cost(A, B, Q, R, S)
        # ---- disturbance model, observer, target
        Bd, Cd, labels = _disturbance_model(A, B, C, inputs, outputs, set(it), disturbance)
        n, nd = A.shape[0], Bd.shape[1]
        Ao = np.block([[A, Bd], [np.zeros((nd, n)), np.eye(nd)]])
        Bo = np.vstack([B, np.zeros((nd, m))])
        eo = np.concatenate([e, np.zeros(nd)])
        Co = np.hstack([C, Cd])
        L, rho_obs = _observer_gain(Ao, Bo, Co, self._config["observer"], states, inputs, outputs, labels)
        T, t0 = _target_map(A, B, C[it], f[it], Bd, Cd[it], e, inputs, tracked)
        self._u0 = self._initial_input(u0)
        self._x0 = _vector(x0, states, "x0", 0.0)
        cons = _state_constraints(state_bounds, dm)
        sw = np.broadcast_to(np.asarray(soft_weight, dtype=float), (2,)) if np.size(soft_weight) in (1, 2) else None
        if sw is None or not np.all(np.isfinite(sw)) or np.any(sw <= 0):
            raise InvalidSettingError(f"soft_weight must be a positive number or (linear, quadratic) pair of positive "
                                      f"numbers, got {soft_weight!r}")
        u_scale = _input_scale(self.u_min, self.u_max, B, Q, R, S, P, n)
        sp = StepProblem(Ao=Ao, Bo=Bo, eo=eo, Co=Co, fo=f, L=L, T=T, t0=t0, A=A, B=B, Q=Q, R=R, S=S, P=P,
                         N=self.horizon, u_min=self.u_min, u_max=self.u_max, du_max=self.du_max, u_scale=u_scale,
                         cons=cons, hard=bool(hard_state_bounds), soft_linear=float(sw[0]),
                         soft_quadratic=float(sw[1]), solver=solver)
        qp = condense(sp)
        if np.min(np.linalg.eigvalsh(qp.H)) <= 1e-13:
            raise InvalidSettingError("the QP Hessian is not positive definite; increase r or r_delta")
        self._problem, self._qp = sp, qp
        fun, lay = step_function(sp, qp, "cosim_mpc_step")
        self._fun, self._lay = fun, lay
        # ---- buffers: meas = [y; r]; two state buffers used alternately (input of one call, output of the next)
        self._meas = np.zeros(lay.n_meas)
        self._states = (np.zeros(lay.n_state), np.zeros(lay.n_state))
        self._out = np.zeros(lay.n_out)
        self._cfun = None
        self.info.update({
            "horizon": self.horizon, "dt": self.dt, "solver": solver, "qp_variables": int(qp.H.shape[0]),
            "qp_constraints": int(qp.Ac.shape[0]), "closed_loop_spectral_radius": rho,
            "observer_spectral_radius": rho_obs, "lqr_gain": K.tolist(), "disturbances": labels,
            "weights": {"q": np.diag(Qy).tolist(), "q_rate": np.diag(Qv).tolist(), "r": np.diag(R).tolist(),
                        "r_delta": np.diag(S).tolist()},
        })
        self._bind(codegen)
        self.reset()

    # ------------------------------------------------------------------ construction helpers
    @staticmethod
    def _design_model(model: Any, dt: float | None) -> DesignModel:
        if isinstance(model, DesignModel):
            if dt is not None and not math.isclose(float(dt), model.dt, rel_tol=1e-9):
                raise InvalidSettingError(f"the design model has dt={model.dt}, but dt={dt} was asked; leave dt out")
            return model
        return DesignModel.from_statespace(model, dt=dt)

    def _initial_input(self, u0: Any) -> np.ndarray:
        if u0 is None:
            return np.clip(np.zeros(len(self.inputs)), self.u_min, self.u_max)
        u = _vector(u0, self.inputs, "u0", 0.0)
        if np.any(u < self.u_min) or np.any(u > self.u_max):
            raise InvalidSettingError(f"u0={u.tolist()} is outside [u_min, u_max]")
        return u

    def _bind(self, codegen: bool) -> None:
        """Compile the step to C and bind the buffers; or keep the casadi Python call (and say why)."""
        reason = "codegen=False"
        if codegen:
            libs, reason = codegen_support(self._problem.solver)
            if not reason:
                try:
                    start = time.perf_counter()
                    library = compile_function(self._fun, libs)
                    bindings = [([self._meas, self._states[k]], [self._out, self._states[1 - k]]) for k in (0, 1)]
                    bound = BoundFunction(library, self._fun.name(), bindings)
                    self.info["compile_seconds"] = round(time.perf_counter() - start, 3)
                    self.info["library"] = str(library)
                    self._cfun, self._bound = bound.fn, bound
                    self._ptrs = (bound.pointers(0), bound.pointers(1))
                    self._iw, self._w = bound.iw, bound.w
                except (BuildError, OSError) as exc:
                    reason = str(exc)
            if reason:
                warnings.warn(f"MPC: the step is not compiled ({reason}); calling casadi from Python instead "
                              "(slower, same result)", RuntimeWarning, stacklevel=3)
        path = "c" if self._cfun is not None else "python"
        self.info["solver_path"] = f"{path}:{self._problem.solver}"
        if self._cfun is None:
            self.info["codegen_unavailable"] = reason
            # casadi's FunctionBuffer: the Function evaluated in place on the bound numpy buffers
            self._buffers = []
            for k in (0, 1):
                buffer, evaluate = self._fun.buffer()
                for i, a in enumerate((self._meas, self._states[k])):
                    buffer.set_arg(i, memoryview(a))
                for i, a in enumerate((self._out, self._states[1 - k])):
                    buffer.set_res(i, memoryview(a))
                self._buffers.append((buffer, evaluate))

    # ------------------------------------------------------------------ the calling convention
    def reset(self) -> None:
        """Clear the observer (estimate ``x0``, zero disturbance), the plan, the previous input and events."""
        lay = self._lay
        s = self._states[0]
        s[:] = 0.0
        s[:lay.n] = self._x0
        s[lay.na:lay.na + lay.m] = self._u0
        s[lay.na + lay.m:] = np.tile(self._u0, lay.N)
        self._k = 0
        self._failures = 0
        self._out[:] = np.nan
        self._out[lay.m + 1:lay.m + 1 + lay.na] = s[:lay.na]
        self.events.clear()

    def _set_setpoint(self, r: np.ndarray) -> None:
        self._setpoint = r
        self._meas[self._lay.p:] = r

    def __call__(self, t: float, y: Sequence[float]) -> np.ndarray:
        """The input to hold over ``[t, t + dt)`` given the measured outputs `y` (in :attr:`outputs` order)."""
        try:
            if len(y) != self._lay.p:
                raise ValueError
            self._meas[:self._lay.p] = y
        except (TypeError, ValueError):
            raise InvalidSettingError(f"MPC expects {self._lay.p} measured output value(s) for {list(self.outputs)}, "
                                      f"got {y!r}") from None
        k = self._k
        if self._cfun is not None:
            arg, res = self._ptrs[k]
            rc = self._cfun(arg, res, self._iw, self._w, 0)
        else:
            rc = self._call_python(k)
        out = self._out
        if rc or not out[self._lay.m] <= _VIOLATION_TOL:
            return self._fallback(t, k, rc)
        self._k = 1 - k
        self._failures = 0
        return out[:self._lay.m].copy()

    def _call_python(self, k: int) -> int:
        buffer, evaluate = self._buffers[k]
        try:
            evaluate()
        except RuntimeError:  # the solver failed: casadi raises (error_on_fail)
            return 1
        return int(buffer.ret())

    def _fallback(self, t: float, k: int, rc: int) -> np.ndarray:
        """The QP failed: apply the documented fallback, advance the observer with it, record an event."""
        lay, sp = self._lay, self._problem
        y = self._meas[:lay.p]
        if not np.all(np.isfinite(y)):
            raise ControllerError(f"MPC got a non-finite measurement {y.tolist()} at t={t:.6g} s")
        violation = self._out[lay.m]
        if rc:
            reason = f"{sp.solver} found no optimal solution (infeasible QP, cycling or iteration limit)"
        elif not np.isfinite(violation):
            reason = "the QP solution was not finite"
        else:
            reason = f"the QP solution violates the constraints by {violation:.3g}"
        self._failures += 1
        if self.on_infeasible == "raise" or self._failures > self.max_fallbacks:
            raise ControllerError(f"MPC failed at t={t:.6g} s: {reason}, {self._failures} consecutive time(s) "
                                  f"(on_infeasible={self.on_infeasible!r}, max_fallbacks={self.max_fallbacks}); "
                                  "relax hard state bounds or the input limits")
        na, m = lay.na, lay.m
        s, s_next = self._states[k], self._states[1 - k]
        xa_prior, u_prev, plan = s[:na], s[na:na + m], s[na + m:]
        xa = xa_prior + sp.L @ (y - sp.Co @ xa_prior - sp.fo)
        lo = np.maximum(self.u_min, u_prev - self.du_max)
        hi = np.minimum(self.u_max, u_prev + self.du_max)
        if self.on_infeasible == "previous_plan":
            u = np.clip(plan[:m], lo, hi)
            action = f"applied move {self._failures} of the last good plan"
        else:
            u = np.clip(u_prev, lo, hi)
            action = "held the previous input"
        target = sp.T @ np.concatenate([self._setpoint, xa[lay.n:]]) + sp.t0
        s_next[:na] = sp.Ao @ xa + sp.Bo @ u + sp.eo
        s_next[na + m:] = np.concatenate([plan[m:], plan[len(plan) - m:]])
        s_next[na:na + m] = u
        self._out[:m] = u
        self._out[m + 1:m + 1 + na] = xa
        self._out[m + 1 + na:] = target
        self._event(t, "infeasible", f"{reason}; {action}: u={u.tolist()}")
        self._k = 1 - k
        return u.copy()

    # ------------------------------------------------------------------ what the controller knows
    @property
    def estimate(self) -> np.ndarray:
        """Filtered state estimate of the last call (model states order); before the first call, ``x0``."""
        lay = self._lay
        return self._out[lay.m + 1:lay.m + 1 + lay.n].copy()

    @property
    def disturbance_estimate(self) -> np.ndarray:
        """Estimated disturbances of the last call, in the order of ``info["disturbances"]``."""
        lay = self._lay
        return self._out[lay.m + 1 + lay.n:lay.m + 1 + lay.na].copy()

    @property
    def design(self) -> StepProblem:
        """The design matrices: augmented model and observer gain, target map, cost, terminal ``P``, limits."""
        return self._problem

    @property
    def plan(self) -> np.ndarray:
        """Moves planned for the next `horizon` calls, shape (horizon, inputs); the last one is repeated."""
        lay = self._lay
        return self._states[self._k][lay.na + lay.m:].reshape(lay.N, lay.m).copy()

    @property
    def target(self) -> tuple[np.ndarray, np.ndarray]:
        """Steady-state target ``(xs, us)`` of the last call."""
        lay = self._lay
        start = lay.m + 1 + lay.na
        return self._out[start:start + lay.n].copy(), self._out[start + lay.n:].copy()

    def to_dict(self) -> dict[str, Any]:
        """As :meth:`Controller.to_dict`, without the facts of this machine (library path, solver path)."""
        data = super().to_dict()
        data["info"] = {k: v for k, v in data["info"].items() if k not in _MACHINE_INFO}
        return data

    def _settings(self) -> dict[str, Any]:
        c = self._config
        return {"model": self.model, "horizon": self.horizon, "inputs": list(self.inputs),
                "outputs": list(self.outputs), "tracked": list(self.tracked),
                "q": c["q"], "q_rate": c["q_rate"], "q_states": c["q_states"], "r": c["r"], "r_delta": c["r_delta"],
                "u_min": self.u_min, "u_max": self.u_max, "du_max": self.du_max, "u0": c["u0"], "x0": c["x0"],
                "state_bounds": c["state_bounds"], "hard_state_bounds": c["hard_state_bounds"],
                "soft_weight": c["soft_weight"], "disturbance": c["disturbance"], "observer": c["observer"],
                "solver": c["solver"], "codegen": c["codegen"], "on_infeasible": self.on_infeasible,
                "max_fallbacks": self.max_fallbacks}


# ---------------------------------------------------------------------------------------------------------------
# design: names, terminal cost, disturbance model, observer, target, constraints


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
