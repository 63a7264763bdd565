"""``cosim design pid`` and ``cosim design mpc``: a controller designed on an identified linear model."""

from __future__ import annotations

import math
from typing import Any

import click

from ..errors import InvalidSettingError
from ..numbers import parse_number
from ._command import _deprecated, _emit, _friendly, _names, _ranges
from ._outputs import check_outputs

__all__ = ["design"]


@click.group()
def design() -> None:
    """Design a controller on an identified model (cosim model JSON) and save it as JSON.

    \b
    Example:
      cosim design pid model.json --tracked theta_L --velocity omega_m --u-max 5000 -o pid.json
      cosim design mpc model.json --measured theta_m,theta_L --tracked theta_L --u-max 5000 -o mpc.json
    """


def _design_model(model_path: str, dt_text: str | None):
    """The identified model as a continuous named StateSpace, and the controller's sample time."""
    from ..export import to_statespace
    from ..identify.model import IdentifiedModel

    model = IdentifiedModel.load(model_path)
    if not model.is_linear:
        raise InvalidSettingError(f"{model_path} is nonlinear, and controllers are designed on a linear model; "
                                  "identify one with `cosim identify ... --library linear`")
    if dt_text is not None:
        dt = parse_number(dt_text, what="--dt")
        if not (math.isfinite(dt) and dt > 0):
            raise InvalidSettingError("--dt must be a positive sample time in seconds, e.g. --dt 1/2257 "
                                      f"(got {dt_text})")
    else:
        dt = model.dt
        if dt is None or not dt > 0:
            raise InvalidSettingError("the model has no sample time; pass the controller's --dt (e.g. --dt 1/2257)")
    return to_statespace(model), float(dt), model


def _limit(text: str | None, option: str) -> float | None:
    return None if text is None else parse_number(text, what=option)


def _bounds(u_min: str | None, u_max: str | None) -> tuple[float | None, float | None]:
    """--u-min and --u-max; a missing --u-min mirrors --u-max."""
    hi = _limit(u_max, "--u-max")
    lo = _limit(u_min, "--u-min") if u_min is not None else (-hi if hi is not None else None)
    return lo, hi


def _design_summary(controller: Any, out: str | None) -> tuple[dict[str, Any], list[str]]:
    """The ``--json`` payload (every design figure) and the few lines printed without it."""
    info = dict(controller.info)
    payload = {"kind": controller.kind, "dt": controller.dt, "inputs": list(controller.inputs),
               "outputs": list(controller.outputs), "tracked": list(controller.tracked), "info": info}
    if out:
        payload["file"] = str(controller.save(out))
    lines = _pid_lines(controller) if controller.kind == "pid" else _mpc_lines(controller)
    if out:
        lines.append(f"written: {out}")
    return payload, lines


def _g(value: Any, digits: int = 3) -> str:
    """A number to `digits` significant digits (``inf`` and missing ones in words)."""
    if value is None:
        return "n/a"
    value = float(value)
    return f"{value:.{digits}g}" if math.isfinite(value) else ("inf" if value > 0 else "-inf")


def _seconds(dt: float) -> str:
    """A sample time as people write it: ``1/5000 s`` when it is one over a whole rate, else ``0.0002 s``."""
    rate = 1.0 / dt
    if abs(rate - round(rate)) <= 1e-6 * rate and round(rate) > 1:
        return f"1/{round(rate)} s"
    return f"{dt:.4g} s"


def _limits(controller: Any) -> str:
    parts = []
    for name, lo, hi, du in zip(controller.inputs, controller.u_min, controller.u_max, controller.du_max,
                                strict=True):
        if math.isfinite(lo) or math.isfinite(hi):
            parts.append(f"{name} in [{_g(lo, 4)}, {_g(hi, 4)}]")
        if math.isfinite(du):
            parts.append(f"|d{name}| <= {_g(du, 4)} per sample")
    return ", ".join(parts) or "no input limits"


