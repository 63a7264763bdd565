"""What a validation checks when it is not told: the scenario and specs an FMU and a controller call for, and the
FMU parameter names a validation may set, checked before anything runs.

* :func:`default_checks` - for the bundled telescope servo its control specs (:data:`TELESCOPE_SPECS` and
  :data:`TELESCOPE_SCENARIO`); for any other FMU, what the plant and the design say: a set-point step of the
  controller's design step (``info["design_step"]``, the step :func:`~controllers.pid.tune_pid` delivered
  through the input limits), its settling time from the predicted one, 10 % overshoot, a steady-state error of
  2 % of the step, and the controller's input limit (else the FMU input's declared range). Each default comes
  with the reason it was chosen (:attr:`DefaultChecks.why`), which ``cosim validate`` prints.
* :func:`check_parameter_names` - every FMU parameter a scenario or the caller sets exists: a misspelt scenario
  key (``duraton=2``) is refused in one line that lists the scenario keys and names the nearest one.

Examples
--------
>>> nice_up(0.37), nice_up(1.2e-3), nice(0.0024717)
(0.4, 0.0015, 0.0025)
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import SpecError

__all__ = ["BUNDLED_MODEL", "SCENARIO_KEYS", "TELESCOPE_SCENARIO", "TELESCOPE_SPECS", "DefaultChecks",
           "check_parameter_names", "default_checks", "fmu_parameters", "nice", "nice_up"]

#: The bundled servo's model name: an FMU of this name is judged by the telescope's specs.
BUNDLED_MODEL = "two_mass_servo"
TELESCOPE_SPECS = ("settling_time<=1.0", "overshoot<=10%", "steady_state_error<=2e-5", "input_limit<=5000")
TELESCOPE_SCENARIO = "step:amp=0.01,at=0.05,duration=2"
#: The keys a scenario's text may use (``step:amp=0.01,at=0.05,duration=2``); others are FMU parameters.
SCENARIO_KEYS = ("amp", "at", "duration", "rate", "input", "setpoint", "band", "name")
#: Default specs for any FMU: the overshoot limit [%], the steady-state error as a fraction of the step, the
#: settling time as a multiple of the predicted one, and the run as a multiple of that settling limit.
_OVERSHOOT = 10.0
_ERROR_FRACTION = 0.02
_SETTLING_MARGIN = 2.0
_RUN_SETTLINGS = 4.0
#: A run without a predicted settling time: its length [s], and the settling limit as a fraction of it.
_RUN_DEFAULT = 2.0


def nice_up(x: float) -> float:
    """`x` rounded up to a number people write: 1, 1.5, 2, 3, 4, 5, 6, 8 times a power of ten."""
    if not (math.isfinite(x) and x > 0):
        return x
    scale = 10.0 ** math.floor(math.log10(x))
    for m in (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * scale >= x * (1 - 1e-12):
            return float(f"{m * scale:.3g}")
    return float(f"{10 * scale:.3g}")


def nice(x: float) -> float:
    """`x` to two significant digits."""
    return float(f"{x:.2g}") if math.isfinite(x) and x != 0 else x


@dataclass(frozen=True)
class DefaultChecks:
    """The scenario and specs :func:`default_checks` chose, and why (one short reason each)."""

    scenario: str
    specs: tuple[str, ...]
    why: tuple[str, ...]
    bundled: bool = False


def _description(fmu: Any, kind: str | None = None) -> Any:
    from ..plant.model_description import open_model_description

    path = getattr(fmu, "path", fmu)
    return open_model_description(path, kind)


def fmu_parameters(md: Any) -> list[str]:
    """Names of the parameters an FMU lets a run set (causality parameter, fixed or tunable), in its order."""
    from ..plant.model_description import parameter_names

    return parameter_names(md)


def check_parameter_names(fmu: Any, scenarios: Iterable[Any], parameters: Mapping[str, Any] | None = None, *,
                          kind: str | None = None) -> None:
    """Refuse, in one line and before anything runs, a name set on the FMU that is not one of its parameters.

    A scenario's extra ``key=value`` (:func:`~cosim.loop.validation.parse_scenario`) is an FMU parameter, so a
    misspelt scenario key lands here: the message says it is neither a scenario key (listed) nor a parameter of
    the FMU, and names the nearest of both. Array elements (``A[1,2]``) count as their array.
    """
    md = None
    for source, names in [(s, list(s.parameters)) for s in scenarios] + [(None, list(parameters or {}))]:
        for name in names:
            if md is None:
                md = _description(fmu, kind)
                known = fmu_parameters(md)
                label = Path(getattr(fmu, "path", fmu)).name
            if name.partition("[")[0].strip() in known:
                continue
            near = difflib.get_close_matches(name, [*SCENARIO_KEYS, *known], n=1, cutoff=0.6)
            hint = f"; did you mean {near[0]}?" if near else ""
            listed = (f"its parameters: {', '.join(known[:30])}" + (" ..." if len(known) > 30 else "") if known
                      else "it has no parameters")
            if source is None:
                raise SpecError(f"{name!r} is not a parameter of {label}{hint} ({listed})")
            raise SpecError(f"scenario option {name!r} in {source.name!r} is neither a scenario key "
                            f"({', '.join(SCENARIO_KEYS)}) nor a parameter of {label}{hint} ({listed})")


def _declared(md: Any, name: str) -> Any:
    return next((v for v in md.modelVariables if v.name == name), None)


def _unit(md: Any, name: str) -> str:
    from ..plant.model_description import variable_unit

    unit = variable_unit(_declared(md, name))
    return f" {unit}" if unit else ""


def _number(text: Any) -> float | None:
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _input_limit(controller: Any, md: Any) -> tuple[float | None, str]:
    """The largest input magnitude the loop may use: the controller's limit, else the FMU input's declared one."""
    name = controller.inputs[0]
    lo, hi = float(controller.u_min[0]), float(controller.u_max[0])
    bound = max(abs(v) for v in (lo, hi) if math.isfinite(v)) if math.isfinite(lo) or math.isfinite(hi) else None
    if bound is not None:
        return bound, f"the controller's limit on {name}"
    var = _declared(md, name)
    declared = [abs(v) for v in (_number(getattr(var, "min", None)), _number(getattr(var, "max", None)))
                if v is not None]
    if declared:
        return max(declared), f"{name}'s declared range in the FMU"
    return None, ""


def _static_step(controller: Any) -> float | None:
    """The step whose steady input takes half the controller's input range, from its design model (None for an
    integrating plant, or without a model or limits)."""
    model = getattr(controller, "design_model", None)
    if model is None:
        return None
    lo, hi = float(controller.u_min[0]), float(controller.u_max[0])
    room = min(hi, -lo)
    if not (math.isfinite(room) and room > 0):
        return None
    try:
        gain = model.static_gain(controller.inputs[0], controller.tracked[0])
    except Exception:  # noqa: BLE001 - a model without those names: no step from it
        return None
    return 0.5 * room * abs(gain) if gain else None


def _step(controller: Any, md: Any) -> tuple[float, str]:
    info = controller.info
    step = _number(info.get("design_step"))
    if step:
        return step, "the controller's design step"
    step = _static_step(controller)
    if step:
        return step, "the step whose steady input takes half the controller's input range"
    step = _number(info.get("linear_step_max"))
    if step:  # rounded down to two digits: a step people write, still within the limits
        scale = 10.0 ** (math.floor(math.log10(abs(step))) - 1)
        return float(f"{math.floor(abs(step) / scale) * scale:.2g}"), ("a step the design keeps within its input "
                                                                        f"limits (the largest is {step:.4g})")
    var = _declared(md, controller.tracked[0])
    nominal = _number(getattr(var, "nominal", None))
    if nominal:
        return nominal, f"{controller.tracked[0]}'s nominal value in the FMU"
    return 1.0, "a unit step (no design step, no limit: a linear loop is judged alike at any size)"


def _settling(controller: Any) -> tuple[float | None, str]:
    """The predicted settling time of the step, or one from the closed loop's slowest pole (MPC)."""
    info = controller.info
    predicted = _number(info.get("step_settling_time_s"))
    if predicted and predicted > 0:
        return predicted, "predicted"
    radius = _number(info.get("closed_loop_spectral_radius"))
    if radius is not None and 0 < radius < 1:
        return 4.0 * controller.dt / -math.log(radius), "four closed-loop time constants"
    return None, ""


