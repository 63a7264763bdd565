"""One call for the common case: run an FMU with given input signals and get a :class:`Trajectory`.

Inputs are sampled at the communication points ``t_k = t0 + k*dt`` and held over the step (zero-order hold).
Row k of an input column in the result is the value held from ``t_k`` to ``t_{k+1}``; row k of an output
column is the output at ``t_k``.

Only the inputs given are driven, and only they are recorded as input columns; an input nobody drives is left to
the FMU after its start value, as FMPy leaves it (see :class:`~cosim.plant.fmu_plant.FmuPlant`), and listed with
that value in ``meta["left_inputs"]``. Replaying a record (``cosim simulate --input-file``) so drives exactly
what the first run drove.

Examples
--------
>>> from cosim import simulate, build_fmu, signals
>>> traj = simulate(build_fmu(), {"Tm": signals.square(500.0, 2.0)}, duration=1.0, dt=1e-3)
>>> len(traj), traj.states
(1001, ('theta_m', 'omega_m', 'theta_L', 'omega_L'))
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidSettingError, SimulationTerminated
from ..numbers import WrittenNumber, check_memory
from ..plant._variables import kind_of
from ..plant.fmu_plant import FmuPlant
from ..plant.model_description import variable_unit
from ..plant.system_plant import SystemPlant
from ..plant.system_structure import is_system_file
from .signals import Signal, parse_signal
from .trajectory import Trajectory

__all__ = ["HOLDS", "InputSpec", "open_plant", "recorded_inputs", "sample_input", "simulate"]

#: What an input can be given as: a Signal (or any callable of time), a constant, samples at the
#: communication points, or a signal spec string such as ``"square:amp=500,freq=2"``.
InputSpec = Signal | Callable[[np.ndarray], Any] | float | np.ndarray | str

_PROGRESS_MIN_STEPS = 200_000  # below this a run takes well under a second: no bar
_CHUNK = 4096


def steps_for(duration: float, dt: float) -> int:
    """Number of steps of `dt` in `duration`, which must be a whole number of them."""
    for name, value in (("duration", duration), ("dt", dt)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise InvalidSettingError(f"{name} must be a positive number of seconds, got {value!r}")
    n = round(duration / dt)
    if n < 1 or abs(n * dt - duration) > 1e-9 * max(1.0, duration):
        raise InvalidSettingError(f"duration {duration:g} s is not a whole number of steps of dt={dt:g} s; "
                                  f"choose duration = n*dt (e.g. {max(n, 1) * dt:.9g} s)")
    return n


def sample_input(name: str, spec: InputSpec, t: np.ndarray, *, maximum: float | None = None) -> np.ndarray:
    """Sample one input at the times `t` (zero-order hold between them).

    Parameters
    ----------
    name : str
        The input's name (for messages).
    spec : Signal, callable, float, array or str
        See :data:`InputSpec`. An array must hold one value per time in `t` (or one fewer: the last is held).
    t : numpy.ndarray
        Sample times.
    maximum : float, optional
        The input's declared maximum, the reference of ``amp=`` fractions in string specs.

    Examples
    --------
    >>> import numpy as np
    >>> sample_input("Tm", "step:value=2,at=0.5", np.array([0.0, 0.5, 1.0])).tolist()
    [0.0, 2.0, 2.0]
    """
    if isinstance(spec, str):
        spec = parse_signal(spec, maximum=maximum)
    if callable(spec):
        values = np.asarray(spec(t), dtype=float)
        if values.ndim == 0:
            values = np.full(t.shape, float(values))
    elif np.ndim(spec) == 0:
        values = np.full(t.shape, float(spec))
    else:
        values = np.asarray(spec, dtype=float).ravel()
        if values.shape[0] == t.shape[0] - 1:
            values = np.append(values, values[-1])
        if values.shape[0] != t.shape[0]:
            raise InvalidSettingError(f"input {name} has {values.shape[0]} samples, expected {t.shape[0] - 1} "
                                      f"(one per step) or {t.shape[0]}")
    if values.shape != t.shape:
        raise InvalidSettingError(f"input {name} gave {values.shape} values for {t.shape[0]} sample times")
    if not np.all(np.isfinite(values)):
        bad = int(np.argmax(~np.isfinite(values)))
        raise InvalidSettingError(f"input {name} is not finite at t={t[bad]:.9g} s; inputs must be finite")
    return values


def open_plant(path: str | os.PathLike, *, kind: str | None = None, solver: str = "cvode",
               t0: float | None = None, master: Mapping[str, Any] | None = None,
               **options: Any) -> FmuPlant | SystemPlant:
    """An FMU as :class:`~cosim.plant.fmu_plant.FmuPlant`, or a system of FMUs (``.ssp``, ``.ssd``, an OSP
    ``...SystemStructure.xml``) as :class:`~cosim.plant.system_plant.SystemPlant`, with the same options; `master`:
    the system master's (``algorithm``, ``extrapolation``, ``step_multiples``...), refused for one FMU."""
    if is_system_file(path):
        if kind not in (None, "cs"):
            raise InvalidSettingError(f"kind={kind!r} is for one FMU; a system's components say their own interface")
        return SystemPlant(path, solver=solver, t0=0.0 if t0 is None else t0, **(master or {}), **options)
    if master:
        raise InvalidSettingError(f"{', '.join(master)}: options of a system's master; {Path(path).name} is one FMU")
    return FmuPlant(path, kind=kind, solver=solver, t0=t0, **options)


