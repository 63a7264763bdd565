"""The PID loop with its actuator's limits (private to :mod:`controllers.pid`): the set-point step the design must
deliver, and the step response of the PID's exact discrete law, limits and anti-windup on, against the model.

* :class:`_Actuator` - the limits, rate limit, bias and anti-windup the tuned PID will run with;
* :func:`_default_step` - the step a design with limits is checked on when none is asked for;
* :func:`_saturated_steps` - the set-point step of many PID designs at once (the law of
  :class:`~controllers.pid.PID`, vectorised over designs) against the model sampled with zero-order hold;
* :func:`_figures` - overshoot and settling time of those responses, as :func:`cosim.loop.response_metrics`
  computes them on a closed-loop run;
* :func:`_pid_step` - the same step with a :class:`~controllers.pid.PID` itself called sample by sample: the
  prediction ``tune_pid`` reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ._plant import _Plant

if TYPE_CHECKING:
    from .controller import PID

#: Default design step: the step whose steady input takes this fraction of the actuator's range (the rest is
#: left for accelerating, braking and disturbances).
_STEADY_FRACTION = 0.5
#: Settling band of the predicted step, as a fraction of the step (the validation's default).
_BAND = 0.02


@dataclass(frozen=True)
class _Actuator:
    """What the PID's output goes through: limits, rate limit, bias, anti-windup (as :class:`PID` takes them)."""

    lo: float
    hi: float
    du: float
    u0: float
    anti_windup: str | None
    tt: float | None

    @property
    def limited(self) -> bool:
        return math.isfinite(self.lo) or math.isfinite(self.hi) or math.isfinite(self.du)


def _static_gain(plant: _Plant) -> float | None:
    """Steady-state gain from the input to the controlled output, or None for an integrating plant (see
    :meth:`~controllers.base.DesignModel.static_gain`)."""
    return plant.model.static_gain(plant.input, plant.output)


def _default_step(plant: _Plant, act: _Actuator) -> float | None:
    """The step a design with input limits must deliver when none is asked: the one whose steady input takes
    :data:`_STEADY_FRACTION` of the input's range on its narrower side (about the bias `u0`), to two significant
    digits, rounded down. None for an
    integrating plant (it holds any position with no input, so the limit sets no step size) or without limits.
    """
    g = _static_gain(plant)
    room = min(act.hi - act.u0, act.u0 - act.lo)
    if g is None or not (math.isfinite(room) and room > 0):
        return None
    step = _STEADY_FRACTION * room * abs(g)
    scale = 10.0 ** (math.floor(math.log10(step)) - 1)
    return float(f"{math.floor(step / scale * (1 + 1e-12)) * scale:.2g}")  # 2 digits, rounded down: 0.1236 -> 0.12


def _tracking_times(kp: np.ndarray, ki: np.ndarray, kd: np.ndarray, dt: float, tt: float | None) -> np.ndarray:
    """The back-calculation time :class:`PID` takes by default: ``sqrt(Ti*Td)``, ``Ti`` without derivative."""
    if tt is not None:
        return np.full(kp.shape, float(tt))
    with np.errstate(divide="ignore", invalid="ignore"):
        ti = np.where(ki > 0, kp / ki, np.inf)
        td = np.where(kp > 0, kd / kp, 0.0)
        t = np.where(td > 0, np.sqrt(ti * td), ti)
    return np.maximum(t, dt)


