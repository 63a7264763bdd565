"""The linear MPC controller, :class:`MPC`: its settings checked, its design assembled, its step bound to
compiled C (or casadi's Python API), the calling convention with its fallback when the QP fails, and its file.

The pipeline one call runs is described in :mod:`controllers.mpc`.
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

from cosim.errors import BuildError, ControllerError, InvalidSettingError

from ..base import KNOWN_CONSTANT_INPUTS, Controller, DesignModel, register
from ._codegen import BoundFunction, codegen_support, compile_function
from ._design import (
    DEFAULT_WEIGHTS,
    _disturbance_model,
    _input_scale,
    _names,
    _observer_gain,
    _square_matrix,
    _state_constraints,
    _target_map,
    _terminal_cost,
    _vector,
)
from ._qp import StepProblem, condense, step_function

__all__ = ["MPC"]

_ON_INFEASIBLE = ("previous_plan", "hold", "raise")
_SOLVERS = ("daqp", "qrqp")
_VIOLATION_TOL = 1e-4  # in the scaled QP (inputs scaled to their range, rows to unit norm)
_MACHINE_INFO = ("solver_path", "library", "compile_seconds", "codegen_unavailable")


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
        Input bounds and largest input change per sample (default none). `u_max` alone mirrors into
        ``u_min = -u_max``, as ``--u-max`` does in ``cosim design mpc`` (give ``u_min=-math.inf`` for no lower
        bound).
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
        if u_min is None and u_max is not None:
            try:
                u_min = -np.asarray(u_max, dtype=float)  # as --u-max alone does in `cosim design mpc`
            except (TypeError, ValueError):
                pass  # refused below, in the base class's words
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