def _written(plant: FmuPlant | SystemPlant, values: Mapping[str, Any] | None) -> dict[str, Any]:
    """Start values as the record's meta keeps them (JSON): a Binary's bytes as their hex digits, a number read from
    text (:class:`~cosim.numbers.WrittenNumber`) as that text where the variable takes text."""
    out = {}
    for name, value in (values or {}).items():
        kind = kind_of(plant.variable(name).type)
        if isinstance(value, (bytes, bytearray)):
            value = bytes(value).hex()
        elif isinstance(value, WrittenNumber) and kind in ("string", "binary"):
            value = value.text
        out[name] = value
    return out


HOLDS = ("zoh", "linear")


def recorded_inputs(record: Trajectory, names: Sequence[str], t: np.ndarray, *, hold: str = "zoh"
                    ) -> dict[str, np.ndarray]:
    """Inputs `names` of a recorded trajectory sampled at the times `t`, for :func:`simulate`.

    ``hold="zoh"`` holds each recorded value until the next recorded time (cosim's convention for inputs, so
    that a trajectory :func:`simulate` wrote drives the FMU again exactly); ``"linear"`` interpolates between
    recorded samples. Times outside the record are refused.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.data.trajectory import Trajectory
    >>> rec = Trajectory.from_arrays([0.0, 1.0, 2.0], {"u": [0.0, 1.0, 3.0]}, roles={"u": "input"})
    >>> recorded_inputs(rec, ["u"], np.array([0.0, 0.5, 1.5]))["u"].tolist()
    [0.0, 0.0, 1.0]
    >>> recorded_inputs(rec, ["u"], np.array([0.5, 1.5]), hold="linear")["u"].tolist()
    [0.5, 2.0]
    """
    if hold not in HOLDS:
        raise InvalidSettingError(f"hold={hold!r}; choose one of {', '.join(HOLDS)}")
    time = record.time
    span = 1e-9 * (float(np.median(np.diff(time))) if len(time) > 1 else 1.0)
    if t[0] < time[0] - span or t[-1] > time[-1] + span:
        raise InvalidSettingError(f"the run ({t[0]:.9g} to {t[-1]:.9g} s) reaches outside the recorded inputs "
                                  f"({time[0]:.9g} to {time[-1]:.9g} s); shorten --duration")
    if hold == "zoh":
        index = np.clip(np.searchsorted(time, t + span, side="right") - 1, 0, len(time) - 1)
        return {name: np.asarray(record[name], dtype=float)[index] for name in names}
    return {name: np.interp(t, time, np.asarray(record[name], dtype=float)) for name in names}


