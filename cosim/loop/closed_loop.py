"""Closed loop: a controller against the plant FMU at a fixed step, and the same controller against a model.

At every sample ``t_k = t0 + k*dt`` the loop reads the plant's outputs, hands the measured ones to the
controller (``u = controller(t_k, y_k)``), holds ``u`` (zero-order hold) together with the scenario's
disturbance inputs over ``[t_k, t_{k+1})``, and steps the FMU. The controller's compute time is taken around
each call with ``time.perf_counter_ns``; a call longer than ``dt`` is a **deadline miss**. An FMU opened here
drives only the controller's inputs and the disturbance inputs; any other input is left to the FMU after its
start value (:class:`~cosim.plant.fmu_plant.FmuPlant`), listed with it in the record's ``meta["left_inputs"]``.

The same controller, reset, then runs against a model (the identified model, a ``control.StateSpace`` or
the controller's own design model) with the same reference and, where the model has them, the same
disturbance inputs, from the plant's initial outputs. The difference between the two closed loops is the
**model-versus-FMU discrepancy**: what the design model fails to predict about the real loop.

What happens when something goes wrong
---------------------------------------
* The **controller raises** (including a non-finite or wrongly sized output): with
  ``on_controller_error="stop"`` (default) the loop stops; with ``"hold"`` it holds the last input and goes on.
* The **plant fails** (an FMI call returns an error, e.g. a state diverged): the loop stops.
* The controller's own fallbacks (an infeasible MPC problem) are reported by the controller as events.

Either way the result keeps the trajectory up to the last good sample, ``status`` says ``"stopped"``, and
``events`` say what happened and when. Nothing is raised for a failure during the run.

Examples
--------
>>> import control
>>> from cosim import build_fmu
>>> from cosim.loop.closed_loop import closed_loop
>>> from controllers.pid import PID
>>> pid = PID(kp=1.5e4, ki=1.3e4, kd=6.4e3, tf=0.022, b=0.33, dt=1e-3, inputs="Tm", outputs="theta_L",
...           u_min=-5000, u_max=5000)
>>> res = closed_loop(pid, build_fmu(), reference=0.01, duration=3.0, model=None)
>>> res.status, round(float(res.fmu["theta_L"][-1]), 4), res.metrics["overshoot_pct"] < 2.0
('completed', 0.01, True)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from ..data.simulation import open_plant
from ..data.trajectory import Trajectory
from ..errors import ControllerError, CosimError, InvalidSettingError, SimulationTerminated, UnknownVariableError
from ..plant.fmu_plant import FmuPlant
from ..plant.model_description import variable_unit
from ..plant.system_plant import SystemPlant
from .response import jsonable_metrics, response_metrics

__all__ = ["ClosedLoopResult", "ModelPlant", "closed_loop"]

#: Runs longer than this many steps show a progress bar (on a terminal).
_PROGRESS_MIN_STEPS = 200_000
_PROGRESS_EVERY = 8192

ReferenceLike = float | Sequence[float] | np.ndarray | Callable[[np.ndarray], Any]


# ---------------------------------------------------------------------------------------------- the model as a plant
class ModelPlant:
    """A model stepped like an :class:`~cosim.plant.FmuPlant`: ``step(u) -> y`` with named inputs and outputs.

    Parameters
    ----------
    model : IdentifiedModel, control.StateSpace or controllers.base.DesignModel
        A linear model steps exactly (zero-order hold); a nonlinear :class:`~cosim.identify.model.IdentifiedModel`
        steps by RK4 with `nsub` substeps. Model inputs named ``"const"`` are held at 1.
    dt : float
        Step size [s].
    inputs, outputs : sequence of str
        The plant's input and output names: ``step`` takes values for `inputs` and returns `outputs`; an input
        the model lacks is ignored, an output it lacks is NaN.
    x0 : mapping, optional
        Initial state by name (missing states start at 0).
    """

    def __init__(self, model: Any, *, dt: float, inputs: Sequence[str], outputs: Sequence[str],
                 x0: Mapping[str, float] | None = None, nsub: int = 4) -> None:
        from controllers.base import KNOWN_CONSTANT_INPUTS, DesignModel

        from ..identify.model import IdentifiedModel

        self.dt = float(dt)
        self.inputs, self.outputs = tuple(inputs), tuple(outputs)
        self._rhs: Callable[[list[float], list[float]], Any] | None = None
        if isinstance(model, IdentifiedModel) and not model.is_linear:
            self.states, model_inputs, model_outputs = model.states, model.inputs, model.states
            self._rhs, self._nsub = model._point_rhs(), int(nsub)
            c = np.eye(len(self.states))
        else:
            if isinstance(model, IdentifiedModel):
                from ..export import to_statespace

                model = to_statespace(model)
            if not isinstance(model, DesignModel):
                model = DesignModel.from_statespace(model, dt=None if getattr(model, "dt", 0) else dt)
            if not math.isclose(model.dt, dt, rel_tol=1e-9):
                raise InvalidSettingError(f"the model is discrete with dt={model.dt}, the loop runs at dt={dt}")
            self.states, model_inputs, model_outputs = model.states, model.inputs, model.outputs
            self._a, self._b, c = model.A, model.B, model.C
        self._u_map = [(j, self.inputs.index(name)) for j, name in enumerate(model_inputs) if name in self.inputs]
        self._u = np.array([1.0 if name in KNOWN_CONSTANT_INPUTS else 0.0 for name in model_inputs])
        self._y_rows = [model_outputs.index(name) if name in model_outputs else -1 for name in self.outputs]
        self._c = c
        self.missing_inputs = tuple(name for name in self.inputs if name not in model_inputs)
        self._x0 = np.array([float((x0 or {}).get(name, 0.0)) for name in self.states])
        self.x = self._x0.copy()

    def reset(self) -> None:
        self.x = self._x0.copy()

    def read_outputs(self) -> np.ndarray:
        y = self._c @ self.x
        return np.array([y[i] if i >= 0 else math.nan for i in self._y_rows])

    def step(self, u: Sequence[float]) -> np.ndarray:
        for j, i in self._u_map:
            self._u[j] = u[i]
        if self._rhs is None:
            self.x = self._a @ self.x + self._b @ self._u
        else:
            self.x = _rk4(self._rhs, self.x, self._u, self.dt, self._nsub)
        if not np.all(np.isfinite(self.x)):
            raise ControllerError("the model's state diverged in closed loop")
        return self.read_outputs()


def _rk4(rhs: Callable, x: np.ndarray, u: np.ndarray, dt: float, nsub: int) -> np.ndarray:
    h, uu = dt / nsub, list(map(float, u))
    x = x.copy()
    for _ in range(nsub):
        k1 = np.array(rhs(list(x), uu))
        k2 = np.array(rhs(list(x + 0.5 * h * k1), uu))
        k3 = np.array(rhs(list(x + 0.5 * h * k2), uu))
        k4 = np.array(rhs(list(x + h * k3), uu))
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


# ---------------------------------------------------------------------------------------------- the result
@dataclass(frozen=True)
class ClosedLoopResult:
    """What a closed-loop run produced.

    Attributes
    ----------
    fmu : Trajectory
        The loop against the FMU: the reference ``r_<tracked>`` for each tracked output, the plant inputs
        (row k held over ``[t_k, t_{k+1})``; the last row repeats the last input) and the plant outputs.
    model : Trajectory or None
        The same loop against the model (same columns, less the outputs the model does not have), or None.
    compute_time : numpy.ndarray
        Seconds each controller call took in the FMU loop.
    metrics : dict
        Per tracked output (the first one also without prefix): ``rise_time``, ``settling_time``,
        ``overshoot_pct``, ``iae``, ``steady_state_error``, ``final_error_max``, ``peak_error``; and
        ``input_peak`` (max abs input per manipulated input, the first without suffix), ``constraint_violations``
        (samples where an input left the controller's or the FMU's limits, or moved faster than ``du_max``),
        ``deadline_misses`` and ``deadline_miss_rate`` (calls longer than dt), ``solve_time_median_us``,
        ``solve_time_p99_us``, ``solve_time_max_us``, ``realtime_factor`` (simulated / wall seconds of the
        FMU loop), ``model_discrepancy_rms`` and ``model_discrepancy_pct`` (RMS of FMU minus model of the
        tracked output, absolute and as % of the step).
    events : tuple of dict
        ``{"time", "kind", "message"}``: the controller's fallbacks and why the loop stopped, if it did.
    status : str
        ``"completed"`` or ``"stopped"``.
    dt : float
    controller : str
        The controller's kind.
    tracked, inputs, outputs : tuple of str
        The controller's tracked outputs, manipulated inputs and measured outputs.
    notes : tuple of str
        Remarks on the run (model run skipped, an input the model lacks...).
    limits : (numpy.ndarray, numpy.ndarray)
        Lower and upper limit of each manipulated input: the tighter of the controller's and the FMU's.
    """

    fmu: Trajectory
    model: Trajectory | None
    compute_time: np.ndarray
    metrics: dict[str, float]
    events: tuple[dict[str, Any], ...]
    status: str
    dt: float
    controller: str
    tracked: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    notes: tuple[str, ...] = field(default=())
    limits: tuple[np.ndarray, np.ndarray] = field(default=(np.zeros(0), np.zeros(0)))

    @property
    def stopped_at(self) -> float | None:
        """Time of the last good sample when the loop stopped early, else None."""
        return float(self.fmu.time[-1]) if self.status == "stopped" else None

    def solve_time_us(self) -> dict[str, float]:
        """Controller compute time per call in µs: ``{"median", "p99", "max"}``."""
        ct = self.compute_time * 1e6
        if ct.size == 0:
            return {"median": math.nan, "p99": math.nan, "max": math.nan}
        return {"median": float(np.median(ct)), "p99": float(np.percentile(ct, 99)), "max": float(ct.max())}

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (no time series)."""
        return {"status": self.status, "controller": self.controller, "dt": self.dt,
                "duration": float(self.fmu.time[-1] - self.fmu.time[0]), "tracked": list(self.tracked),
                "inputs": list(self.inputs), "outputs": list(self.outputs),
                "metrics": jsonable_metrics(self.metrics), "solve_time_us": jsonable_metrics(self.solve_time_us()),
                "events": list(self.events), "notes": list(self.notes)}


