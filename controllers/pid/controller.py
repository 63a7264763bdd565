"""The discrete PID controller (:class:`PID`): setpoint weighting, filtered derivative, limits, anti-windup.

The control law (parallel form, Åström & Hägglund, *Advanced PID Control*, 2006, ch. 3 and 13; Åström &
Wittenmark, *Computer-Controlled Systems*, 3rd ed., sect. 8.5) is, at sample ``t_k = t0 + k*dt``::

    P_k = kp * (b*r_k - y_k)                                   setpoint weight b, no derivative of r
    D_k = tf/(tf + dt) * D_{k-1} - kd/(tf + dt) * (y_k - y_{k-1})   derivative of -y, first-order filter tf,
                                                                 backward difference (stable for any tf >= 0)
    v_k = u0 + P_k + I_k + D_k                                  unconstrained output
    u_k = sat(v_k)                                              rate limit du_max, then limits u_min, u_max
    I_{k+1} = I_k + ki*dt*(r_k - y_k) + dt/tt*(u_k - v_k)      forward difference, back-calculation

so the integral term is known before the measurement arrives and ``u_k`` depends on ``y_k`` only through
multiplications and additions (no computational delay is added: ``u_k`` is held over ``[t_k, t_k + dt)``).
In z the feedback part is ``C(z) = kp + ki*dt/(z - 1) + kd*(z - 1)/((tf + dt)*z - tf)``, which is exactly the
controller :func:`~controllers.pid.tune_pid` designs with.

**Derivative from a velocity sensor** (Åström & Hägglund, sect. 3.4; the usual servo structure). With
``velocity="omega_m"`` the derivative action is taken from a *measured* velocity ``v`` instead of the
difference of ``y``, through the same optional first-order filter (backward difference)::

    D_k = tf/(tf + dt) * D_{k-1} - kd*dt/(tf + dt) * v_k            with tf = 0 (default): D_k = -kd * v_k

The PID then measures two outputs (``outputs``, in the plant's output order: the controlled output and the
velocity) and tracks one. On a two-mass servo the motor velocity is collocated with the motor torque, so
its feedback damps the resonance that limits a PID on the load angle alone. In z the law is
``u = F(z) r - C(z) y - K_v(z) v`` with ``C(z) = kp + ki*dt/(z - 1)`` and ``K_v(z) = kd*dt*z/((tf + dt)*z - tf)``.

With ``anti_windup="clamping"`` the integrator stops (conditional integration) while the output is limited
and the error would drive it further into the limit; with ``anti_windup=None`` it integrates regardless.

Examples
--------
>>> pid = PID(kp=2.0, ki=1.0, dt=0.1, u_min=-1.0, u_max=1.0)
>>> pid.setpoint = 0.3
>>> [round(float(pid(0.1 * k, [0.0])[0]), 3) for k in range(3)]
[0.6, 0.63, 0.66]

With a velocity sensor, ``y = [omega_m, theta_L]`` (the plant's order) and ``D = -kd * omega_m``:

>>> servo = PID(kp=8.9e5, ki=4.2e6, kd=6.4e4, b=0.5, dt=1 / 2257, inputs="Tm", outputs=["omega_m", "theta_L"],
...             velocity="omega_m", u_min=-5000, u_max=5000)
>>> servo.tracked, servo.setpoint.tolist()
(('theta_L',), [0.0])
>>> float(servo(0.0, [0.01, 0.0])[0])   # -kd * 0.01
-640.0
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import control
import numpy as np

from cosim.errors import ControllerError, InvalidSettingError
from cosim.numbers import finite_number as _finite

from ..base import Controller, register

__all__ = ["ANTI_WINDUP", "PID"]

#: Anti-windup methods of :class:`PID` (``None`` switches anti-windup off).
ANTI_WINDUP = ("back-calculation", "clamping")
#: Derivative filter ``n = Td/tf`` when neither `tf` nor `n` is given (no filter on a measured velocity).
DEFAULT_N = 10.0


def _names(value: Any) -> list[Any]:
    if isinstance(value, str):
        return [value]
    try:
        return list(value)
    except TypeError:
        return [value]


def _one_name(value: Any, role: str) -> tuple[str]:
    names = _names(value)
    if len(names) != 1 or not isinstance(names[0], str):
        raise InvalidSettingError(f"a PID has exactly one {role} name, got {value!r}; use one PID per loop")
    return (names[0],)


def _measured(outputs: Any, velocity: Any) -> tuple[tuple[str, ...], str, int, int | None]:
    """Measured outputs, the controlled one, and the positions of the controlled output and the velocity."""
    if velocity is None:
        (name,) = _one_name(outputs, "output")
        return (name,), name, 0, None
    if not isinstance(velocity, str) or not velocity:
        raise InvalidSettingError(f"velocity must be the name of a measured output, got {velocity!r}")
    names = _names(outputs)
    if len(names) != 2 or velocity not in names or names[0] == names[1] or not all(isinstance(n, str) for n in names):
        other = names[0] if len(names) == 1 and isinstance(names[0], str) and names[0] != velocity else "theta_L"
        raise InvalidSettingError(f"with velocity={velocity!r} the PID measures two outputs: give the controlled "
                                  f"output and {velocity!r} in the plant's output order, e.g. "
                                  f"outputs=[{velocity!r}, {other!r}] (got outputs={outputs!r})")
    i_vel = names.index(velocity)
    return tuple(names), names[1 - i_vel], 1 - i_vel, i_vel


def _pid_tf(kp: float, ki: float, kd: float, tf: float, dt: float) -> control.TransferFunction:
    """``C(z) = kp + ki*dt/(z - 1) + kd*(z - 1)/((tf + dt)*z - tf)``: the PID's feedback law in z."""
    c = control.tf([kp], [1.0], dt)
    if ki:
        c = c + control.tf([ki * dt], [1.0, -1.0], dt)
    if kd:
        c = c + control.tf([kd, -kd], [tf + dt, -tf], dt)
    return c