def simulate(
    fmu: str | os.PathLike,
    inputs: Mapping[str, InputSpec] | None = None,
    *,
    duration: float,
    dt: float,
    parameters: Mapping[str, float] | None = None,
    start: Mapping[str, float] | None = None,
    t0: float | None = None,
    outputs: list[str] | str | None = None,
    progress: bool | None = None,
    kind: str | None = None,
    solver: str = "cvode",
    master: Mapping[str, Any] | None = None,
) -> Trajectory:
    """Simulate a co-simulation FMU at a fixed step and return its trajectory.

    Parameters
    ----------
    fmu : path-like
        The FMU (FMI 2.0 or 3.0), or a system of FMUs (``.ssp``, ``SystemStructure.ssd``,
        ``OspSystemStructure.xml``: :class:`~cosim.plant.system_plant.SystemPlant`, its names
        ``component.variable``).
    inputs : mapping, optional
        Input name -> :data:`InputSpec`: the inputs driven. An input not named is left to the FMU: its start value
        (the FMU's, or one given in `start`) is set once and never again.
    duration, dt : float
        Length of the run and communication step, in seconds; `duration` is a whole number of steps.
    parameters, start : mapping, optional
        Parameter values and start values by name (see :class:`FmuPlant`).
    t0 : float, optional
        Start time (default: the FMU's DefaultExperiment startTime, else 0).
    outputs : list of str or "all", optional
        Variables to record (default: the FMU's outputs). Any numeric variable may be named: an output, a
        state or local variable the FMU does not declare as an output (``"mass.s"``), a parameter; ``"all"``
        records every one of them.
    kind : {"cs", "me"}, optional
        The FMU's interface: co-simulation, or Model Exchange integrated by FMPy's solvers (default: co-simulation
        when the FMU has it, else Model Exchange).
    solver : {"cvode", "euler"}
        The solver of a Model Exchange FMU (FMPy's CVode, or forward Euler at the FMU's default step).
    master : mapping, optional
        A system's master options (:class:`~cosim.plant.system_plant.SystemPlant`: ``algorithm``,
        ``extrapolation``, ``step_multiples``, ``hold_discrete``, ``engine``).
    progress : bool or None, default None
        Progress bar on stderr. None shows it for long runs (200,000 steps or more) and only when stderr is
        a terminal; True shows it anyway, False hides it.

    Returns
    -------
    Trajectory
        Time ``t0 + k*dt`` for k = 0..n, the inputs driven (role ``input``, in modelDescription order), the
        outputs (role ``state`` when the FMU declares them as states, else ``output``); ``meta`` holds the FMU,
        dt, parameters and start values, the inputs left to the FMU with their values at the start
        (``left_inputs``),
        the FMI type of every integer or Boolean column (``types``: written as whole numbers), and ``status``:
        ``"completed"``, or ``"terminated"`` when the FMU ended the simulation itself (Stair at 9 s): the record
        then stops at that time, its last row read there, and ``meta["terminated"]`` holds the time and the
        FMU's last message.

    Examples
    --------
    >>> from cosim import simulate, build_fmu
    >>> traj = simulate(build_fmu(), {"Tm": 1000.0}, duration=0.5, dt=1e-3, parameters={"KL": 1e6})
    >>> bool(traj["omega_m"][-1] > 0)
    True
    """
    n = steps_for(duration, dt)
    inputs = dict(inputs or {})
    # the time, inputs and outputs, and a copy of them in the Trajectory: refused before the FMU loads
    named = len(outputs) if isinstance(outputs, (list, tuple)) else 0
    check_memory(2.0 * (n + 1) * (1 + len(inputs) + named + 1), what=f"a simulation of {n + 1:,} "
                 f"samples ({duration:g} s at dt={dt:g} s)", hint="use a larger dt or a shorter duration")
    with open_plant(fmu, dt=dt, parameters=parameters, start=start, t0=t0, inputs=list(inputs), outputs=outputs,
                    kind=kind, solver=solver, master=master) as plant:
        check_memory(2.0 * (n + 1) * (1 + len(plant.inputs) + len(plant.outputs)),
                     what=f"a simulation of {n + 1:,} samples of {len(plant.inputs) + len(plant.outputs)} signals",
                     hint="use a larger dt, a shorter duration or fewer outputs")
        t0 = plant.t0
        t = t0 + dt * np.arange(n + 1)
        u = np.empty((n + 1, len(plant.inputs)))
        for j, name in enumerate(plant.inputs):
            var = plant.variable(name)
            maximum = float(var.max) if getattr(var, "max", None) not in (None, "") else None
            u[:, j] = sample_input(name, inputs[name], t, maximum=maximum)
        left = dict(zip(plant.left_inputs, plant.get(plant.left_inputs), strict=True))
        y = np.empty((n + 1, len(plant.outputs)))
        if plant.inputs:
            plant.set_inputs(u[0])  # the first row's outputs with the first row's inputs (direct feedthrough)
        y[0] = plant.read_outputs()
        from tqdm.auto import tqdm  # tqdm.auto costs tens of ms to import (asyncio): only when simulating

        # disable=None lets tqdm show the bar only on a terminal
        disable = (None if n >= _PROGRESS_MIN_STEPS else True) if progress is None else not progress
        ended = None
        with tqdm(total=n, unit="step", desc=f"simulate {plant.path.stem}", disable=disable, leave=False) as bar:
            for first in range(0, n, _CHUNK):
                last = min(first + _CHUNK, n)
                try:
                    y[first + 1:last + 1] = plant.run(u[first:last])
                except SimulationTerminated as exc:  # the FMU ended the run: keep everything up to its end
                    ended, k = exc, first + len(exc.completed)
                    y[first + 1:k + 1] = exc.completed
                    y[k + 1] = exc.outputs
                    t, u, y = t[:k + 2].copy(), u[:k + 2], y[:k + 2]
                    t[-1] = exc.time
                    break
                bar.update(last - first)
        driven = [name for name in plant.declared_inputs if name in inputs]  # modelDescription order
        u = u[:, [plant.inputs.index(name) for name in driven]]
        names = driven + list(plant.outputs)
        roles = {name: "input" for name in driven}
        roles.update({name: "state" if name in plant.states else "output" for name in plant.outputs})
        types = plant.types
        units = {name: variable_unit(plant.variable(name)) for name in names}
        meta = {
            "source": "system" if plant.kind == "system" else "fmu",
            "fmu": plant.path.name,
            "model": plant.model_description.modelName,
            "fmi_version": plant.fmi_version,
            "kind": plant.kind,
            **({"master": {"algorithm": plant.algorithm, "extrapolation": plant.extrapolation,
                           "engine": plant.engine}} if plant.kind == "system" else {}),
            **({"solver": plant.solver} if plant.kind == "me" else {}),
            "dt": dt,
            "t0": t0,
            "intersample": "zoh",
            "parameters": plant.parameters,
            "start": _written(plant, start),
            "inputs": {name: str(spec) if not isinstance(spec, np.ndarray) else "samples"
                       for name, spec in inputs.items()},
            "left_inputs": left,
            "status": "completed" if ended is None else "terminated",
        }
        if types:
            meta["types"] = types  # integer and Boolean columns: written as whole numbers
        if ended is not None:
            meta["terminated"] = {"time": ended.time, "message": ended.message}
    data = dict(zip(names, np.hstack([u, y]).T, strict=True))
    return Trajectory.from_arrays(t, data, units=units, roles=roles, meta=meta)