def _pid_lines(pid: Any) -> list[str]:
    i = pid.info
    vel = f", velocity {i['velocity']}" if i.get("velocity") else ""
    lines = [f"{i.get('structure', 'PID')} on {i.get('input')} -> {i.get('output')}{vel}; dt {_seconds(pid.dt)}; "
             f"{_limits(pid)}",
             f"  gains: kp {_g(pid.kp)}, ki {_g(pid.ki)}, kd {_g(pid.kd)}"
             + (f", tf {_g(pid.tf)} s" if pid.tf else "") + f", b {_g(pid.b, 2)}",
             f"  loop: crossover {_g(i.get('crossover_hz'))} Hz, phase margin {_g(i.get('phase_margin_deg'))} deg, "
             f"gain margin {_g(i.get('gain_margin_db'))} dB, modulus margin {_g(i.get('modulus_margin'), 2)}"
             + ("" if i.get("closed_loop_stable", True) else ", closed loop UNSTABLE")]
    step = i.get("design_step")
    figures = (f"overshoot {_g(i.get('step_overshoot_pct'), 2)} %, settling {_g(i.get('step_settling_time_s'))} s")
    if step is not None and "step_overshoot_linear_pct" in i:
        source = f" ({i['design_step_source']})" if i.get("design_step_source") not in (None, "asked") else ""
        lines.append(f"  step {_g(step)}{source}, with the limits: {figures}; linear: overshoot "
                     f"{_g(i.get('step_overshoot_linear_pct'), 2)} %, settling "
                     f"{_g(i.get('step_settling_time_linear_s'))} s, up to steps of {_g(i.get('linear_step_max'))}")
    else:
        lines.append(f"  predicted step: {figures}")
    lines += [f"  note: {note}" for note in i.get("notes", [])]
    return lines


def _mpc_lines(mpc: Any) -> list[str]:
    i = mpc.info
    radius = i.get("closed_loop_spectral_radius")
    return [f"MPC on {', '.join(mpc.inputs)} -> {', '.join(mpc.tracked)} (measures {', '.join(mpc.outputs)}); "
            f"dt {_seconds(mpc.dt)}; {_limits(mpc)}",
            f"  horizon {mpc.horizon} moves ({_g(mpc.horizon * mpc.dt)} s); "
            f"solver {i.get('solver_path', i.get('solver'))}",
            f"  closed loop spectral radius {_g(radius, 4)}"
            + (" (stable)" if radius is not None and radius < 1 else " (NOT stable)" if radius is not None else "")
            + f", observer {_g(i.get('observer_spectral_radius'), 4)}"]


def _warn(controller: Any) -> None:
    """The design's warnings, one ``warning: ...`` line each on stderr."""
    for text in controller.info.get("warnings") or []:
        click.echo(f"warning: {' '.join(str(text).split())}", err=True)


@design.command("pid")
@click.argument("model_path", metavar="MODEL.json")
@click.option("--input", "input_name", default=None, help="Manipulated input (default: the model's first).")
@click.option("--tracked", "output_name", default=None, metavar="Y",
              help="Controlled (tracked) output (default: the model's first).")
@click.option("--velocity", default=None, metavar="Y",
              help="Take the derivative action from this measured velocity (e.g. omega_m, the motor's) instead of "
                   "differentiating the output: damps a two-mass resonance.")
@click.option("--dt", "dt_text", default=None, help="Sample time [s] (default: the model's, e.g. 1/2257).")
@click.option("--phase-margin", type=float, default=None, help="Target phase margin [deg] (default 60).")
@click.option("--bandwidth-hz", type=float, default=None, help="Target crossover frequency [Hz] instead.")
@click.option("--gain-margin-db", type=float, default=6.0, show_default=True, help="Least gain margin [dB].")
@click.option("--no-derivative", is_flag=True, help="Design a PI (no derivative action).")
@click.option("--u-min", default=None, help="Lower input limit (default: -u-max).")
@click.option("--u-max", default=None, help="Upper input limit, e.g. 5000.")
@click.option("--du-max", default=None, help="Largest input change per sample.")
@click.option("--step", "step_text", default=None, metavar="R",
              help="Set-point step the design must deliver through the input limits, in the tracked output's unit "
                   "(default: the step whose steady input takes half the limit; none for an integrating plant). "
                   "cosim validate steps by it by default.")
