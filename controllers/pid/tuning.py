"""Tuning of :class:`~controllers.pid.PID` on a linear model: :func:`tune_pid`.

Two structures, both designed on the *exact discrete loop* (the model sampled with zero-order hold at the
controller's sample time, the PID's own discrete law) and checked with ``control.stability_margins`` on the
loop's exact frequency response:

* PID on one output (the derivative of that output): loop shaping at the gain crossover;
* PI on the controlled output plus feedback of a measured velocity (``velocity="omega_m"``), the servo
  structure: a direct search over the velocity gain and the crossover, with ``kp`` and ``ki`` solved exactly
  for the phase margin, the loop broken at the plant input.

See :func:`tune_pid` for the methods (its search is in :mod:`controllers.pid._search`, the plant's frequency
response in :mod:`controllers.pid._plant`). ``controllers.pid`` re-exports :func:`tune_pid`.

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
import warnings
from typing import Any

import control
import numpy as np

from cosim.errors import ControllerError, CosimDeprecationWarning, InvalidSettingError, UnknownVariableError
from cosim.numbers import finite_number as _finite

from ..base import KNOWN_CONSTANT_INPUTS, DesignModel
from ._plant import _antiresonance, _Plant, _wrap
from ._saturation import _STEADY_FRACTION, _Actuator, _default_step, _figures, _pid_step, _static_gain
from ._search import _NS, _SAT_HORIZONS, _WC_DECADES, _Candidate, _Demand, _design, _not_met, _step_figures
from .controller import PID

__all__ = ["tune_pid"]

#: Velocity structure: gains tried, as fractions of the one whose velocity loop alone crosses over at
#: `max_crossover`.
_KD_FRACTIONS = 10.0 ** np.linspace(-3.0, 0.0, 97)
#: Velocity structure: loop gains (about -2 to +2 dB) over which the predicted setpoint step must keep the
#: overshoot limit, and the default phase margin [deg].
_VELOCITY_GAINS = (0.8, 0.9, 1.0, 1.1, 1.25)
_VELOCITY_PM = 48.0
#: Velocity structure: highest position-loop crossover as a fraction of the antiresonance (the lowest lightly
#: damped zero from the input to the velocity, see :func:`~controllers.pid._plant._antiresonance`), where the
#: load decouples from the motor.
_ANTIRESONANCE_FRACTION = 0.7


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
                    load_step_iae=c.iae_load, _horizon=c.horizon)
        if plant.gains != (1.0,):
            _step_figures(plant, c, pid.b, None)
            info.update(loop_gain_range=[min(plant.gains), max(plant.gains)], step_overshoot_worst_pct=c.overshoot,
                        step_settling_time_worst_s=c.settling)
    return info


def _limit_report(pid: PID, plant: _Plant, act: _Actuator, step: float | None, horizon: float) -> dict[str, Any]:
    """What the limits do to the set-point step: the largest step that stays linear, and the step of `step` run
    through :class:`PID` itself (limits, rate limit, anti-windup) against the model: its overshoot, settling
    time and input peak."""
    n = max(2, math.ceil(_SAT_HORIZONS * horizon / plant.dt))
    free = copy.deepcopy(pid)
    free._umin, free._umax, free._dumax = -math.inf, math.inf, math.inf
    _, u = _pid_step(free, plant, 1.0, n)
    rise, fall = u - pid.u0, pid.u0 - u  # per unit step up; a step down mirrors it
    room_up = min(_room(act.hi - pid.u0, rise), _room(pid.u0 - act.lo, fall))
    room_down = min(_room(act.hi - pid.u0, fall), _room(pid.u0 - act.lo, rise))
    du = np.abs(np.diff(u))
    room_rate = act.du / du.max() if du.size and du.max() > 0 else math.inf
    info: dict[str, Any] = {"linear_step_max": min(room_up, room_down, room_rate)}
    if step is None:
        return info
    worst = None
    for s in {step, -step} if room_up != room_down else {step}:
        y, u = _pid_step(pid, plant, s, n)
        overshoot, settling = (float(v[0]) for v in _figures(y[:, None], s, plant.dt))
        if worst is None or (overshoot, settling) > worst[:2]:
            worst = (overshoot, settling, float(np.abs(u).max()))
    assert worst is not None
    info.update(step_overshoot_pct=worst[0], step_settling_time_s=worst[1], step_input_peak=worst[2])
    return info


def _room(room: float, per_unit: np.ndarray) -> float:
    """The largest step whose input `per_unit * step` stays within `room`."""
    top = float(per_unit.max())
    return room / top if top > 0 else math.inf


def tune_pid(sys: control.StateSpace, *, dt: float, input: str | None = None, tracked: str | None = None,
             velocity: str | None = None, phase_margin: float | None = None, bandwidth: float | None = None,
             bandwidth_hz: float | None = None, derivative: bool | None = None, gain_margin_db: float = 6.0,
             modulus_margin: float = 0.5, max_overshoot: float | None = 10.0, max_crossover: float | None = None,
             delay: int = 0, b: float | None = None, n: float | None = None, u_min: float | None = None,
             u_max: float | None = None, du_max: float | None = None, u0: float = 0.0,
             anti_windup: str | None = "back-calculation", tt: float | None = None, step: float | None = None,
             output: str | None = None) -> PID:
    """Design a discrete :class:`PID` on a linear model for a phase margin, or a crossover frequency.

    Method (PID on one output): loop shaping at the gain crossover ``wc`` on the *discrete* loop
    ``L(z) = C(z) P(z)``, with ``P`` the model sampled with zero-order hold at `dt` (times ``z**-delay``) and
    ``C`` the PID's exact discrete law. At a candidate ``wc`` the controller must supply the phase
    ``-180 deg + PM - arg P``: for a grid of integral times ``Ti = alpha/wc`` (alpha 1.5 to 30) and filters
    ``n = Td/tf`` (2 to 30) the derivative time ``Td`` is solved so that ``arg L = -180 deg + PM`` exactly (and
    for the PI, ``Ti`` is solved), then ``kp`` makes ``|L| = 1``.

    Method (with `velocity`: PI on `tracked`, ``D = -kd * velocity``): a direct search on the exact discrete
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

    **Input limits.** With a limit (`u_max`, `u_min` or `du_max`) the design must also deliver a set-point
    `step` through the actuator: a design is admissible only when its step, run through the PID's exact
    discrete law with the limits, rate limit and anti-windup on (the model sampled with zero-order hold; the
    loop gains as above, at their extremes; both directions when the limits are not symmetric about `u0`),
    keeps `max_overshoot` and settles. Saturating briefly is allowed: that is what the anti-windup is for.
    The step defaults to the one whose steady input takes half the actuator's range (its narrower side about
    `u0`), ``0.5 * u_max * |G(0)|`` for symmetric limits, ``G(0)`` the static gain from `input` to `tracked`;
    an integrating plant holds any position without input, so there no step is derived and the design is the
    linear one, with ``info["linear_step_max"]`` the largest step that keeps the input within the limits
    (give `step` to design for a larger one). When the step needs a steady input beyond the limit, or no
    robust design delivers it, the linear design is kept and ``info["warnings"]`` says so with the largest
    step that stays linear. The crossover search runs every 4th crossover down to the first one whose best
    designs deliver the step, then the crossovers around it as above.

    Parameters
    ----------
    sys : control.StateSpace
        Continuous or discrete (then at `dt`) model; inputs named ``"const"`` (an identified model's
        constant term) are ignored.
    dt : float
        Controller sample time [s].
    input, tracked : str, optional
        Manipulated input and controlled (tracked) output, as ``--input`` and ``--tracked`` of
        ``cosim design pid``; default the first non-"const" input and the first output.
    velocity : str, optional
        A measured output to take the derivative action from, e.g. ``"omega_m"`` (a velocity collocated with
        `input` damps a resonance between them and `tracked`). The PID then measures `tracked` and `velocity`
        (``pid.outputs`` in the model's output order) and tracks `tracked`; the velocity is not filtered.
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
        Largest overshoot [%] of the predicted setpoint step (default 10; with limits, of the linear step and of
        the saturated step of `step`); None: no limit. When no robust design meets it, the one with the least
        overshoot is kept and ``info["warnings"]`` says so.
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
        Passed on to :class:`PID` (limits, bias, anti-windup). `u_max` alone mirrors into ``u_min = -u_max``,
        as ``--u-max`` does in ``cosim design pid`` (give ``u_min=-math.inf`` for no lower limit).
    step : float, optional
        The set-point step [unit of `tracked`] the design must deliver through the limits (see *Input
        limits*); default derived from the plant. Stored as ``info["design_step"]``; ``cosim validate`` steps
        by it by default.
    output : str, optional
        Deprecated name of `tracked` (a ``DeprecationWarning``).

    Returns
    -------
    PID
        With ``info``: ``method``, the targets, ``structure`` ("PI", "PID" or "PI+velocity"), ``velocity``,
        ``ti_s``, ``td_s`` (``kd/kp``), ``tf_s``, ``b``, the achieved ``gain_margin`` (factor;
        ``gain_margin_db``; at ``phase_crossover_rad_s``), ``lower_gain_margin_db`` (conditionally stable
        loops), ``phase_margin_deg`` (the smallest over the gain crossings, lag or lead), ``crossover_rad_s``
        (= ``bandwidth_rad_s``; where that margin is), ``crossover_hz``, ``gain_crossovers_rad_s``,
        ``modulus_margin`` (min ``|1 + L|``) and ``sensitivity_peak``, ``closed_loop_stable``,
        ``closed_loop_bandwidth_rad_s``, and the predicted ``step_overshoot_pct``, ``step_settling_time_s``
        (2 %) and ``load_step_iae`` (per unit input step); with `velocity` also ``loop_gain_range`` and the
        worst linear step figures over it, ``step_overshoot_worst_pct`` and ``step_settling_time_worst_s``,
        ``antiresonance_rad_s`` and the resulting ``max_crossover_rad_s``. All loop figures are for the loop
        broken at the plant input. With limits: ``design_step`` and ``design_step_source``,
        ``linear_step_max``, ``delivers_step``, ``step_input_peak``, and ``step_overshoot_pct`` and
        ``step_settling_time_s`` are those of the saturated step of `design_step` (the loop's with its limits),
        ``step_overshoot_linear_pct`` and ``step_settling_time_linear_s`` the linear ones; ``notes`` and
        ``warnings`` say what the limits did.

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
    reports a negative number. Predicted step figures are those of the linear model, with the PID's limits
    when it has them; friction and backlash are not in them.

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
    >>> pid = tune_pid(motor, dt=0.001, tracked="angle", velocity="speed", bandwidth=20.0)
    >>> pid.outputs, pid.tracked, pid.info["structure"]
    (('angle', 'speed'), ('angle',), 'PI+velocity')
    >>> round(pid.info["crossover_rad_s"], 2), round(pid.info["phase_margin_deg"], 1)
    (20.0, 48.0)

    A mass on a spring (1 kg, 100 N/m) and a force limit of 50 N: the design delivers a 0.25 m step (its steady
    force is half the limit); the predicted overshoot is that of the loop with the limit (the input saturates
    for steps above 0.079 m).

    >>> spring = control.ss([[0, 1], [-100, -1]], [[0], [1]], [[1, 0]], 0, inputs=["F"], outputs=["x"])
    >>> pid = tune_pid(spring, dt=0.001, u_max=50)
    >>> pid.u_min.tolist(), pid.info["design_step"], pid.info["delivers_step"]
    ([-50.0], 0.25, True)
    >>> round(pid.info["step_overshoot_pct"], 1), pid.info["step_input_peak"], round(pid.info["linear_step_max"], 3)
    (8.7, 50.0, 0.079)
    """
    if output is not None:
        warnings.warn("tune_pid(output=...) is deprecated and will be removed; use tracked=... (the name of "
                      "`cosim design pid --tracked`)", CosimDeprecationWarning, stacklevel=2)
        if tracked is not None and tracked != output:
            raise InvalidSettingError(f"give the tracked output once: tracked={tracked!r} and output={output!r}")
        tracked = output
    if u_min is None and u_max is not None:
        try:
            u_min = -float(u_max)  # as --u-max alone does in `cosim design pid`
        except (TypeError, ValueError):
            pass  # the PID refuses it below, in its own words
    model = DesignModel.from_statespace(sys, dt=dt)
    h = model.dt
    i_in, i_out = _select_signals(model, input, tracked)
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
    check = PID(kp=1.0, dt=h, u_min=u_min, u_max=u_max, du_max=du_max, u0=u0, anti_windup=anti_windup, tt=tt)
    act = _Actuator(check._umin, check._umax, check._dumax, check.u0, anti_windup, tt)
    if step is not None:
        step = _finite(step, "step")
        if step == 0:
            raise InvalidSettingError("step is the set-point step the design must deliver; give a non-zero one")
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
    step, source, demand, steady_note = _demand(plant, act, step)
    best, robust = _design(plant, pm, bandwidth, derivative, gm_min, mm_min, w_max, ns, b, max_overshoot, demand)
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
    report = _loop_report(pid, plant)
    horizon = report.pop("_horizon", None)
    if step is not None:
        report.update(design_step=step, design_step_source=source)
    if act.limited:
        report.update(design_step=step, design_step_source=source,
                      delivers_step=False if steady_note is not None else best.delivers,
                      step_overshoot_linear_pct=report.get("step_overshoot_pct"),
                      step_settling_time_linear_s=report.get("step_settling_time_s"))
        if horizon is not None:
            report.update(_limit_report(pid, plant, act, step, horizon))
        report["notes"] = _limit_notes(report, plant, step, steady_note, max_overshoot, notes)
    pid.info = {**info, **report}
    pid.design_model = model
    return pid


def _demand(plant: _Plant, act: _Actuator, step: float | None) -> tuple[float | None, str | None, _Demand | None,
                                                                          str | None]:
    """The design step, where it comes from, what the search must deliver (None: the linear design), and why a
    step cannot be delivered at all (its steady input is beyond the limits)."""
    source = None if step is None else "asked"
    if not act.limited:
        return step, source, None, None
    if step is None:
        step = _default_step(plant, act)
        if step is None:
            return None, None, None, None
        source = f"steady input {_STEADY_FRACTION:.0%} of the limit"
    g0 = _static_gain(plant)
    if g0 is not None:
        steady = [act.u0 + s / g0 for s in (step, -step)]
        if not all(act.lo < u < act.hi for u in steady):
            return step, source, None, (f"a step of {step:.4g} needs a steady input of {steady[0]:.4g}, beyond "
                                        f"the limits [{act.lo:g}, {act.hi:g}]: no design can hold it")
    return step, source, _Demand(step, act), None


def _limit_notes(report: dict[str, Any], plant: _Plant, step: float | None, steady_note: str | None,
                 max_overshoot: float | None, warns: list[str]) -> list[str]:
    """Say what the limits did (``notes``); append to `warns` what the user must know (steps not delivered)."""
    top = report.get("linear_step_max")
    linear = f"steps up to {top:.3g} stay linear" if top is not None and math.isfinite(top) else ""
    notes = []
    if step is None:
        why = (f"{plant.output} has no steady state for {plant.input} (it integrates it, or drifts)"
               if _static_gain(plant) is None
               else f"{plant.input} has no range limit, only a rate limit")
        notes.append(f"{why}: no step is derived from the limits; {linear or 'the input stays within them'}; "
                     "give step= (--step) to design for a larger one")
    elif steady_note is not None:
        warns.append(f"{steady_note}; kept the linear design" + (f", {linear}" if linear else ""))
    elif report.get("delivers_step") is False:
        sat, settles = report.get("step_overshoot_pct"), report.get("step_settling_time_s")
        limit = f" and overshoot <= {max_overshoot:g} %" if max_overshoot is not None else ""
        shown = ("" if sat is None else ", whose step never settles with the limits" if not (
            settles is not None and math.isfinite(settles)) else f", whose step overshoots {sat:.1f} % with the limits")
        warns.append(f"no robust design delivers a step of {step:.4g} in {plant.output} within the limits{limit}; "
                     f"kept the linear design{shown}" + (f"; {linear}" if linear else ""))
    return notes