def _saturated_steps(plant: _Plant, gains: np.ndarray, b: np.ndarray, step: np.ndarray | float, act: _Actuator,
                     n: int) -> tuple[np.ndarray, np.ndarray]:
    """Controlled output and input (``n x M``) after a set-point `step` at sample 0, the loop at rest before.

    Row ``j`` of `gains` is ``(kp, ki, kd, tf)`` of design ``j``, ``b[j]`` its set-point weight, ``step[j]`` its
    step (or one for all). The law is :class:`~controllers.pid.PID`'s (module docstring there): derivative of the
    measurement (no kick on the first sample) or of the measured velocity, rate limit (not on the first
    sample), limits, then the integrator with back-calculation (or clamping, or none). The measurement at
    ``t_k`` is taken before ``u_k`` is applied. Between the limits the loop is linear in the augmented state
    ``z = [x, I, D, y_prev, u_prev]``, so a sample is two products with the designs' matrices and a clip.
    """
    h = plant.dt
    kp, ki, kd, tf = (np.asarray(gains[:, i], float) for i in range(4))
    m, nx = kp.size, plant.A.shape[0]
    s = np.broadcast_to(np.asarray(step, float), (m,))
    ad = tf / (tf + h)
    bd = kd * h / (tf + h) if plant.velocity is not None else kd / (tf + h)
    bi = ki * h
    ao = ((h / _tracking_times(kp, ki, kd, h, act.tt)) * (ki > 0) if act.anti_windup == "back-calculation"
          else np.zeros(m))
    ii, idd, iy, iu = nx, nx + 1, nx + 2, nx + 3  # positions of I, D, y_prev, u_prev in z
    nz = nx + 4
    ry = np.zeros(nz)
    ry[:nx], ry[iu] = plant.C[0], plant.D[0, 0]  # y_k = C x_k + D u_(k-1)
    rm = np.zeros(nz)  # what the derivative acts on: y - y_prev, or the measured velocity
    if plant.velocity is None:
        rm[:] = ry
        rm[iy] -= 1.0
    else:
        rm[:nx], rm[iu] = plant.C[1], plant.D[1, 0]
    e_i, e_d = np.eye(nz)[ii], np.eye(nz)[idd]
    rd = ad[:, None] * e_d - bd[:, None] * rm                    # D_k = rd . z
    kv = -kp[:, None] * ry + e_i + rd                            # v_k = kv . z + c
    c = act.u0 + kp * np.asarray(b, float) * s
    f = np.zeros((m, nz, nz))
    f[:, :nx, :nx] = plant.A
    f[:, ii] = e_i - bi[:, None] * ry
    f[:, idd] = rd
    f[:, iy] = ry
    gu = np.zeros((m, nz))
    gu[:, :nx], gu[:, ii], gu[:, iu] = plant.B[:, 0], ao, 1.0
    gv = np.zeros((m, nz))
    gv[:, ii] = -ao
    g0 = np.zeros((m, nz))
    g0[:, ii] = bi * s
    clamping, rate = act.anti_windup == "clamping", math.isfinite(act.du)
    z = np.zeros((m, nz))
    ys, us = np.empty((n, m)), np.empty((n, m))
    for k in range(n):
        v = (kv * z).sum(axis=1) + c
        u = np.clip(v, z[:, iu] - act.du, z[:, iu] + act.du) if rate and k else v
        u = np.clip(u, act.lo, act.hi)
        us[k] = u
        ys[k] = z @ ry
        z_next = (f @ z[:, :, None])[:, :, 0] + u[:, None] * gu + v[:, None] * gv + g0
        if clamping:  # no integration while limited and the error pushes further into the limit
            e = s - ys[k]
            hold = (u != v) & ((u < v) != (e < 0))
            z_next[:, ii] -= np.where(hold, bi * e, 0.0)
        z = z_next
    return ys, us


def _figures(y: np.ndarray, step: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Overshoot [%] and 2 % settling time [s] of each column of `y` (a step at sample 0), as the validation
    measures them: settling is inf when the response is outside the band at the last sample."""
    direction = math.copysign(1.0, step)
    overshoot = np.maximum(0.0, np.max((y - step) * direction, axis=0)) / abs(step) * 100.0
    outside = np.abs(y - step) > _BAND * abs(step)
    n = y.shape[0]
    last = n - np.argmax(outside[::-1], axis=0)  # the sample after the last one outside the band
    settling = np.where(outside.any(axis=0), last * dt, 0.0)
    settling[outside[-1]] = math.inf
    overshoot[~np.all(np.isfinite(y), axis=0)] = math.inf
    return overshoot, settling


def _pid_step(pid: PID, plant: _Plant, step: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The set-point step of `pid` itself (a copy: its limits, rate limit and anti-windup) against the model,
    sample by sample, from rest: the controlled output and the input, ``n`` samples each."""
    import copy

    ctrl = copy.deepcopy(pid)
    ctrl.reset()
    ctrl.setpoint = step
    x = np.zeros(plant.A.shape[0])
    u = 0.0
    ys, us = np.empty(n), np.empty(n)
    vel_first = plant.velocity is not None and ctrl.outputs[0] == plant.velocity
    for k in range(n):
        meas = plant.C @ x + plant.D[:, 0] * u
        y = meas if plant.velocity is None else (meas[::-1] if vel_first else meas)
        u = float(ctrl(k * plant.dt, y)[0])
        ys[k], us[k] = meas[0], u
        x = plant.A @ x + plant.B[:, 0] * u
    return ys, us