@click.option("-o", "--output", "outputs", multiple=True, metavar="FILE",
              help="Write the controller JSON. (Before 0.2, --output named the tracked signal: a model output given "
                   "here is still read so, with a deprecation warning.)")
@click.option("--out", "old_out", type=click.Path(dir_okay=False), default=None, hidden=True)
@click.option("--json", "as_json", is_flag=True, help="Print every design figure (gains, margins, steps) as JSON.")
@_friendly
def design_pid(model_path: str, input_name: str | None, output_name: str | None, velocity: str | None,
               dt_text: str | None,
               phase_margin: float | None, bandwidth_hz: float | None, gain_margin_db: float, no_derivative: bool,
               u_min: str | None, u_max: str | None, du_max: str | None, step_text: str | None,
               outputs: tuple[str, ...], old_out: str | None, as_json: bool) -> None:
    """Tune a discrete PID on the model for a phase margin or a bandwidth; report the margins achieved.

    With input limits the design delivers a set-point step through them (--step, default the step whose steady
    input takes half the limit): its predicted overshoot and settling are those of the loop with the limits.
    Prints a short summary (structure, gains, margins, the step with and without the limits, warnings);
    --json prints every figure.

    \b
    Example:
      cosim design pid model.json --input Tm --tracked theta_L --velocity omega_m --u-max 5000 -o pid.json
    """
    from controllers.base import DesignModel
    from controllers.pid import tune_pid

    from ..export import label_name

    sys_c, dt, _ = _design_model(model_path, dt_text)
    labels = [label_name(y) for y in sys_c.output_labels]
    signals = [o for o in outputs if o in labels and not o.lower().endswith(".json")]
    files = [o for o in outputs if o not in signals] + ([old_out] if old_out else [])
    if old_out:
        _deprecated("--out FILE", "-o/--output FILE")
    if signals:
        _deprecated(f"--output {signals[0]} (a signal)", f"--tracked {signals[0]}")
        if output_name is not None or len(signals) > 1:
            raise InvalidSettingError("give the tracked output once, with --tracked")
        output_name = signals[0]
    odd = [f for f in files if not f.lower().endswith(".json")]
    if odd:
        raise InvalidSettingError(f"-o/--output {odd[0]} is neither a .json file nor an output of the model "
                                  f"({', '.join(labels)}); write the controller to FILE.json and name "
                                  "the tracked output with --tracked")
    if len(files) > 1:
        raise InvalidSettingError(f"one controller file, please: -o/--output was given {', '.join(files)}")
    out = files[0] if files else None
    check_outputs({"-o/--output": [out]}, {"-o/--output": (".json",)})
    lo, hi = _bounds(u_min, u_max)
    step = _limit(step_text, "--step")
    if step is not None and not (math.isfinite(step) and step != 0):
        raise InvalidSettingError(f"--step is the set-point step the design must deliver; give a non-zero number, "
                                  f"e.g. --step 0.01 (got {step_text})")
    pid = tune_pid(sys_c, dt=dt, input=input_name, tracked=output_name, velocity=velocity,
                   phase_margin=phase_margin, bandwidth_hz=bandwidth_hz, gain_margin_db=gain_margin_db,
                   derivative=False if no_derivative else None, u_min=lo, u_max=hi,
                   du_max=_limit(du_max, "--du-max"), step=step)
    pid.design_model = DesignModel.from_statespace(sys_c, dt=dt)
    payload, lines = _design_summary(pid, out)
    _warn(pid)
    _emit(as_json, payload, "\n".join(lines))


@design.command("mpc")
@click.argument("model_path", metavar="MODEL.json")
@click.option("--input", "input_names", default=None, metavar="U,...",
              help="Manipulated inputs (default: the model's first that is not 'const').")