# ---------------------------------------------------------------------------------------------- inputs of the loop
def _signal(value: Any, t: np.ndarray, what: str) -> np.ndarray:
    """A reference or disturbance given as a number, an array (one per sample) or a callable of t."""
    if callable(value):
        try:
            out = np.asarray(value(t), dtype=float)
        except Exception as exc:  # a user's function: say which one failed
            raise InvalidSettingError(f"{what} function failed on the time grid: {exc}") from None
        if out.ndim == 0:
            out = np.full(len(t), float(out))
    else:
        out = np.asarray(value, dtype=float)
        if out.ndim == 0:
            out = np.full(len(t), float(out))
    if out.shape[0] == len(t) - 1:
        out = np.concatenate([out, out[-1:]])
    if out.shape[0] != len(t):
        raise InvalidSettingError(f"{what} has {out.shape[0]} samples, expected {len(t)} (one per time step)")
    if not np.all(np.isfinite(out)):
        raise InvalidSettingError(f"{what} has NaN or infinite values")
    return out


def _references(reference: Any, tracked: Sequence[str], t: np.ndarray) -> np.ndarray:
    if isinstance(reference, Mapping):
        unknown = [k for k in reference if k not in tracked]
        if unknown:
            raise UnknownVariableError(f"reference for {unknown[0]!r}, but the controller tracks {list(tracked)}")
        return np.column_stack([_signal(reference.get(name, 0.0), t, f"reference {name}") for name in tracked])
    return np.column_stack([_signal(reference, t, "reference")] * len(tracked))


