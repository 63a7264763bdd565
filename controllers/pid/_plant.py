"""The plant as the PID tuner sees it, and what a loop's frequency response says (private to :mod:`controllers.pid`).

* :class:`_Plant` - the model sampled with zero-order hold (and a computational delay) from the manipulated
  input to the controlled output (and a measured velocity): its exact frequency response on a grid refined
  around every lightly damped mode, the loop with a PID's gains, and the PID loop's closed-loop state space;
* :func:`_shape` - the PID's discrete law over ``kp``, ``C(z)/kp``, on arrays of points;
* :func:`_loop_figures` - gain crossings, phase and gain margins and ``min |1 + L|`` of a loop on the grid;
* :func:`_antiresonance` - the lowest lightly damped zero from the input to the velocity.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import control
import numpy as np

from ..base import DesignModel

#: Damping below which a zero counts as lightly damped (:func:`_antiresonance`).
_LIGHT = 0.3


def _shape(z: Any, dt: float, ti: float, td: Any, tf: Any) -> Any:
    """``C(z)/kp`` for ``Ti = ti`` (inf: no integral), ``Td = td``, filter ``tf`` (arrays broadcast)."""
    c = 1.0 + (dt / ti) / (z - 1.0) if math.isfinite(ti) else 1.0
    return c + td * (z - 1.0) / ((tf + dt) * z - tf)


def _wrap(phase: Any) -> Any:
    """Angle wrapped into (-pi, pi]."""
    return np.pi - np.mod(np.pi - phase, 2 * np.pi)


class _Plant:
    """The discrete plant (ZOH, then `delay` samples) from the manipulated input to the controlled output (and,
    for the velocity structure, to the measured velocity), and its exact response on a frequency grid."""

    def __init__(self, model: DesignModel, i_in: int, i_out: int, delay: int, w_lo: float,
                 i_vel: int | None = None) -> None:
        h = model.dt
        rows = [i_out] if i_vel is None else [i_out, i_vel]
        a, b = model.A, model.B[:, [i_in]]
        c, d = model.C[rows, :], model.D[rows][:, [i_in]]
        if delay:  # u reaches the plant `delay` samples later: a shift register in front of it
            n = a.shape[0]
            a = np.block([[a, np.zeros((n, delay - 1)), b],
                          [np.zeros((delay, n)), np.eye(delay, delay, -1)]])
            b = np.vstack([np.zeros((n, 1)), np.eye(delay, 1)])
            c = np.hstack([c, np.zeros((len(rows), delay - 1)), d])
            d = np.zeros((len(rows), 1))
        self.A, self.B, self.C, self.D, self.dt, self.delay = a, b, c, d, h, delay
        self.model = model
        self.input, self.output = model.inputs[i_in], model.outputs[i_out]
        self.velocity = None if i_vel is None else model.outputs[i_vel]
        self.kds = np.zeros(0)  # velocity gains the search tries (set by tune_pid)
        self.gains: tuple[float, ...] = (1.0,)  # loop gains the predicted setpoint step must be good for
        self.wc_cap = math.inf  # highest crossover the search may pin (below the antiresonance)
        w_nyq = math.pi / h
        w = np.geomspace(w_lo, w_nyq, max(int(100 * math.log10(w_nyq / w_lo)), 200))
        extra = []
        for lam in np.linalg.eigvals(model.A):  # resolve lightly damped modes: points across each peak
            if abs(lam) > 1e-12 and lam.imag > 0:
                s = np.log(lam) / h
                width = max(abs(s.real), 1e-4 * s.imag)  # even counts: never exactly on an undamped pole
                extra.append(s.imag + width * np.linspace(-8.0, 8.0, 64))
                extra.append(s.imag * (1.0 + np.linspace(-0.05, 0.05, 40)))
        if extra:
            e = np.concatenate(extra)
            w = np.union1d(w, e[(e > w_lo) & (e < w_nyq)])
        self.w = w
        self.z = np.exp(1j * w * h)
        resp = self.responses(self.z)
        self.p = resp[0]
        self.pv = resp[1] if i_vel is not None else None

    def responses(self, z: np.ndarray) -> np.ndarray:
        """``P(z)`` of every output row (controlled output, then the velocity) at the points `z`."""
        z = np.atleast_1d(z)
        n, rows = self.A.shape[0], self.C.shape[0]
        out = np.empty((rows, z.size), dtype=complex)
        eye = np.eye(n)
        for k in range(0, z.size, 512):
            zz = z[k:k + 512]
            try:
                x = np.linalg.solve(zz[:, None, None] * eye - self.A, np.broadcast_to(self.B, (zz.size, n, 1)))
            except np.linalg.LinAlgError:  # a point on an undamped pole: the response is infinite there
                x = np.stack([np.linalg.lstsq(zi * eye - self.A, self.B, rcond=None)[0] for zi in zz])
                singular = [np.linalg.matrix_rank(zi * eye - self.A) < n for zi in zz]
                x[singular] = np.inf
            out[:, k:k + 512] = (self.C @ x)[:, :, 0].T + self.D[:, :1]
        return out

    def response(self, z: np.ndarray) -> np.ndarray:
        """``P(z)`` of the controlled output at the points `z`."""
        return self.responses(z)[0]

    def loop(self, kp: float, ki: float, kd: float, tf: float) -> np.ndarray:
        """The loop ``L`` broken at the plant input, on :attr:`w`: ``C(z) P(z)`` for the PID on one output,
        ``(kp + ki*dt/(z - 1)) P(z) + K_v(z) P_v(z)`` with a measured velocity."""
        h, z = self.dt, self.z
        if self.velocity is None:
            return kp * _shape(z, h, kp / ki if ki else math.inf, kd / kp if kp else 0.0, tf) * self.p
        return (kp + ki * h / (z - 1.0)) * self.p + kd * h * z / ((tf + h) * z - tf) * self.pv

    def negated(self) -> _Plant:
        """The same plant with the opposite sign of its gain."""
        other = copy.copy(self)
        other.C, other.D, other.p = -self.C, -self.D, -self.p
        other.pv = None if self.pv is None else -self.pv
        return other

    def statespace(self) -> control.StateSpace:
        return control.ss(self.A, self.B, self.C, self.D, self.dt)

    def closed_loop(self, kp: float, ki: float, kd: float, tf: float) -> tuple[np.ndarray, ...] | None:
        """``z+ = A z + B w``, ``y = C z + D w`` of the PID loop (limits off), ``w = [r_P, r_I, d]``.

        ``r_P`` drives only the proportional setpoint path ``kp*r`` and ``r_I`` only the integrator, so the
        setpoint response for a weight b is ``b*y(r_P) + y(r_I)``; ``d`` is a load step at the plant input.
        None when the loop is algebraically ill-posed.
        """
        if self.velocity is not None:
            return self._closed_loop_velocity(kp, ki, kd, tf)
        h = self.dt
        ac, be, br, cc = [], [], [], []  # controller: xc+ = Ac xc + Be*(-y) + Br*r_I, u = Cc xc + Dc*(-y) + kp*r_P
        if ki:
            ac.append(1.0), be.append(ki * h), br.append(ki * h), cc.append(1.0)
        dc = kp
        if kd:
            ad, bd = tf / (tf + h), kd / (tf + h)
            dc += bd
            if ad:
                ac.append(ad), be.append(bd * (ad - 1.0)), br.append(0.0), cc.append(1.0)
        nc = len(ac)
        ac_m, be_m, br_m = np.diag(ac), np.array(be).reshape(nc, 1), np.array(br).reshape(nc, 1)
        cc_m = np.array(cc).reshape(1, nc)
        ap, bp, cp, dp = self.A, self.B, self.C, float(self.D[0, 0])
        n = ap.shape[0]
        den = 1.0 + dc * dp
        if abs(den) < 1e-12:
            return None
        g = 1.0 / den
        ku = g * np.hstack([-dc * cp, cc_m])                                   # u = ku z + kw w
        kw = g * np.array([[kp, 0.0, -dc * dp]])
        cy = np.hstack([cp, np.zeros((1, nc))]) + dp * ku                      # y = cy z + dy w
        dy = dp * kw + np.array([[0.0, 0.0, dp]])
        bu = np.vstack([bp, np.zeros((nc, 1))])
        be_z = np.vstack([np.zeros((n, 1)), be_m])
        a_cl = np.block([[ap, np.zeros((n, nc))], [np.zeros((nc, n)), ac_m]]) + bu @ ku - be_z @ cy
        b_cl = bu @ (kw + np.array([[0.0, 0.0, 1.0]])) - be_z @ dy
        b_cl[n:, 1:2] += br_m
        return a_cl, b_cl, cy, dy

    def _closed_loop_velocity(self, kp: float, ki: float, kd: float, tf: float) -> tuple[np.ndarray, ...] | None:
        """:meth:`closed_loop` for the PI on the controlled output with feedback of the measured velocity."""
        h = self.dt
        ad, bv = tf / (tf + h), kd * h / (tf + h)
        # controller states: the integral I (I+ = I + ki*h*(r_I - y)) and the velocity filter D (D+ = ad*D - bv*v)
        # u = kp*r_P + I + ad*D - kp*y - bv*v, with m = [y, v] = Cm x + Dm (u + d)
        ac, bm, br, cc = [], [], [], []
        if ki:
            ac.append(1.0), bm.append([ki * h, 0.0]), br.append(ki * h), cc.append(1.0)
        if kd and ad:
            ac.append(ad), bm.append([0.0, bv]), br.append(0.0), cc.append(ad)
        nc = len(ac)
        ac_m, bm_m = np.diag(ac).reshape(nc, nc), np.array(bm).reshape(nc, 2)
        br_m, cc_m = np.array(br).reshape(nc, 1), np.array(cc).reshape(1, nc)
        ap, bp, cm, dm = self.A, self.B, self.C, self.D
        n = ap.shape[0]
        gain = np.array([[kp, bv]])
        gd = float((gain @ dm)[0, 0])
        den = 1.0 + gd
        if abs(den) < 1e-12:
            return None
        ku = np.hstack([-gain @ cm, cc_m]) / den                               # u = ku z + kw w
        kw = np.array([[kp, 0.0, -gd]]) / den
        cmz = np.hstack([cm, np.zeros((2, nc))]) + dm @ ku                      # m = cmz z + dmw w
        dmw = dm @ (kw + np.array([[0.0, 0.0, 1.0]]))
        bu = np.vstack([bp, np.zeros((nc, 1))])
        bm_z = np.vstack([np.zeros((n, 2)), bm_m])
        a_cl = np.block([[ap, np.zeros((n, nc))], [np.zeros((nc, n)), ac_m]]) + bu @ ku - bm_z @ cmz
        b_cl = bu @ (kw + np.array([[0.0, 0.0, 1.0]])) - bm_z @ dmw
        b_cl[n:, 1:2] += br_m
        return a_cl, b_cl, cmz[:1], dmw[:1]


def _antiresonance(model: DesignModel, i_in: int, i_vel: int) -> float | None:
    """Frequency [rad/s] of the lowest lightly damped zero from input `i_in` to output `i_vel` (the
    antiresonance of a two-mass drive seen from the motor), or None: finite generalised eigenvalues of the
    Rosenbrock pencil, mapped to s = ln(z)/dt."""
    from scipy.linalg import eig

    n = model.A.shape[0]
    pencil = np.block([[model.A, model.B[:, [i_in]]], [model.C[[i_vel], :], model.D[[i_vel]][:, [i_in]]]])
    e = np.zeros((n + 1, n + 1))
    e[:n, :n] = np.eye(n)
    alpha, beta = eig(pencil, e, right=False, homogeneous_eigvals=True)
    finite = np.abs(beta) > 1e-9 * np.maximum(np.abs(alpha), 1.0)
    z = alpha[finite] / beta[finite]
    z = z[(np.abs(z) > 1e-12) & (z.imag > 0)]
    s = np.log(z.astype(complex)) / model.dt
    light = s[-s.real < _LIGHT * np.abs(s)]
    return float(np.abs(light).min()) if light.size else None


def _loop_figures(w: np.ndarray, loop: np.ndarray) -> dict[str, Any]:
    """Gain crossings and their phase margins, negative-real-axis crossings and their gains, min |1 + L|.

    The phase margin of a crossing is the phase change, lag or lead, that would move it onto -1: ``|arg(-L)|``
    (a collocated velocity loop crosses with phase lead).
    """
    mag = np.abs(loop)
    lm = np.log(np.maximum(mag, 1e-300))
    idx = np.nonzero(np.sign(lm[:-1]) != np.sign(lm[1:]))[0]
    frac = lm[idx] / (lm[idx] - lm[idx + 1])
    pms = np.abs(np.degrees(np.angle(-(loop[idx] + frac * (loop[idx + 1] - loop[idx])))))
    wcs = np.exp(np.log(w[idx]) + frac * (np.log(w[idx + 1]) - np.log(w[idx])))
    im = loop.imag
    jdx = np.nonzero(np.sign(im[:-1]) != np.sign(im[1:]))[0]
    f2 = im[jdx] / (im[jdx] - im[jdx + 1])
    re = loop.real[jdx] + f2 * (loop.real[jdx + 1] - loop.real[jdx])
    gains = -re[re < 0]
    if loop.real[-1] < 0 and abs(im[-1]) <= 1e-9 * mag[-1]:  # at the Nyquist frequency L is real
        gains = np.append(gains, -loop.real[-1])
    upper, lower = gains[gains < 1], gains[gains > 1]
    dist = np.abs(1.0 + loop)
    return {"pm": float(pms.min()) if pms.size else math.inf, "w_first": float(wcs[0]) if wcs.size else math.inf,
            "gm": float(1.0 / upper.max()) if upper.size else math.inf,
            "gm_low": float(1.0 / lower.min()) if lower.size else 0.0, "mm": float(dist.min())}