@click.option("--measured", default=None, metavar="Y,...",
              help="Measured outputs, in the plant's order (default: all model outputs); the rest is estimated.")
@click.option("--tracked", default=None, metavar="Y,...", help="Outputs that follow the set-point (default: the "
              "first measured).")
@click.option("--dt", "dt_text", default=None, help="Sample time [s] (default: the model's, e.g. 1/2257).")
@click.option("--horizon", default=20, show_default=True, type=click.IntRange(1, 500), help="Moves N.")
@click.option("--q", "q_text", default=None, help="Tracking-error weight (default: the MPC's).")
@click.option("--q-rate", default=None, help="Weight on the tracked outputs' rate (damping).")
@click.option("--r", "r_text", default=None, help="Input weight.")
@click.option("--r-delta", default=None, help="Input-change weight.")
@click.option("--u-min", default=None, help="Lower input bound (default: -u-max).")
@click.option("--u-max", default=None, help="Upper input bound, e.g. 5000.")
@click.option("--du-max", default=None, help="Largest input change per sample.")
@click.option("--state-bound", "state_bounds", multiple=True, metavar="NAME=LOW:HIGH",
              help="Soft bound on a state or output, e.g. omega_m=-2:2. Repeatable.")
@click.option("--hard-state-bounds", is_flag=True, help="Make the state bounds hard (the QP may become infeasible).")
@click.option("--disturbance", type=click.Choice(["input", "output", "none"]), default="input", show_default=True,
              help="Disturbance model for offset-free tracking.")
@click.option("--no-codegen", is_flag=True, help="Evaluate the QP through casadi's Python API instead of C.")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default=None,
              help="Write the controller JSON.")
@click.option("--out", "old_out", type=click.Path(dir_okay=False), default=None, hidden=True)
@click.option("--json", "as_json", is_flag=True, help="Print the design figures as JSON.")
@_friendly
def design_mpc(model_path: str, input_names: str | None, measured: str | None, tracked: str | None,
               dt_text: str | None, horizon: int, q_text: str | None, q_rate: str | None, r_text: str | None,
               r_delta: str | None, u_min: str | None, u_max: str | None, du_max: str | None,
               state_bounds: tuple[str, ...], hard_state_bounds: bool, disturbance: str, no_codegen: bool,
               out: str | None, old_out: str | None, as_json: bool) -> None:
    """Design a linear MPC (casadi, condensed QP, DAQP compiled to C) on the model.

    Terminal cost from the discrete Riccati equation, input and input-rate bounds, soft state bounds,
    offset-free tracking through a disturbance observer (steady-state Kalman filter).

    \b
    Example:
      cosim design mpc model.json --measured theta_m,theta_L --tracked theta_L --u-max 5000 -o mpc.json
    """
    from controllers.mpc import MPC

    if old_out:
        _deprecated("--out FILE", "-o/--output FILE")
        if out:
            raise InvalidSettingError("one controller file, please: give -o/--output only")
        out = old_out
    check_outputs({"-o/--output": [out]}, {"-o/--output": (".json",)})
    sys_c, dt, _ = _design_model(model_path, dt_text)
    lo, hi = _bounds(u_min, u_max)
    weights = {key: parse_number(text, what=f"--{key.replace('_', '-')}")
               for key, text in (("q", q_text), ("q_rate", q_rate), ("r", r_text), ("r_delta", r_delta)) if text}
    mpc = MPC(sys_c, dt=dt, horizon=horizon, inputs=_names(input_names, "--input") if input_names else None,
              outputs=_names(measured, "--measured") if measured else None,
              tracked=_names(tracked, "--tracked") if tracked else None, u_min=lo, u_max=hi,
              du_max=_limit(du_max, "--du-max"), state_bounds=_ranges(state_bounds, "--state-bound") or None,
              hard_state_bounds=hard_state_bounds, disturbance=None if disturbance == "none" else disturbance,
              codegen=not no_codegen, **weights)
    payload, lines = _design_summary(mpc, out)
    _warn(mpc)
    _emit(as_json, payload, "\n".join(lines))