def _limits_of(plant: FmuPlant, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = [], []
    for name in names:
        var = plant.variable(name)
        lo.append(float(var.min) if getattr(var, "min", None) not in (None, "") else -math.inf)
        hi.append(float(var.max) if getattr(var, "max", None) not in (None, "") else math.inf)
    return np.array(lo), np.array(hi)


# ---------------------------------------------------------------------------------------------- the loop
def _index(columns: list[int]) -> slice | np.ndarray:
    """A slice for contiguous columns (a view, no fancy indexing), else an index array."""
    if columns and columns == list(range(columns[0], columns[0] + len(columns))):
        return slice(columns[0], columns[0] + len(columns))
    return np.asarray(columns)


def _run(controller: Any, plant: Any, *, n: int, t0: float, dt: float, refs: np.ndarray, u_base: np.ndarray,
         ctrl_cols: list[int], meas_cols: list[int], noise: np.ndarray | None, on_controller_error: str,
         progress: bool | None, desc: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, list[dict]]:
    """Run `n` steps; return outputs, inputs, compute times, the number of steps done and stop events."""
    ny = len(plant.outputs)
    Y = np.full((n + 1, ny), math.nan)
    U = u_base.copy()
    CT = np.zeros(n)
    stops: list[dict[str, Any]] = []
    Y[0] = plant.read_outputs()
    ref_changes = np.ones(n, dtype=bool)
    ref_changes[1:] = np.any(refs[1:n] != refs[:n - 1], axis=1)
    ctrl_idx, meas_idx = _index(ctrl_cols), _index(meas_cols)  # slices where contiguous: cheaper per step
    isfinite, single, first = math.isfinite, len(ctrl_cols) == 1, ctrl_cols[0]
    step, perf = plant.step, time.perf_counter_ns
    hold = on_controller_error == "hold"
    last_u = U[0, ctrl_idx].copy()
    k = held = 0
    disable = (None if n >= _PROGRESS_MIN_STEPS else True) if progress is None else not progress
    bar = tqdm(total=n, unit="step", desc=desc, disable=disable, leave=False)
    try:
        for k in range(n):  # noqa: B007 - k is read after the loop (steps done)
            if ref_changes[k]:
                controller.setpoint = refs[k]
            ym = Y[k, meas_idx]
            if noise is not None:
                ym = ym + noise[k]
            t = t0 + k * dt
            row = U[k]
            c0 = perf()
            try:
                u = controller(t, ym)
                CT[k] = (perf() - c0) * 1e-9
                row[ctrl_idx] = u
                if not (isfinite(row[first]) if single else np.all(np.isfinite(row[ctrl_idx]))):
                    raise ControllerError(f"the controller returned a non-finite input {list(np.ravel(u))}")
            except Exception as exc:  # any controller failure is reported with its time, not raised
                CT[k] = (perf() - c0) * 1e-9
                kind = type(exc).__name__
                if not hold:
                    stops.append({"time": t, "kind": "controller_error",
                                  "message": f"the controller raised {kind} at t={t:.6g} s: {exc}; the loop stopped"})
                    break
                row[ctrl_idx] = last_u
                held += 1
                if held == 1:
                    stops.append({"time": t, "kind": "controller_error",
                                  "message": f"the controller raised {kind} at t={t:.6g} s: {exc}; input held"})
                else:
                    first = stops[-1]["message"].split("; input held")[0]
                    stops[-1]["message"] = f"{first}; input held ({held} calls failed, the last at t={t:.6g} s)"
            last_u = row[ctrl_idx].copy()
            try:
                Y[k + 1] = step(row)
            except SimulationTerminated as exc:  # the FMU ended the run itself: not a failure, the loop stops
                stops.append({"time": exc.time, "kind": "terminated", "message": f"{exc}; the loop stopped"})
                break
            except CosimError as exc:
                stops.append({"time": t, "kind": "plant_error",
                              "message": f"the plant failed at t={t:.6g} s: {exc}; the loop stopped"})
                break
            if k % _PROGRESS_EVERY == 0 and k:
                bar.update(_PROGRESS_EVERY)
        else:
            k = n
    finally:
        bar.close()
    done = k  # steps completed; outputs valid up to row `done`
    return Y[:done + 1], U[:done + 1], CT[:done], done, stops


def closed_loop(controller: Any, plant: FmuPlant | str | Any, *, duration: float,
                reference: ReferenceLike | Mapping[str, ReferenceLike] = 0.0,
                disturbance: Mapping[str, Any] | None = None, parameters: Mapping[str, float] | None = None,
                start: Mapping[str, float] | None = None, model: Any = "design",
                measurement_noise: Mapping[str, float] | None = None, seed: int = 0,
                on_controller_error: str = "stop", t_event: float | None = None, band: float = 0.02,
                band_abs: float | None = None, band_peak: float | None = None,
                progress: bool | None = None, kind: str | None = None) -> ClosedLoopResult:
    """Run `controller` against the plant FMU at the controller's sample time, and against a model.

    Parameters
    ----------
    controller : controllers.base.Controller
        Anything with ``dt``, ``inputs``, ``outputs``, ``tracked``, ``setpoint``, ``reset()`` and
        ``__call__(t, y)``. It is reset before each run.
    plant : FmuPlant or path-like
        An open :class:`FmuPlant` (its step must equal the controller's ``dt``; it is reset with
        `parameters` and `start`; it drives the inputs it was opened with, those nobody in the loop drives held at
        their start values, which a note says), or an FMU file, opened here to drive only the controller's
        inputs and the disturbances, and closed.
    duration : float
        Length of the run [s], rounded to whole steps.
    reference : number, array, callable of t, or mapping by tracked output
        Set-point of the tracked outputs (a callable gets the whole time array).
    disturbance : mapping, optional
        Plant inputs not driven by the controller, by name (number, array or callable of t), e.g. a load
        torque ``{"TL": lambda t: 500.0 * (t >= 1.0)}``. Others are left to the FMU.
    parameters, start : mapping, optional
        FMU parameters (switch effects on: ``{"Fc": 100.0}``) and start values (the initial state).
    model : "design", None, IdentifiedModel, control.StateSpace or DesignModel
        What the same controller also runs against: ``"design"`` (default) the controller's design model when
        it has one; None skips the model run.
    measurement_noise : mapping, optional
        Standard deviation of white noise added to each measured output, by name (seeded by `seed`).
    on_controller_error : {"stop", "hold"}
        What the loop does when the controller raises: stop, or hold the last input and go on.
    t_event, band, band_abs, band_peak : optional
        Passed to :func:`cosim.loop.response.response_metrics` (event time, settling band).
    progress : bool or None
        Progress bar (None: only for long runs on a terminal).
    kind : {"cs", "me"}, optional
        The interface of an FMU opened here (see :class:`~cosim.plant.fmu_plant.FmuPlant`).

    Returns
    -------
    ClosedLoopResult
    """
    if on_controller_error not in ("stop", "hold"):
        raise InvalidSettingError(f"on_controller_error must be 'stop' or 'hold', got {on_controller_error!r}")
    dt = float(controller.dt)
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise InvalidSettingError(f"duration must be a positive number of seconds, got {duration!r}")
    n = max(1, int(round(duration / dt)))
    own = not isinstance(plant, (FmuPlant, SystemPlant))
    fmu = _open(plant, controller, disturbance, dt=dt, parameters=parameters, start=start, kind=kind) if own else plant
    try:
        if not own:
            if not math.isclose(fmu.dt, dt, rel_tol=1e-9):
                raise InvalidSettingError(f"the plant steps at dt={fmu.dt}, the controller at dt={dt}; "
                                          "open the FmuPlant with the controller's dt")
            fmu.reset(parameters=parameters, start=start)
        return _closed_loop(controller, fmu, n=n, reference=reference, disturbance=disturbance, model=model,
                            measurement_noise=measurement_noise, seed=seed, on_controller_error=on_controller_error,
                            t_event=t_event, band=band, band_abs=band_abs, band_peak=band_peak, progress=progress)
    finally:
        if own:
            fmu.close()


def _open(path: Any, controller: Any, disturbance: Mapping[str, Any] | None, **options: Any) -> FmuPlant:
    """The FMU at `path`, driving the controller's inputs and the disturbance inputs only."""
    twice = [name for name in (disturbance or {}) if name in controller.inputs]
    if twice:
        raise InvalidSettingError(f"{twice[0]!r} is driven by the controller; a disturbance goes on another input")
    driven = list(dict.fromkeys([*controller.inputs, *(disturbance or {})]))
    try:
        return open_plant(path, inputs=driven, **options)
    except UnknownVariableError as exc:
        raise UnknownVariableError(f"the loop drives {', '.join(driven)} (the controller's inputs, then the "
                                   f"disturbances): {exc}") from None


def _columns(names: Sequence[str], available: Sequence[str], role: str, where: str) -> list[int]:
    missing = [name for name in names if name not in available]
    if missing:
        raise UnknownVariableError(f"the controller's {role} {missing[0]!r} is not an {role} of {where}; "
                                   f"its {role}s are {list(available)}")
    return [list(available).index(name) for name in names]


def _closed_loop(controller: Any, fmu: FmuPlant, *, n: int, reference: Any, disturbance: Any, model: Any,
                 measurement_noise: Any, seed: int, on_controller_error: str, t_event: float | None, band: float,
                 band_abs: float | None, band_peak: float | None, progress: bool | None) -> ClosedLoopResult:
    dt, t0 = float(controller.dt), fmu.t0
    where = fmu.path.name
    ctrl_cols = _columns(controller.inputs, fmu.inputs, "input", where)
    meas_cols = _columns(controller.outputs, fmu.outputs, "output", where)
    _columns(controller.tracked, fmu.outputs, "output", where)
    t = t0 + dt * np.arange(n + 1)
    refs = _references(reference, controller.tracked, t)
    u_base = np.tile(np.asarray(fmu.get(fmu.inputs), dtype=float), (n + 1, 1))
    for name, value in (disturbance or {}).items():
        if name not in fmu.inputs:
            raise UnknownVariableError(f"disturbance on {name!r}, but {where} has inputs {list(fmu.inputs)}")
        if name in controller.inputs:
            raise InvalidSettingError(f"{name!r} is driven by the controller; a disturbance goes on another input")
        u_base[:, fmu.inputs.index(name)] = _signal(value, t, f"disturbance {name}")
    noise = None
    if measurement_noise:
        unknown = [k for k in measurement_noise if k not in controller.outputs]
        if unknown:
            raise UnknownVariableError(f"measurement noise on {unknown[0]!r}, which the controller does not "
                                       f"measure ({list(controller.outputs)})")
        std = np.array([float(measurement_noise.get(name, 0.0)) for name in controller.outputs])
        noise = np.random.default_rng(seed).standard_normal((n, len(std))) * std
    x0 = dict(zip(fmu.outputs, fmu.read_outputs().tolist(), strict=True))
    notes: list[str] = []
    undriven = [name for name in fmu.inputs if name not in controller.inputs and name not in (disturbance or {})]
    if undriven:  # an open plant that drives inputs nobody in the loop drives
        notes.append(f"the FmuPlant drives {', '.join(undriven)}, which nobody in the loop drives: held at "
                     f"{', '.join(f'{u_base[0, fmu.inputs.index(n)]:g}' for n in undriven)}; open it with "
                     f"inputs={list(dict.fromkeys([*controller.inputs, *(disturbance or {})]))} to leave them "
                     "to the FMU")
    left = dict(zip(fmu.left_inputs, fmu.get(fmu.left_inputs), strict=True))

    controller.reset()
    wall = time.perf_counter()
    Y, U, CT, done, stops = _run(controller, fmu, n=n, t0=t0, dt=dt, refs=refs, u_base=u_base, ctrl_cols=ctrl_cols,
                                 meas_cols=meas_cols, noise=noise, on_controller_error=on_controller_error,
                                 progress=progress, desc=f"closed loop {fmu.path.stem}")
    wall = time.perf_counter() - wall
    U[-1, ctrl_cols] = U[-2, ctrl_cols] if len(U) > 1 else U[-1, ctrl_cols]
    events = [e.to_dict() for e in getattr(controller, "events", [])] + stops
    status = "completed" if done == n else "stopped"
    units = _units(fmu)
    fmu_traj = _trajectory(t[:done + 1], refs[:done + 1], U, Y, controller, fmu.inputs, fmu.outputs,
                           {"source": "closed_loop", "plant": where, "left_inputs": left}, units)

    model_traj = None
    design = getattr(controller, "design_model", None) if isinstance(model, str) and model == "design" else model
    if isinstance(model, str) and model != "design":
        raise InvalidSettingError(f"model must be 'design', None or a model object, got {model!r}")
    if design is not None:
        try:
            mplant = ModelPlant(design, dt=dt, inputs=fmu.inputs, outputs=fmu.outputs, x0=x0)
        except CosimError as exc:
            notes.append(f"no model run: {exc}")
        else:
            if any(np.isnan(mplant.read_outputs()[meas_cols])):
                notes.append("no model run: the model lacks a measured output of the controller")
            else:
                if mplant.missing_inputs:
                    notes.append(f"the model has no input {', '.join(mplant.missing_inputs)}: not applied to it")
                controller.reset()
                Ym, Um, _, mdone, mstops = _run(controller, mplant, n=done, t0=t0, dt=dt, refs=refs,
                                                u_base=u_base[:done + 1], ctrl_cols=ctrl_cols, meas_cols=meas_cols,
                                                noise=noise, on_controller_error=on_controller_error,
                                                progress=progress, desc="closed loop model")
                if len(Um) > 1:
                    Um[-1, ctrl_cols] = Um[-2, ctrl_cols]
                notes += [f"model run: {e['message']}" for e in mstops]
                model_traj = _trajectory(t[:mdone + 1], refs[:mdone + 1], Um, Ym, controller, fmu.inputs,
                                         fmu.outputs, {"source": "closed_loop", "plant": "model"}, units)
    controller.reset()
    lo, hi = _limits_of(fmu, controller.inputs)
    lo = np.maximum(np.asarray(controller.u_min, dtype=float), lo)
    hi = np.minimum(np.asarray(controller.u_max, dtype=float), hi)
    metrics = _metrics(controller, fmu_traj, model_traj, CT, dt, wall, t_event=t_event, band=band,
                       band_abs=band_abs, band_peak=band_peak, limits=(lo, hi))
    return ClosedLoopResult(fmu=fmu_traj, model=model_traj, compute_time=CT, metrics=metrics, events=tuple(events),
                            status=status, dt=dt, controller=getattr(controller, "kind", type(controller).__name__),
                            tracked=tuple(controller.tracked), inputs=tuple(controller.inputs),
                            outputs=tuple(controller.outputs), notes=tuple(notes), limits=(lo, hi))


def _units(fmu: Any) -> dict[str, str]:
    """The unit of each of the plant's variables that declares one (its own or its type's)."""
    units = {}
    for name, var in getattr(fmu, "variables", {}).items():
        unit = variable_unit(var)
        if unit:
            units[name] = unit
    return units


def _trajectory(t: np.ndarray, refs: np.ndarray, U: np.ndarray, Y: np.ndarray, controller: Any,
                inputs: Sequence[str], outputs: Sequence[str], meta: dict[str, Any],
                units: Mapping[str, str]) -> Trajectory:
    signals: dict[str, np.ndarray] = {f"r_{name}": refs[:, j] for j, name in enumerate(controller.tracked)}
    roles = {f"r_{name}": "reference" for name in controller.tracked}
    for j, name in enumerate(inputs):
        signals[name] = U[:, j]
        roles[name] = "input"
    for j, name in enumerate(outputs):
        if np.all(np.isnan(Y[:, j])):
            continue  # an output the model does not have
        signals[name] = Y[:, j]
        roles[name] = "output"
    units = {**{f"r_{name}": units[name] for name in controller.tracked if name in units}, **units}
    return Trajectory.from_arrays(t, signals, units={k: v for k, v in units.items() if k in signals}, roles=roles,
                                  meta=meta)


def _metrics(controller: Any, traj: Trajectory, model_traj: Trajectory | None, ct: np.ndarray, dt: float,
             wall: float, *, t_event: float | None, band: float, band_abs: float | None, band_peak: float | None,
             limits: tuple[np.ndarray, np.ndarray]) -> dict[str, float]:
    t = traj.time
    metrics: dict[str, float] = {}
    for j, name in enumerate(controller.tracked):
        m = response_metrics(t, traj[name], traj[f"r_{name}"], t_event=t_event, band=band, band_abs=band_abs,
                             band_peak=band_peak)
        if model_traj is not None and len(model_traj) > 1:
            k = min(len(model_traj), len(traj))
            diff = traj[name][:k] - model_traj[name][:k]
            rms = float(np.sqrt(np.mean(diff ** 2)))
            m["model_discrepancy_rms"] = rms
            scale = abs(m["step"]) if m["step"] and math.isfinite(m["step"]) else float(np.ptp(traj[name][:k]))
            m["model_discrepancy_pct"] = 100.0 * rms / scale if scale > 0 else math.nan
        for key, value in m.items():
            metrics[f"{name}.{key}"] = value
            if j == 0:
                metrics[key] = value
    u = np.column_stack([traj[name] for name in controller.inputs])
    u_run = u[:-1] if len(u) > 1 else u
    lo, hi = limits
    tol = 1e-9 * np.maximum(1.0, np.maximum(np.abs(np.nan_to_num(lo, posinf=0, neginf=0)),
                                            np.abs(np.nan_to_num(hi, posinf=0, neginf=0))))
    bad = np.any((u_run < lo - tol) | (u_run > hi + tol), axis=1)
    du_max = np.asarray(getattr(controller, "du_max", np.full(u.shape[1], math.inf)), dtype=float)
    if len(u_run) > 1 and np.any(np.isfinite(du_max)):
        bad[1:] |= np.any(np.abs(np.diff(u_run, axis=0)) > du_max * (1 + 1e-9) + tol, axis=1)
    metrics["constraint_violations"] = float(np.count_nonzero(bad))
    for j, name in enumerate(controller.inputs):
        peak = float(np.max(np.abs(u_run[:, j]))) if len(u_run) else math.nan
        metrics[f"{name}.input_peak"] = peak
        if j == 0:
            metrics["input_peak"] = peak
    metrics["deadline_misses"] = float(np.count_nonzero(ct > dt))
    metrics["deadline_miss_rate"] = float(np.mean(ct > dt)) if ct.size else 0.0
    if ct.size:
        us = ct * 1e6
        metrics["solve_time_median_us"] = float(np.median(us))
        metrics["solve_time_p99_us"] = float(np.percentile(us, 99))
        metrics["solve_time_max_us"] = float(us.max())
    metrics["realtime_factor"] = float(ct.size * dt / wall) if wall > 0 else math.nan
    return metrics
