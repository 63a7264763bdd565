"""Tuning of :class:`~controllers.pid.PID` on a linear model: :func:`tune_pid`.

Two structures, both designed on the *exact discrete loop* (the model sampled with zero-order hold at the
controller's sample time, the PID's own discrete law) and checked with ``control.stability_margins`` on the
loop's exact frequency response:

* PID on one output (the derivative of that output): loop shaping at the gain crossover;
* PI on the controlled output plus feedback of a measured velocity (``velocity="omega_m"``), the servo
  structure: a direct search over the velocity gain and the crossover, with ``kp`` and ``ki`` solved exactly
  for the phase margin, the loop broken at the plant input.

See :func:`tune_pid` for the methods. ``controllers.pid`` re-exports :func:`tune_pid`.

Examples
--------
>>> import control
>>> plant = control.ss(control.tf([2.0], [0.5, 1.0]), inputs=["u"], outputs=["y"])
>>> pid = tune_pid(plant, dt=0.01, bandwidth=5.0)
>>> pid.info["structure"], round(pid.info["phase_margin_deg"], 1)
('PI', 60.0)
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import control
import numpy as np
from scipy.optimize import brentq

from cosim.errors import ControllerError, InvalidSettingError, UnknownVariableError

from .base import KNOWN_CONSTANT_INPUTS, DesignModel

if TYPE_CHECKING:
    from .pid import PID

__all__ = ["tune_pid"]

#: Integral times ``Ti*wc`` and derivative filters ``n = Td/tf`` the search tries at each crossover.
_ALPHAS = (1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0)
_NS = (2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 30.0)
#: ``Td*wc`` grid on which the phase condition is bracketed before it is solved exactly.
_BETAS = np.logspace(-3.0, 2.0, 201)
#: Crossover candidates per decade, decades searched below `max_crossover`, and how far below the highest
#: crossover with an admissible step response the candidates still compete.
_WC_PER_DECADE = 24
_WC_DECADES = 6.0
_WC_SPAN = 2.0
#: Tolerance on the phase margin of secondary gain crossings [deg].
_PM_TOL = 0.5
#: Velocity structure: gains tried, as fractions of the one whose velocity loop alone crosses over at
#: `max_crossover`, and the relative tolerance on the position loop's crossover being the lowest one.
_KD_FRACTIONS = 10.0 ** np.linspace(-3.0, 0.0, 97)
_FIRST_TOL = 0.01
#: Velocity structure: loop gains (about -2 to +2 dB) over which the predicted setpoint step must keep the
#: overshoot limit, and the default phase margin [deg].
_VELOCITY_GAINS = (0.8, 0.9, 1.0, 1.1, 1.25)
_VELOCITY_PM = 48.0
#: Velocity structure: highest position-loop crossover as a fraction of the antiresonance (the lowest lightly
#: damped zero, damping below _LIGHT, from the input to the velocity), where the load decouples from the motor.
_ANTIRESONANCE_FRACTION = 0.7
_LIGHT = 0.3
#: Setpoint weights tried, settling band, and time samples of the predicted step responses.
_B_GRID = np.linspace(0.0, 1.0, 41)
_SETTLE = 0.02
_STEPS = 2000


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


def _select_signals(model: DesignModel, input: str | None, output: str | None) -> tuple[int, int]:
    manipulable = [name for name in model.inputs if name not in KNOWN_CONSTANT_INPUTS]
    if input is None:
        if not manipulable:
            raise InvalidSettingError(f"the model has no input to manipulate (its inputs are {list(model.inputs)})")
        input = manipulable[0]
    elif input not in manipulable:
        raise UnknownVariableError(f"the model has no manipulable input named {input!r}; its inputs are "
                                   f"{manipulable}" + (" (a 'const' input is the model's constant term)"
                                                       if input in KNOWN_CONSTANT_INPUTS else ""))
    if output is None:
        output = model.outputs[0]
    elif output not in model.outputs:
        raise UnknownVariableError(f"the model has no output named {output!r}; its outputs are {list(model.outputs)}")
    return model.inputs.index(input), model.outputs.index(output)


def _select_velocity(model: DesignModel, velocity: str | None, i_out: int) -> int | None:
    if velocity is None:
        return None
    if not isinstance(velocity, str) or velocity not in model.outputs:
        raise UnknownVariableError(f"velocity={velocity!r} is not an output of the model; its outputs are "
                                   f"{list(model.outputs)}")
    if model.outputs.index(velocity) == i_out:
        raise InvalidSettingError(f"velocity={velocity!r} is the controlled output itself; name the measured "
                                  f"velocity among {[o for o in model.outputs if o != velocity]}")
    return model.outputs.index(velocity)


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


class _Candidate:
    """One PI(D) shape at one crossover, with its loop figures and (once computed) its step figures."""

    def __init__(self, wc: float, kp: float, ti: float, td: float, tf: float, n: float | None) -> None:
        self.wc, self.kp, self.ti, self.td, self.tf, self.n = wc, kp, ti, td, tf, n
        self.figs: dict[str, Any] = {}
        self.b = self.overshoot = self.settling = self.iae_load = math.nan
        self.admissible = False

    def gains(self) -> tuple[float, float, float, float]:
        return self.kp, self.kp / self.ti, self.kp * self.td, self.tf


def _shapes_at(plant: _Plant, wc: float, pm: float, derivative: bool | None,
               ns: Sequence[float]) -> list[_Candidate]:
    """PI and PID shapes with ``arg L(e^{j wc dt}) = -180 deg + pm`` and ``|L| = 1`` at `wc`."""
    if plant.velocity is not None:
        return _velocity_shapes(plant, wc, pm)
    h = plant.dt
    zc = np.exp(1j * wc * h)
    pc = complex(plant.response(np.array([zc]))[0])
    if not (abs(pc) > 0 and math.isfinite(abs(pc))):
        return []
    phi = float(_wrap(-math.pi + pm - np.angle(pc)))  # phase the controller must supply at wc
    out: list[_Candidate] = []
    q = 1.0 / (zc - 1.0)
    if derivative is not True and -math.pi / 2 < phi < 0:  # PI: angle(1 + x*q) = phi with x = dt/Ti
        rot = np.exp(-1j * phi)
        x = math.sin(phi) / (rot * q).imag
        if x > 0 and (rot * (1 + x * q)).real > 0:
            out.append(_Candidate(wc, 1.0 / abs((1 + x * q) * pc), h / x, 0.0, 0.0, None))
    if derivative is not False and -math.pi / 2 < phi < math.pi / 2:
        tds = _BETAS / wc
        for alpha in _ALPHAS:
            ti = alpha / wc
            for n in ns:
                f = _wrap(np.angle(_shape(zc, h, ti, tds, tds / n)) - phi)
                up = np.nonzero((f[:-1] < 0) & (f[1:] >= 0))[0]  # the first (smallest Td) solution
                if not up.size:
                    continue
                i = int(up[0])

                def err(td: float, ti: float = ti, n: float = n) -> float:
                    return float(_wrap(np.angle(_shape(zc, h, ti, td, td / n)) - phi))

                td = brentq(err, tds[i], tds[i + 1], xtol=1e-15 / wc, rtol=1e-13)
                out.append(_Candidate(wc, 1.0 / abs(_shape(zc, h, ti, td, td / n) * pc), ti, td, td / n, n))
    return out


def _velocity_shapes(plant: _Plant, wc: float, pm: float) -> list[_Candidate]:
    """PI + velocity-feedback gains with ``L(e^{j wc dt}) = -e^{+-j pm}`` for every velocity gain in
    ``plant.kds``: the loop is linear in ``(kp, ki, kd)``, so at a given ``kd`` the complex condition is a 2 x 2
    real linear system in ``(kp, ki)``; solutions with ``kp, ki > 0`` are kept."""
    h = plant.dt
    zc = np.exp(1j * wc * h)
    pt, pv = plant.responses(np.array([zc]))[:, 0]
    if not (np.isfinite(pt) and np.isfinite(pv) and abs(pt) > 0):
        return []
    q = pt * h / (zc - 1.0)
    m = np.array([[pt.real, q.real], [pt.imag, q.imag]])
    if abs(np.linalg.det(m)) <= 1e-12 * abs(pt) * abs(q):
        return []
    out = []
    for sign in (1.0, -1.0):
        rhs = -np.exp(1j * sign * pm) - plant.kds * pv
        kps, kis = np.linalg.solve(m, np.vstack([rhs.real, rhs.imag]))
        out += [_Candidate(wc, float(kp), float(kp / ki), float(kd / kp), 0.0, None)
                for kp, ki, kd in zip(kps, kis, plant.kds, strict=True) if kp > 0 and ki > 0]
    return out


def _robust_at(plant: _Plant, wc: float, pm: float, derivative: bool | None, gm_min: float, mm_min: float,
               ns: Sequence[float]) -> list[_Candidate]:
    """The shapes at `wc` that meet the margins on the frequency grid and give a stable closed loop."""
    ok: list[_Candidate] = []
    if wc > plant.wc_cap:
        return ok
    pm_deg = math.degrees(pm)
    for c in _shapes_at(plant, wc, pm, derivative, ns):
        fg = c.figs = _loop_figures(plant.w, plant.loop(*c.gains()))
        if fg["pm"] < pm_deg - _PM_TOL or fg["gm"] < gm_min or fg["gm_low"] > 1.0 / gm_min or fg["mm"] < mm_min:
            continue
        if plant.velocity is not None and fg["w_first"] < wc * (1.0 - _FIRST_TOL):
            continue  # wc is not the position loop's crossover (the lowest)
        cl = plant.closed_loop(*c.gains())
        if cl is not None and np.max(np.abs(np.linalg.eigvals(cl[0]))) < 1.0:
            ok.append(c)
    return ok


def _held_step_responses(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, m: int,
                         k: int) -> np.ndarray:
    """Outputs at samples ``0, m, ..., k*m`` of ``x+ = A x + B w``, ``y = C x + D w`` for each unit input held
    from sample 0 (columns of `b`), from x = 0: ``(k + 1) x n_inputs``.

    Uses ``x_j = (I - A^j)(I - A)^-1 B`` with the eigendecomposition of a stable `A`; falls back to the
    recursion when the eigenvectors are ill-conditioned.
    """
    n = a.shape[0]
    x_end = np.linalg.solve(np.eye(n) - a, b)
    y_end = c @ x_end + d
    lam, v = np.linalg.eig(a)
    if np.linalg.cond(v) < 1e8 and np.all(np.abs(lam) > 1e-12):
        g = (c @ v).ravel()
        hh = np.linalg.solve(v, x_end)
        powers = np.exp(np.log(lam)[:, None] * (m * np.arange(k + 1))[None, :])  # lam**j, n x (k + 1)
        return (y_end - ((g[:, None] * powers).T @ hh).real).reshape(k + 1, -1)
    am = np.linalg.matrix_power(a, m)
    x = np.zeros_like(b)
    y = np.empty((k + 1, b.shape[1]))
    y[0] = (c @ x + d)[0]
    nm = (np.eye(n) - am) @ x_end
    for i in range(1, k + 1):
        x = am @ x + nm
        y[i] = (c @ x + d)[0]
    return y


def _step_figures(plant: _Plant, c: _Candidate, b: float | None, max_overshoot: float | None) -> None:
    """Predicted unit setpoint step (best or given b) and input load step of the linear loop, into `c`.

    The setpoint figures are the worst over the loop gains ``plant.gains`` (scaling the controller's gains
    is scaling the plant's input gain, as far as the setpoint response goes).
    """
    kp, ki, kd, tf = c.gains()
    a, bm, cy, dy = plant.closed_loop(kp, ki, kd, tf)  # type: ignore[misc]
    h = plant.dt
    rho = float(np.max(np.abs(np.linalg.eigvals(a))))
    tau = h / -math.log(rho) if rho > 0 else h
    horizon = min(max(12.0 * tau, 10.0 / c.wc), 100.0 / c.wc)
    m = max(1, math.ceil(horizon / (h * _STEPS)))
    k = math.ceil(horizon / (h * m))
    nominal = _held_step_responses(a, bm, cy, dy, m, k)
    step = m * h
    c.iae_load = float(np.sum(np.abs(nominal[:, 2])) * step)
    weights = _B_GRID if b is None else np.array([b])
    overshoot = np.zeros(weights.size)
    settling = np.zeros(weights.size)
    for g in plant.gains:
        y = nominal
        if g != 1.0:
            cl = plant.closed_loop(g * kp, g * ki, g * kd, tf)
            if cl is None or np.max(np.abs(np.linalg.eigvals(cl[0]))) >= 1.0:
                overshoot[:], settling[:] = math.inf, math.inf
                break
            y = _held_step_responses(*cl, m, k)
        ys = weights[:, None] * y[None, :, 0] + y[None, :, 1]
        overshoot = np.maximum(overshoot, np.maximum(ys.max(axis=1) - 1.0, 0.0) * 100.0)
        outside = np.abs(ys - 1.0) > _SETTLE
        last = k + 1 - np.argmax(outside[:, ::-1], axis=1)  # the sample after the last one outside the band
        ts = np.where(outside.any(axis=1), last * step, 0.0)
        ts[outside[:, -1]] = math.inf  # not settled within the horizon
        settling = np.maximum(settling, ts)
    ok = np.ones(weights.size, bool) if max_overshoot is None else overshoot <= max_overshoot + 1e-9
    c.admissible = bool(ok.any() and np.isfinite(settling[ok]).any())
    j = int(np.argmin(np.where(ok, settling, np.inf))) if c.admissible else int(np.argmin(overshoot))
    c.b, c.overshoot, c.settling = float(weights[j]), float(overshoot[j]), float(settling[j])


def _design(plant: _Plant, pm: float, bandwidth: float | None, derivative: bool | None, gm_min: float,
            mm_min: float, w_max: float, ns: Sequence[float], b: float | None,
            max_overshoot: float | None) -> tuple[_Candidate | None, list[_Candidate]]:
    """The chosen design (None when no shape is robust) and every robust candidate that was considered.

    Admissible candidates (overshoot within `max_overshoot`) compete on the load-step IAE; when there are
    none, the one with the least overshoot is returned (its ``admissible`` is False).
    """
    if bandwidth is not None:
        grid = np.array([bandwidth])
    else:
        grid = w_max * 10.0 ** (-np.arange(int(_WC_DECADES * _WC_PER_DECADE) + 1) / _WC_PER_DECADE)
    robust: list[_Candidate] = []
    w_robust = w_admissible = 0.0  # highest crossovers with a robust and with an admissible candidate
    for wc in grid:
        if wc < (w_admissible / _WC_SPAN if w_admissible else w_robust / _WC_SPAN**2):
            break
        for c in _robust_at(plant, float(wc), pm, derivative, gm_min, mm_min, ns):
            _step_figures(plant, c, b, max_overshoot)
            robust.append(c)
            w_robust = w_robust or float(wc)
            if c.admissible and not w_admissible:
                w_admissible = float(wc)
    if not robust:
        return None, robust
    admissible = [c for c in robust if c.admissible]
    if admissible:
        return min(admissible, key=lambda c: c.iae_load), robust
    return min(robust, key=lambda c: (round(c.overshoot, 3), c.iae_load)), robust


def _any_robust(plant: _Plant, pm: float, bandwidth: float | None, derivative: bool | None, gm_min: float,
                mm_min: float, w_max: float, ns: Sequence[float]) -> _Candidate | None:
    """The highest-crossover robust candidate (margins and stability only), or None."""
    grid = ([bandwidth] if bandwidth is not None else
            w_max * 10.0 ** (-np.arange(int(_WC_DECADES * _WC_PER_DECADE) + 1) / _WC_PER_DECADE))
    for wc in grid:
        found = _robust_at(plant, float(wc), pm, derivative, gm_min, mm_min, ns)
        if found:
            return found[0]
    return None


#: Phase margins [deg] tried to say what is reachable when a target is not.
_PM_PROBE = (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 85.0)


def _reachable_pms(feasible: Any, below: float | None = None) -> str:
    """Which of :data:`_PM_PROBE` (below `below`) satisfy `feasible(pm_rad)`, said in a few words."""
    ok = [pm for pm in _PM_PROBE if (below is None or pm < below) and feasible(math.radians(pm))]
    if not ok:
        return "no phase margin from 10 to 85 deg is"
    if len(ok) == 1:
        return f"a phase margin of {ok[0]:g} deg is"
    return f"phase margins of {ok[0]:g} to {ok[-1]:g} deg are"


def _not_met(plant: _Plant, pm_deg: float, bandwidth: float | None, derivative: bool | None, gm_db: float,
             gm_min: float, mm_min: float, w_max: float, ns: Sequence[float]) -> str:
    """One line: which target no PI(D) meets, and what is reachable instead."""
    kind = {None: "PI(D)", True: "PID", False: "PI"}[derivative]
    limits = f"gain margin >= {gm_db:g} dB and modulus margin >= {mm_min:g}"
    where = f"on {plant.input} -> {plant.output}"
    if plant.velocity is not None:
        kind, where = "PI with velocity feedback", f"{where} with {plant.velocity} fed back"
    if _any_robust(plant.negated(), math.radians(pm_deg), bandwidth, derivative, gm_min, mm_min, w_max, ns):
        return (f"the model's gain from {plant.input} to {plant.output} is negative (more input, less output) and "
                "PID gains are positive: tune on the negated model (-sys) and negate the PID's output, or swap "
                "the sign of the measurement")
    if bandwidth is not None:
        top = _any_robust(plant, math.radians(pm_deg), None, derivative, gm_min, mm_min, w_max, ns)
        at_bw = _reachable_pms(lambda pm: _any_robust(plant, pm, bandwidth, derivative, gm_min, mm_min, w_max, ns)
                               is not None)
        reach = (f"{at_bw} reachable at {bandwidth:.4g} rad/s; "
                 + (f"with {pm_deg:g} deg the highest crossover is about {top.wc:.3g} rad/s "
                    f"({top.wc / 2 / math.pi:.3g} Hz)" if top else
                    f"no crossover up to {w_max:.4g} rad/s gives {pm_deg:g} deg"))
        return (f"no {kind} gives crossover {bandwidth:.4g} rad/s with phase margin {pm_deg:g} deg, {limits} {where}: "
                f"{reach}")
    reach = _reachable_pms(lambda pm: _any_robust(plant, pm, None, derivative, gm_min, mm_min, w_max, ns)
                           is not None, below=pm_deg)
    return (f"no {kind} reaches phase margin {pm_deg:g} deg with {limits} and crossover <= {w_max:.4g} rad/s {where}; "
            f"{reach} reachable")


def _controller_ss(pid: PID) -> control.StateSpace:
    """The PID's feedback law (limits off) as a state space from the negated measurements, in the order of
    :class:`_Plant`'s outputs (controlled output, then the velocity), to ``u``."""
    c = control.ss(pid.feedback_tf())
    if pid.velocity is None:
        return c
    v = control.ss(pid.velocity_tf())
    nc, nv = c.nstates, v.nstates
    a = np.zeros((nc + nv, nc + nv))
    a[:nc, :nc], a[nc:, nc:] = c.A, v.A
    b = np.zeros((nc + nv, 2))
    b[:nc, :1], b[nc:, 1:] = c.B, v.B
    return control.ss(a, b, np.hstack([c.C, v.C]), np.hstack([c.D, v.D]), pid.dt)


def _loop_report(pid: PID, plant: _Plant) -> dict[str, Any]:
    """Achieved figures of the loop broken at the plant input, ``L = C(z) P(z)`` (with a measured velocity
    ``L = C(z) P(z) + K_v(z) P_v(z)``): margins by ``control.stability_margins`` on its exact frequency
    response, closed-loop poles by ``control.feedback``, and the predicted linear step responses."""
    h = plant.dt
    loop = plant.loop(pid.kp, pid.ki, pid.kd, pid.tf)
    gm, pm, sm, w180, wc, wms = (np.atleast_1d(v) for v in
                                 control.stability_margins(control.frd(loop, plant.w), returnall=True))
    pm = np.abs(_wrap(np.radians(pm))) * (180.0 / math.pi)  # lag or lead, as in _loop_figures
    up, low = np.nonzero(gm > 1)[0], np.nonzero(gm < 1)[0]
    k_up = int(up[np.argmin(gm[up])]) if up.size else None
    k_low = int(low[np.argmax(gm[low])]) if low.size else None
    k_pm = int(np.argmin(pm)) if pm.size else None
    k_sm = int(np.argmin(sm)) if sm.size else None
    closed = control.feedback(control.series(plant.statespace(), _controller_ss(pid)), 1)
    radius = float(np.max(np.abs(closed.poles())))
    forward = loop if pid.velocity is None else (pid.kp + pid.ki * h / (plant.z - 1.0)) * plant.p
    t_mag = np.abs(forward / (1.0 + loop))  # from the setpoint (b = 1) to the controlled output
    below = np.nonzero(t_mag < 1.0 / math.sqrt(2.0))[0]
    info: dict[str, Any] = {
        "gain_margin": float(gm[k_up]) if k_up is not None else math.inf,
        "gain_margin_db": float(20.0 * np.log10(gm[k_up])) if k_up is not None else math.inf,
        "phase_crossover_rad_s": float(w180[k_up]) if k_up is not None else None,
        "lower_gain_margin_db": float(20.0 * np.log10(gm[k_low])) if k_low is not None else None,
        "phase_margin_deg": float(pm[k_pm]) if k_pm is not None else math.inf,
        "crossover_rad_s": float(wc[k_pm]) if k_pm is not None else None,
        "crossover_hz": float(wc[k_pm]) / (2.0 * math.pi) if k_pm is not None else None,
        "gain_crossovers_rad_s": [float(x) for x in wc],
        "modulus_margin": float(sm[k_sm]) if k_sm is not None else None,
        "sensitivity_peak": float(1.0 / sm[k_sm]) if k_sm is not None else None,
        "modulus_margin_rad_s": float(wms[k_sm]) if k_sm is not None else None,
        "closed_loop_stable": bool(radius < 1.0),
        "closed_loop_spectral_radius": radius,
        "closed_loop_bandwidth_rad_s": float(plant.w[below[0]]) if below.size and below[0] > 0 else None,
    }
    info["bandwidth_rad_s"] = info["crossover_rad_s"]
    if info["closed_loop_stable"] and pid.kp > 0 and pid.ki > 0:
        c = _Candidate(info["crossover_rad_s"] or 1.0 / h, pid.kp, pid.kp / pid.ki, pid.kd / pid.kp, pid.tf, None)
        nominal = copy.copy(plant)
        nominal.gains = (1.0,)
        _step_figures(nominal, c, pid.b, None)
        info.update(step_overshoot_pct=c.overshoot, step_settling_time_s=c.settling,
                    load_step_iae=c.iae_load)
        if plant.gains != (1.0,):
            _step_figures(plant, c, pid.b, None)
            info.update(loop_gain_range=[min(plant.gains), max(plant.gains)], step_overshoot_worst_pct=c.overshoot,
                        step_settling_time_worst_s=c.settling)
    return info


def tune_pid(sys: control.StateSpace, *, dt: float, input: str | None = None, output: str | None = None,
             velocity: str | None = None, phase_margin: float | None = None, bandwidth: float | None = None,
             bandwidth_hz: float | None = None, derivative: bool | None = None, gain_margin_db: float = 6.0,
             modulus_margin: float = 0.5, max_overshoot: float | None = 10.0, max_crossover: float | None = None,
             delay: int = 0, b: float | None = None, n: float | None = None, u_min: float | None = None,
             u_max: float | None = None, du_max: float | None = None, u0: float = 0.0,
             anti_windup: str | None = "back-calculation", tt: float | None = None) -> PID:
    """Design a discrete :class:`PID` on a linear model for a phase margin, or a crossover frequency.

    Method (PID on one output): loop shaping at the gain crossover ``wc`` on the *discrete* loop
    ``L(z) = C(z) P(z)``, with ``P`` the model sampled with zero-order hold at `dt` (times ``z**-delay``) and
    ``C`` the PID's exact discrete law. At a candidate ``wc`` the controller must supply the phase
    ``-180 deg + PM - arg P``: for a grid of integral times ``Ti = alpha/wc`` (alpha 1.5 to 30) and filters
    ``n = Td/tf`` (2 to 30) the derivative time ``Td`` is solved so that ``arg L = -180 deg + PM`` exactly (and
    for the PI, ``Ti`` is solved), then ``kp`` makes ``|L| = 1``.

    Method (with `velocity`: PI on `output`, ``D = -kd * velocity``): a direct search on the exact discrete
    loop broken at the plant input, ``L(z) = (kp + ki*dt/(z - 1)) P(z) + kd P_v(z)`` (``P_v``: input to
    velocity). ``L`` is linear in the gains, so for each velocity gain ``kd`` on a grid (1/1000 up to the gain
    whose velocity loop alone crosses over at `max_crossover`, 32 per decade) and each candidate ``wc``, ``kp``
    and ``ki`` are solved exactly from ``L(e^{j wc dt}) = -e^{+-j PM}``; ``wc`` must be the lowest gain
    crossing (the position loop's). This lets the velocity feedback damp the collocated resonance (the inner
    loop) while the PI sets the position loop's crossover and phase margin, without assuming either. Two rules
    keep the design robust to an identified model's errors: ``wc`` stays below 0.7 times the antiresonance
    (the lowest lightly damped zero from the input to the velocity, where the load decouples from the motor
    and the velocity feedback no longer acts on it; identified models place it 20-30 % off; not applied to a
    given `bandwidth`), and the predicted setpoint step must keep `max_overshoot` for loop gains from 0.8 to
    1.25 times the model's.

    For both: a design is *robust* when every gain crossing has the phase margin (lag or lead), the gain margin
    is at least `gain_margin_db` (both ways for a conditionally stable loop), ``min |1 + L|`` is at least
    `modulus_margin` and the discrete closed loop is stable. Given a bandwidth, ``wc`` is that bandwidth;
    given only a phase margin, ``wc`` runs down from `max_crossover` (24 values per decade) and the robust
    designs at crossovers down to half the highest one with an admissible step response compete. Among them
    the tuner keeps the one with the smallest integrated absolute error after a load step at the plant input
    (load-disturbance rejection; for a well-damped loop it is about 1/ki, the integral gain Åström &
    Hägglund's MIGO design maximises) whose setpoint step, with the best setpoint weight ``b`` in [0, 1] (the
    one that settles fastest), overshoots at most `max_overshoot`. The achieved margins are computed by
    ``control.stability_margins`` on the exact discrete frequency response of the same loop and stored in
    ``pid.info``.

    Parameters
    ----------
    sys : control.StateSpace
        Continuous or discrete (then at `dt`) model; inputs named ``"const"`` (an identified model's
        constant term) are ignored.
    dt : float
        Controller sample time [s].
    input, output : str, optional
        Manipulated input and controlled output; default the first non-"const" input and the first output.
    velocity : str, optional
        A measured output to take the derivative action from, e.g. ``"omega_m"`` (a velocity collocated with
        `input` damps a resonance between them and `output`). The PID then measures `output` and `velocity`
        (``pid.outputs`` in the model's output order) and tracks `output`; the velocity is not filtered.
    phase_margin : float, optional
        Phase margin [deg] at the crossover, default 60; with `velocity` 48: a servo floor of 45 deg plus
        3 deg for the model's errors (a model a few % off moves it by up to 2 deg), and no more, because the
        position loop's gains must stay high against Coulomb friction (at 60 deg the bundled servo creeps for
        seconds with 100 N m of it).
    bandwidth : float, optional
        Gain crossover frequency ``wc`` [rad/s] to design for (called bandwidth here; the closed loop's
        -3 dB bandwidth is reported as ``closed_loop_bandwidth_rad_s``).
    bandwidth_hz : float, optional
        The same in Hz (give one of the two).
    derivative : bool, optional
        True: PID only; False: PI only; None (default): both compete. With `velocity` the structure is fixed
        (False is refused).
    gain_margin_db, modulus_margin : float
        Robustness constraints: gain margin [dB] (default 6) and smallest ``|1 + L|`` (default 0.5, a
        sensitivity peak of at most 2).
    max_overshoot : float or None
        Largest overshoot [%] of the predicted linear setpoint step (default 10); None: no limit. When no
        robust design meets it, the one with the least overshoot is kept and ``info["warnings"]`` says so.
    max_crossover : float, optional
        Upper end of the crossover search [rad/s]; default ``0.2/dt`` (Åström & Wittenmark's rule of thumb
        ``wc*dt`` of 0.15 to 0.5 for the sample rate).
    delay : int
        Computational delay in samples (0: ``u_k`` is computed from ``y_k`` and held over ``[t_k, t_k + dt)``,
        as cosim's closed loop does).
    b : float, optional
        Setpoint weight; default: chosen as described above.
    n : float, optional
        Fix the derivative filter ``n = Td/tf`` instead of searching it (not with `velocity`).
    u_min, u_max, du_max, u0, anti_windup, tt
        Passed on to :class:`PID` (limits, bias, anti-windup).

    Returns
    -------
    PID
        With ``info``: ``method``, the targets, ``structure`` ("PI", "PID" or "PI+velocity"), ``velocity``,
        ``ti_s``, ``td_s`` (``kd/kp``), ``tf_s``, ``b``, the achieved ``gain_margin`` (factor;
        ``gain_margin_db``; at ``phase_crossover_rad_s``), ``lower_gain_margin_db`` (conditionally stable
        loops), ``phase_margin_deg`` (the smallest over the gain crossings, lag or lead), ``crossover_rad_s``
        (= ``bandwidth_rad_s``; where that margin is), ``crossover_hz``, ``gain_crossovers_rad_s``,
        ``modulus_margin`` (min ``|1 + L|``) and ``sensitivity_peak``, ``closed_loop_stable``,
        ``closed_loop_bandwidth_rad_s``, and the predicted linear ``step_overshoot_pct``,
        ``step_settling_time_s`` (2 %) and ``load_step_iae`` (per unit input step); with `velocity` also
        ``loop_gain_range`` and the worst step figures over it, ``step_overshoot_worst_pct`` and
        ``step_settling_time_worst_s``, ``antiresonance_rad_s`` and the resulting ``max_crossover_rad_s``.
        All loop figures are for the loop broken at the plant input.

    Raises
    ------
    ControllerError
        When no design meets the targets; the message says what is reachable.
    UnknownVariableError
        When `input`, `output` or `velocity` is not in the model; the message lists what is.

    Notes
    -----
    The margins come from ``control.stability_margins`` applied to ``control.frd`` of the loop's exact
    response on a grid refined around every lightly damped mode, not to the loop's transfer function: at
    fast sampling the poles crowd ``z = 1`` and python-control's polynomial method is ill-conditioned (it
    falls back to its own coarse grid, which misses a 1 % damped resonance). A gain crossing with phase lead
    (a collocated velocity loop has them) counts with ``|180 deg + arg L|``, wrapped, where python-control
    reports a negative number. Predicted step figures are those of the linear model; friction, backlash and
    saturation are not in them.

    Examples
    --------
    >>> import control
    >>> motor = control.ss([[0, 1], [0, -2]], [[0], [4]], [[1, 0]], 0, inputs=["V"], outputs=["angle"])
    >>> pid = tune_pid(motor, dt=0.001, bandwidth=20.0)
    >>> info = pid.info
    >>> round(info["crossover_rad_s"], 2), round(info["phase_margin_deg"], 1), info["closed_loop_stable"]
    (20.0, 60.0, True)

    The same motor with its speed measured: a PI on the angle and speed feedback (default phase margin 48 deg).

    >>> motor = control.ss([[0, 1], [0, -2]], [[0], [4]], [[1, 0], [0, 1]], 0, inputs=["V"],
    ...                    outputs=["angle", "speed"])
    >>> pid = tune_pid(motor, dt=0.001, output="angle", velocity="speed", bandwidth=20.0)
    >>> pid.outputs, pid.tracked, pid.info["structure"]
    (('angle', 'speed'), ('angle',), 'PI+velocity')
    >>> round(pid.info["crossover_rad_s"], 2), round(pid.info["phase_margin_deg"], 1)
    (20.0, 48.0)
    """
    from .pid import PID, _finite

    model = DesignModel.from_statespace(sys, dt=dt)
    h = model.dt
    i_in, i_out = _select_signals(model, input, output)
    i_vel = _select_velocity(model, velocity, i_out)
    if bandwidth is not None and bandwidth_hz is not None:
        raise InvalidSettingError("give the bandwidth in rad/s (bandwidth=) or in Hz (bandwidth_hz=), not both")
    if bandwidth_hz is not None:
        bandwidth = 2.0 * math.pi * _finite(bandwidth_hz, "bandwidth_hz", low=0.0, strict=True)
    if bandwidth is not None:
        bandwidth = _finite(bandwidth, "bandwidth", low=0.0, strict=True)
        if bandwidth >= math.pi / h:
            raise InvalidSettingError(f"bandwidth {bandwidth:g} rad/s is not below the Nyquist frequency "
                                      f"{math.pi / h:.6g} rad/s of dt = {h:g} s; lower it or sample faster")
    if phase_margin is None:
        pm_deg = 60.0 if i_vel is None else _VELOCITY_PM
    else:
        pm_deg = _finite(phase_margin, "phase_margin", low=0.0, strict=True)
    if pm_deg >= 90.0:
        raise InvalidSettingError(f"phase_margin must be below 90 deg, got {pm_deg:g}")
    gm_db = _finite(gain_margin_db, "gain_margin_db", low=0.0)
    mm_min = _finite(modulus_margin, "modulus_margin", low=0.0)
    if mm_min >= 1.0:
        raise InvalidSettingError(f"modulus_margin is min |1 + L| and must be below 1, got {mm_min:g}")
    if max_overshoot is not None:
        max_overshoot = _finite(max_overshoot, "max_overshoot", low=0.0)
    w_max = 0.2 / h if max_crossover is None else _finite(max_crossover, "max_crossover", low=0.0, strict=True)
    w_max = min(w_max, 0.99 * math.pi / h)
    if isinstance(delay, bool) or not isinstance(delay, int) or delay < 0:
        raise InvalidSettingError(f"delay must be a whole number of samples >= 0, got {delay!r}")
    if derivative not in (None, True, False):
        raise InvalidSettingError(f"derivative must be True, False or None, got {derivative!r}")
    if i_vel is not None and (derivative is False or n is not None):
        raise InvalidSettingError(f"with velocity={velocity!r} the derivative action is kd * {velocity} (unfiltered): "
                                  "leave derivative and n out")
    ns = _NS if n is None else (_finite(n, "n", low=0.0, strict=True),)
    if b is not None:
        b = _finite(b, "b", low=0.0)
    PID(kp=1.0, dt=h, u_min=u_min, u_max=u_max, du_max=du_max, u0=u0, anti_windup=anti_windup)  # check them now
    w_lo = min(w_max, bandwidth or w_max) * 10.0 ** -(_WC_DECADES + 2)
    plant = _Plant(model, i_in, i_out, delay, w_lo, i_vel)
    w_anti = None
    if plant.pv is not None:
        pv_top = abs(complex(plant.responses(np.array([np.exp(1j * w_max * h)]))[1, 0]))
        if not (math.isfinite(pv_top) and pv_top > 0):
            raise ControllerError(f"the model's {velocity} does not respond to {plant.input} at {w_max:.4g} rad/s; "
                                  "the velocity feedback needs a velocity the input drives")
        plant.kds = _KD_FRACTIONS / pv_top
        plant.gains = _VELOCITY_GAINS
        w_anti = _antiresonance(model, i_in, i_vel)
        if w_anti is not None and bandwidth is None:
            plant.wc_cap = _ANTIRESONANCE_FRACTION * w_anti
    gm_min = 10.0 ** (gm_db / 20.0)
    pm = math.radians(pm_deg)
    best, robust = _design(plant, pm, bandwidth, derivative, gm_min, mm_min, w_max, ns, b, max_overshoot)
    if best is None:
        raise ControllerError(_not_met(plant, pm_deg, bandwidth, derivative, gm_db, gm_min, mm_min, w_max, ns))
    notes = [] if best.admissible or max_overshoot is None else [
        f"no robust design keeps the predicted step overshoot <= {max_overshoot:g} %; kept the least, "
        f"{best.overshoot:.1f} %"]
    kp, ki, kd, tf = best.gains()
    if i_vel is None:
        method = ("discrete loop shaping at the gain crossover (ZOH model, exact PID law); "
                  "min load-step IAE subject to margins and setpoint overshoot")
        structure = "PID" if best.td > 0 else "PI"
        outputs = [plant.output]
    else:
        method = ("PI + velocity feedback: search over kd and the position loop's crossover, kp and ki solved "
                  "for the phase margin on the exact discrete loop broken at the plant input; min load-step IAE "
                  "subject to margins and setpoint overshoot")
        structure = "PI+velocity"
        outputs = [name for name in model.outputs if name in (plant.output, plant.velocity)]
    info = {"method": method, "input": plant.input, "output": plant.output, "velocity": plant.velocity, "dt": h,
            "delay_samples": delay, "phase_margin_target_deg": pm_deg, "bandwidth_target_rad_s": bandwidth,
            "max_crossover_rad_s": min(w_max, plant.wc_cap), "antiresonance_rad_s": w_anti,
            "gain_margin_min_db": gm_db, "modulus_margin_min": mm_min, "max_overshoot_pct": max_overshoot,
            "structure": structure, "ti_s": best.ti, "td_s": best.td, "tf_s": best.tf,
            "b": best.b, "candidates_considered": len(robust), "warnings": notes}
    pid = PID(kp=kp, ki=ki, kd=kd, tf=tf, dt=h, b=best.b, inputs=[plant.input], outputs=outputs,
              velocity=plant.velocity, u_min=u_min, u_max=u_max, du_max=du_max, u0=u0, anti_windup=anti_windup,
              tt=tt)
    pid.info = {**info, **_loop_report(pid, plant)}
    pid.design_model = model
    return pid