def default_checks(fmu: str | os.PathLike | Any, controller: Any, *, kind: str | None = None,
                   steps: Sequence[float] = ()) -> DefaultChecks:
    """The scenario and specs a validation of `controller` on `fmu` uses when none are given, with the reasons.

    Parameters
    ----------
    fmu : path-like or FmuPlant
    controller : controllers.base.Controller
    kind : {"cs", "me"}, optional
    steps : sequence of float
        The set-point steps of the scenarios the caller gives (the steady-state error is judged relative to the
        smallest); default the default scenario's.

    Returns
    -------
    DefaultChecks
        For the bundled servo (model name ``two_mass_servo``) :data:`TELESCOPE_SCENARIO` and
        :data:`TELESCOPE_SPECS`; for any other FMU a step of the design step (else the step whose steady input
        takes half the controller's input range, else the largest step it keeps linear, else the tracked
        output's declared nominal, else 1), ``settling_time`` twice the predicted one (rounded up),
        ``overshoot<=10%``, ``steady_state_error`` 2 % of the step and ``input_limit`` the controller's limit
        (else the FMU input's declared range; none without either). The run lasts four settling limits.

    Examples
    --------
    >>> from cosim import build_fmu
    >>> from controllers.pid import PID
    >>> pid = PID(kp=1.5e4, ki=1.3e4, dt=1e-3, inputs="Tm", outputs="theta_L", u_min=-5000, u_max=5000)
    >>> default_checks(build_fmu(), pid).specs == TELESCOPE_SPECS
    True
    """
    md = _description(fmu, kind)
    if md.modelName == BUNDLED_MODEL:
        return DefaultChecks(TELESCOPE_SCENARIO, TELESCOPE_SPECS,
                             ("the bundled telescope servo: a 0.01 rad step, its axis's control specs",), True)
    tracked = controller.tracked[0]
    unit = _unit(md, tracked)
    step, step_why = _step(controller, md)
    settle, settle_how = _settling(controller)
    at = nice_up(max(0.05, 5.0 * controller.dt))
    if settle is not None:
        limit = nice_up(max(_SETTLING_MARGIN * settle, 10.0 * controller.dt))
        duration = nice_up(at + _RUN_SETTLINGS * limit)
        settle_why = f"settling_time<={limit:g}: twice the {settle_how} {settle:.3g} s"
    else:
        duration = _RUN_DEFAULT
        limit = duration / 2
        settle_why = f"settling_time<={limit:g}: half the run (no settling time predicted)"
    judged = min((abs(s) for s in steps), default=abs(step))
    error = nice(_ERROR_FRACTION * judged)
    specs = [f"settling_time<={limit:g}", f"overshoot<={_OVERSHOOT:g}%", f"steady_state_error<={error:g}"]
    why = [f"step:amp={step:.4g}{unit}: {step_why}", settle_why,
           f"steady_state_error<={error:g}{unit}: {_ERROR_FRACTION:.0%} of the step"]
    bound, bound_why = _input_limit(controller, md)
    if bound is not None:
        specs.append(f"input_limit<={bound:g}")
        why.append(f"input_limit<={bound:g}: {bound_why}")
    return DefaultChecks(f"step:amp={step:.6g},at={at:g},duration={duration:g}", tuple(specs), tuple(why))