@register("pid")
class PID(Controller):
    """Discrete SISO PID: parallel form, setpoint weight, derivative of the measurement (or from a measured
    velocity), limits, anti-windup.

    See the module docstring for the exact discrete law (forward difference for the integral, backward
    difference for the filtered derivative), and for the variant that takes the derivative action from a
    measured velocity.

    Parameters
    ----------
    kp, ki, kd : float
        Proportional [u/y], integral [u/(y s)] and derivative [u s/y] gains, all >= 0 (not all zero). In
        standard form ``Ti = kp/ki`` and ``Td = kd/kp``. With `velocity`, `kd` multiplies the measured
        velocity [u/(y/s)].
    dt : float
        Sample time [s].
    tf : float, optional
        Time constant of the first-order derivative filter [s], >= 0 (0: no filter). With `velocity` it
        low-passes the measured velocity; default 0 there.
    n : float, optional
        Alternatively the filter as ``n = Td/tf`` (needs ``kp > 0``); default 10 when neither is given (and
        no `velocity`).
    b : float
        Setpoint weight of the proportional term, >= 0 (1: error feedback; 0: the setpoint acts through the
        integral only, so a setpoint step does not make the output jump).
    inputs : sequence of one str (or a str)
        The manipulated plant input.
    outputs : sequence of str (or a str)
        The measured outputs, in the plant's output order: the controlled (tracked) output alone, or with
        `velocity` the controlled output and the velocity, e.g. ``["omega_m", "theta_L"]``.
    velocity : str, optional
        The measured output the derivative action comes from (``D = -kd * velocity``, filtered by `tf`);
        None (default): the derivative of the controlled output.
    u_min, u_max : float, optional
        Output limits (none by default).
    du_max : float, optional
        Largest output change per sample. The first call after :meth:`reset` is rate-limited relative to the
        `u` given to reset, and not at all when none was given.
    u0 : float
        Output bias (feed-forward offset), added to P + I + D.
    anti_windup : {"back-calculation", "clamping", None}
        Back-calculation feeds ``(u - v)/tt`` into the integrator; clamping stops integrating while the
        output is limited and the error pushes into the limit; None integrates regardless.
    tt : float, optional
        Tracking time constant of back-calculation [s], >= dt. Default ``sqrt(Ti*Td)``, or ``Ti`` without
        derivative action (Åström & Hägglund), or ``dt`` for a pure integral controller.
    info : mapping, optional
        Design figures (filled by :func:`~controllers.pid.tune_pid`).

    Attributes
    ----------
    kp, ki, kd, tf, b, u0, tt : float
        Current gains and settings (change them with :meth:`set_gains`).
    velocity : str or None
        The measured velocity of the derivative action.
    integral : float
        The integral term ``I`` (it also holds the offsets that keep gain changes bumpless).

    Examples
    --------
    A setpoint step with ``b = 0`` does not make the output jump:

    >>> pid = PID(kp=10.0, ki=5.0, kd=1.0, tf=0.01, dt=0.001, b=0.0, inputs="Tm", outputs="theta_L")
    >>> u_before = pid(0.0, [0.0])[0]
    >>> pid.setpoint = 1.0
    >>> float(pid(0.001, [0.0])[0] - u_before)
    0.0

    The derivative action from a measured motor speed; ``y`` comes in the order of `outputs`:

    >>> pid = PID(kp=10.0, ki=5.0, kd=2.0, dt=0.001, inputs="Tm", outputs=["omega_m", "theta_L"],
    ...           velocity="omega_m")
    >>> pid.setpoint = 1.0
    >>> float(pid(0.0, [0.5, 0.2])[0])    # 10*(1 - 0.2) - 2*0.5
    7.0
    """

    def __init__(self, *, kp: float, ki: float = 0.0, kd: float = 0.0, dt: float, tf: float | None = None,
                 n: float | None = None, b: float = 1.0, inputs: str | Sequence[str] = ("u",),
                 outputs: str | Sequence[str] = ("y",), velocity: str | None = None, u_min: float | None = None,
                 u_max: float | None = None, du_max: float | None = None, u0: float = 0.0,
                 anti_windup: str | None = "back-calculation", tt: float | None = None,
                 info: dict[str, Any] | None = None) -> None:
        inputs = _one_name(inputs, "input")
        measured, controlled, self._iy, self._iv = _measured(outputs, velocity)
        super().__init__(dt=dt, inputs=inputs, outputs=measured, tracked=(controlled,), u_min=u_min, u_max=u_max,
                         du_max=du_max, info=info)
        self.velocity: str | None = velocity
        if anti_windup not in (*ANTI_WINDUP, None):
            raise InvalidSettingError(f"anti_windup must be one of {list(ANTI_WINDUP)} or None, got {anti_windup!r}")
        self.anti_windup = anti_windup
        self.u0 = _finite(u0, "u0")
        self._tt_given = None if tt is None else _finite(tt, "tt", low=0.0, strict=True)
        self._umin, self._umax = float(self.u_min[0]), float(self.u_max[0])
        self._dumax = float(self.du_max[0])
        self.kp = self.ki = self.kd = self.tf = self.tt = 0.0
        self.b = 1.0
        self.n: float | None = None
        self._apply_gains(kp=kp, ki=ki, kd=kd, tf=tf, n=n, b=b)
        self._r = 0.0
        self.reset()

    # ------------------------------------------------------------------ gains
    @property
    def ti(self) -> float:
        """Integral time ``kp/ki`` [s] (inf without integral action)."""
        return self.kp / self.ki if self.ki > 0 else math.inf

    @property
    def td(self) -> float:
        """Derivative time ``kd/kp`` [s] (0 without derivative action, inf when kp = 0 < kd)."""
        if self.kd == 0:
            return 0.0
        return self.kd / self.kp if self.kp > 0 else math.inf

    def _apply_gains(self, *, kp: Any, ki: Any, kd: Any, tf: Any, n: Any, b: Any) -> None:
        kp, ki, kd = (_finite(v, name, low=0.0) for v, name in ((kp, "kp"), (ki, "ki"), (kd, "kd")))
        if kp == ki == kd == 0:
            raise InvalidSettingError("kp, ki and kd are all 0: give at least one positive gain")
        b = _finite(b, "b", low=0.0)
        if tf is not None and n is not None:
            raise InvalidSettingError("give the derivative filter as tf (seconds) or as n = Td/tf, not both")
        if n is not None:
            n = _finite(n, "n", low=0.0, strict=True)
        if tf is not None:
            tf = _finite(tf, "tf", low=0.0)
        elif kd == 0 or (n is None and self._iv is not None):
            tf = 0.0
        else:
            if kp == 0:
                raise InvalidSettingError("with kp = 0 the filter cannot be given as n = Td/tf; give tf in seconds")
            tf = kd / kp / (n if n is not None else DEFAULT_N)
        dt = self.dt
        if self._tt_given is not None:
            tt = self._tt_given
        elif ki == 0:
            tt = math.inf
        elif kp == 0:
            tt = dt
        else:
            ti, td = kp / ki, kd / kp
            tt = max(math.sqrt(ti * td) if td > 0 else ti, dt)
        if tt < dt:
            raise InvalidSettingError(f"tt = {tt:g} s is shorter than the sample time dt = {dt:g} s; use tt >= dt")
        self.kp, self.ki, self.kd, self.tf, self.b, self.n, self.tt = kp, ki, kd, tf, b, n, tt
        # coefficients of the discrete law (module docstring)
        self._ad = tf / (tf + dt)
        self._bd = kd * dt / (tf + dt) if self._iv is not None else kd / (tf + dt)
        self._bi = ki * dt
        self._ao = dt / tt if (self.anti_windup == "back-calculation" and ki > 0) else 0.0
        self._kb = kp * b

    def _held_terms(self) -> float:
        """What the next call would add to the integral term from the last measurement at unchanged input:
        ``kp*(b*r - y)``, and with a measured velocity also its term ``tf/(tf + dt)*D - kd*dt/(tf + dt)*v``."""
        p = self._kb * self._r - self.kp * self._y_prev
        return p + self._ad * self._d - self._bd * self._v_prev if self._iv is not None else p

    def set_gains(self, *, kp: float | None = None, ki: float | None = None, kd: float | None = None,
                  tf: float | None = None, n: float | None = None, b: float | None = None) -> None:
        """Change gains without a bump: the integral term absorbs the change of the proportional term.

        Parameters left out keep their value; the derivative filter keeps its form (``tf`` in seconds, or
        ``n = Td/tf`` when the PID was built with `n`) unless `tf` or `n` is given. The integral term takes
        the change of ``kp*(b*r - y)`` at the last measurement and the current setpoint, so a call with the same
        measurement gives the output the old gains would have given (Åström & Hägglund, sect. 13.5); the
        derivative term keeps its state. With a measured `velocity` the integral also takes the change of
        the velocity term at the last measured velocity, for the same reason. The default tracking time
        follows the new gains.

        Examples
        --------
        >>> pid = PID(kp=2.0, ki=1.0, dt=0.1)
        >>> pid.setpoint = 1.0
        >>> float(pid(0.0, [0.5])[0])    # 2*(1 - 0.5); the integral becomes 0.1*0.5
        1.0
        >>> pid.set_gains(kp=4.0)
        >>> float(pid(0.1, [0.5])[0])    # 1.05, as with kp = 2, although 4*(1 - 0.5) = 2
        1.05
        """
        if tf is None and n is None:
            tf, n = (self.tf, None) if self.n is None else (None, self.n)
        old = self._held_terms() if self._y_prev is not None else 0.0
        self._apply_gains(kp=self.kp if kp is None else kp, ki=self.ki if ki is None else ki,
                          kd=self.kd if kd is None else kd, tf=tf, n=n, b=self.b if b is None else b)
        if self._y_prev is not None:
            self.integral += old - self._held_terms()

    # ------------------------------------------------------------------ the calling convention
    def _set_setpoint(self, r: np.ndarray) -> None:
        self._setpoint = r
        self._r = float(r[0])

    def reset(self, u: float | None = None) -> None:
        """Clear the internal state and :attr:`events`; with `u`, the first output equals `u` (bumpless start).

        Parameters
        ----------
        u : float, optional
            The output the plant is receiving now (manual mode): the integral term is initialised at the
            next call so that the output continues from it, and the rate limit starts from it.

        Examples
        --------
        >>> pid = PID(kp=2.0, ki=1.0, dt=0.1)
        >>> pid.reset(u=3.0)
        >>> float(pid(0.0, [0.7])[0])
        3.0
        """
        self.events.clear()
        self.integral = 0.0
        self._d = 0.0
        self._y_prev: float | None = None
        self._v_prev = 0.0
        self._u_start = None if u is None else _finite(u, "u")
        self._u_prev = self._u_start

    def __call__(self, t: float, y: Sequence[float]) -> np.ndarray:
        """The input to hold over ``[t, t + dt)`` given the measured outputs `y` (in :attr:`outputs` order).

        Returns
        -------
        numpy.ndarray
            One value, within ``[u_min, u_max]`` and the rate limit.
        """
        try:
            if self._iv is None:
                (yv,) = y
                yv = float(yv)
                vv = yv
            else:
                y0, y1 = y
                yv, vv = (float(y0), float(y1)) if self._iy == 0 else (float(y1), float(y0))
        except (TypeError, ValueError):
            count = "one output" if self._iv is None else "two outputs"
            raise InvalidSettingError(f"the PID measures {count} ({', '.join(self.outputs)}); got y={y!r}") from None
        if yv - yv != 0.0 or vv - vv != 0.0:  # NaN or infinite
            raise ControllerError(f"the PID got a non-finite measurement {list(self.outputs)}={list(y)} "
                                  f"at t={t:.6g} s")
        if self._iv is None:
            y_prev = self._y_prev if self._y_prev is not None else yv
            d = self._ad * self._d - self._bd * (yv - y_prev)
        else:
            d = self._ad * self._d - self._bd * vv
        p = self._kb * self._r - self.kp * yv
        if self._u_start is None:
            v = self.u0 + p + self.integral + d
        else:  # bumpless start: the first output is the given u, the integral term takes the difference
            v = self._u_start
            self.integral = v - self.u0 - p - d
            self._u_start = None
        u = v
        u_prev = self._u_prev
        if u_prev is not None:
            if u > u_prev + self._dumax:
                u = u_prev + self._dumax
            elif u < u_prev - self._dumax:
                u = u_prev - self._dumax
        if u > self._umax:
            u = self._umax
        elif u < self._umin:
            u = self._umin
        e = self._r - yv
        if self._ao:
            self.integral += self._bi * e + self._ao * (u - v)
        elif self.anti_windup != "clamping" or u == v or (u < v) == (e < 0):
            self.integral += self._bi * e
        self._d = d
        self._y_prev = yv
        self._v_prev = vv
        self._u_prev = u
        return np.array((u,))

    # ------------------------------------------------------------------ files
    def _settings(self) -> dict[str, Any]:
        filt: dict[str, Any] = {"n": self.n} if self.n is not None else {"tf": self.tf}
        return {"kp": self.kp, "ki": self.ki, "kd": self.kd, "dt": self.dt, **filt, "b": self.b,
                "inputs": list(self.inputs), "outputs": list(self.outputs), "velocity": self.velocity,
                "u_min": self._umin, "u_max": self._umax, "du_max": self._dumax, "u0": self.u0,
                "anti_windup": self.anti_windup, "tt": self._tt_given}

    def __repr__(self) -> str:
        vel = f", velocity={self.velocity!r}" if self.velocity is not None else ""
        return (f"PID(kp={self.kp:.6g}, ki={self.ki:.6g}, kd={self.kd:.6g}, tf={self.tf:.6g}, b={self.b:g}, "
                f"dt={self.dt:g}, inputs={list(self.inputs)}, outputs={list(self.outputs)}{vel}, "
                f"u_min={self._umin:g}, u_max={self._umax:g})")

    # ------------------------------------------------------------------ linear analysis
    def feedback_tf(self) -> control.TransferFunction:
        """The feedback part ``C(z)`` of the law from ``-y`` to ``u`` (limits off), as a discrete transfer function.

        With a measured `velocity` it is the part acting on the controlled output, ``kp + ki*dt/(z - 1)``;
        the velocity's part is :meth:`velocity_tf`.

        Examples
        --------
        >>> c = PID(kp=1.0, ki=2.0, dt=0.5).feedback_tf()
        >>> float(np.real(c(3.0)))       # 1 + 2*0.5/(3 - 1)
        1.5
        """
        if self._iv is not None:
            return _pid_tf(self.kp, self.ki, 0.0, 0.0, self.dt)
        return _pid_tf(self.kp, self.ki, self.kd, self.tf, self.dt)

    def velocity_tf(self) -> control.TransferFunction:
        """The part ``K_v(z) = kd*dt*z/((tf + dt)*z - tf)`` of the law from ``-velocity`` to ``u`` (0 without one).

        Examples
        --------
        >>> pid = PID(kp=1.0, kd=3.0, tf=0.5, dt=0.5, outputs=["w", "y"], velocity="w")
        >>> float(np.real(pid.velocity_tf()(1.0)))   # the static gain is kd
        3.0
        """
        if self._iv is None or self.tf == 0:
            return control.tf([0.0 if self._iv is None else self.kd], [1.0], self.dt)
        return control.tf([self.kd * self.dt, 0.0], [self.tf + self.dt, -self.tf], self.dt)

    def setpoint_tf(self) -> control.TransferFunction:
        """The setpoint part ``F(z) = kp*b + ki*dt/(z - 1)`` of the law (from ``r`` to ``u``)."""
        z = control.tf([1.0, 0.0], [1.0], self.dt)
        return self.kp * self.b + self.ki * self.dt / (z - 1)
