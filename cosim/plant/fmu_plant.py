"""An FMU as a plant: `FmuPlant`, stepped from Python at full speed.

`FmuPlant` wraps any FMI 2.0 or 3.0 FMU (the bundled two-mass servo, or one exported by OpenModelica, Dymola,
Simulink, pythonfmu...): co-simulation, or Model Exchange integrated by FMPy's CVode or Euler
(:mod:`cosim.plant.model_exchange`, ``kind="me"``). It reads the FMU's modelDescription.xml to discover inputs,
outputs and parameters, of every numeric type and FMI 3 arrays element by element (:mod:`cosim.plant._variables`),
instantiates the FMU with FMPy, and then drives a co-simulation FMU's 64-bit float signals through ctypes
function pointers bound once (:mod:`cosim.plant._stepping`), so that :meth:`FmuPlant.step` costs three FMI calls
and nothing else.

Why not FMPy's ``FMU2Slave.setReal/doStep/getReal`` in the loop: each of those builds new ctypes arrays and
goes through a generic wrapper on every call, which costs more than the model itself for small plants. FMPy
is still used for everything it does well (reading the model description, extracting, loading the library,
instantiating); only the three calls of the hot path are bound here.

Time is ``t0 + k*dt`` (never accumulated); step k goes from ``t0 + k*dt`` to exactly ``t0 + (k+1)*dt`` (its
length is their difference, as FMPy computes it) and the input passed to :meth:`FmuPlant.step` is held constant
over the step (zero-order hold).

The FMU file is checked and its model description read by :func:`~cosim.plant.model_description.open_model_description`;
values are set and read by type in :mod:`cosim.plant._fmi_calls`, and FMI 2.0 messages arrive through
:mod:`cosim.plant._fmi_callbacks`.

Examples
--------
>>> from cosim import FmuPlant, build_fmu
>>> with FmuPlant(build_fmu(), dt=1e-3, parameters={"Fc": 0.0}) as plant:
...     y = plant.step([100.0, 0.0])          # Tm = 100 N m, TL = 0
...     plant.outputs
('theta_m', 'omega_m', 'theta_L', 'omega_L')
"""

from __future__ import annotations

import collections
import logging
import math
import os
import shutil
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import (
    FmiCallError,
    FmuPlatformError,
    InvalidSettingError,
    SimulationTerminated,
    UnknownVariableError,
)
from ._fmi_callbacks import fmi2_callbacks
from ._fmi_calls import REAL_TYPES, coerce, read_value, status_name, write_value
from ._fmu_description import _close_matches
from ._stepping import _input_value, _Stepping
from ._variables import NUMERIC, Signal, array_value, expand_signals, unknown_element
from .model_description import interface_kind, open_model_description, parameter_names
from .model_exchange import ModelExchangeSlave

__all__ = ["FmuPlant"]

_log = logging.getLogger("cosim.fmu")
# FMPy loads an FMU's library with os.chdir into its binaries folder and back (fmpy.fmi1._FMU.__init__, for
# Windows' dependent DLLs), and the directory is the process's: two plants loading at once in threads of one
# process (a Dask worker's, a thread pool's) left it in the other's temporary folder, deleted when that plant
# closed, and every relative path failed after ("No such file or directory"). Loads take this lock in turn.
_LIBRARY_LOAD = threading.Lock()


class FmuPlant(_Stepping):
    """An FMU driven at a fixed communication step: co-simulation, or Model Exchange integrated by FMPy's solvers.

    Parameters
    ----------
    fmu : path-like
        The ``.fmu`` file (FMI 2.0 or 3.0, co-simulation or Model Exchange, with a binary for this platform).
    dt : float, optional
        Communication step size in seconds. Defaults to the FMU's DefaultExperiment stepSize.
    parameters : mapping, optional
        Parameter values by name, applied before initialisation.
    start : mapping, optional
        Start values by name (for instance the initial states ``{"theta_m": -2.0}``), applied before
        initialisation. Any variable with a start value can be set.
    t0 : float, optional
        Start time. Default: the FMU's DefaultExperiment startTime, else 0.
    inputs, outputs : sequence of str, optional
        The inputs driven by :meth:`step`, and the variables it returns, in this order: numbers of any FMI type
        (Float32/64, integers, Booleans and Enumerations, passed as floats) and FMI 3 array elements by name
        (``u[1]``, ``A[1,2]``, row-major, from 1). Default: every numeric input and output, in modelDescription
        order. `outputs` may also name states and local variables, or be ``"all"``. An input not driven is left
        to the FMU (:attr:`left_inputs`): its start value, the FMU's or the one given in `start`, is set once at
        initialisation and never again, as FMPy leaves an input it is not given. (An FMU may route two inputs to
        one variable, as Dymola exports ``extForce`` beside ``force.f``: setting the one nobody drives would
        override the other.) The exception is an element of a partly driven FMI 3 array, which is rewritten
        with its start value at each step, as FMI sets an array whole.
    instance_name : str
        Name of the FMU instance (appears in the FMU's log messages).
    kind : {"cs", "me"}, optional
        The interface: co-simulation (the FMU integrates itself) or Model Exchange (integrated here by FMPy's
        solvers, :class:`~cosim.plant.model_exchange.ModelExchangeSlave`, with time, state and step events).
        Default: co-simulation when the FMU has it, else Model Exchange. Read back as :attr:`kind`.
    solver : {"cvode", "euler"}
        Model Exchange only: FMPy's CVode, or forward Euler at the DefaultExperiment stepSize (else `dt`).
    relative_tolerance : float, optional
        Model Exchange with CVode: its relative tolerance (default: the DefaultExperiment's, else 1e-5).
    initialize : bool
        False leaves the FMU in Initialization Mode (a master's consistent start): :meth:`exit_initialization`.

    Notes
    -----
    The instance always terminates and frees itself in :meth:`close`, called by ``with`` also on error.
    An FMU that ends the simulation itself (Stair at 9 s) makes :meth:`step` raise
    :class:`~cosim.errors.SimulationTerminated` with the time, its message and the outputs then;
    :func:`cosim.simulate` keeps the record up to that time.
    The FMU's log messages go to the Python logger ``cosim.fmu``; the last ones are attached to the
    error when an FMI call fails.

    Examples
    --------
    >>> from cosim import FmuPlant, build_fmu
    >>> with FmuPlant(build_fmu(), dt=0.01, start={"omega_L": 1.0}) as plant:
    ...     for _ in range(100):
    ...         y = plant.step([0.0, 0.0])
    ...     round(plant.time, 6), bool(y[3] > 0)
    (1.0, True)
    """

    def __init__(
        self,
        fmu: str | os.PathLike,
        *,
        dt: float | None = None,
        parameters: Mapping[str, float] | None = None,
        start: Mapping[str, float] | None = None,
        t0: float | None = None,
        inputs: Sequence[str] | None = None,
        outputs: Sequence[str] | None = None,
        instance_name: str = "cosim",
        kind: str | None = None,
        solver: str = "cvode",
        relative_tolerance: float | None = None,
        initialize: bool = True,
    ) -> None:
        self.path = Path(fmu).absolute()  # FMPy changes the process's directory while it loads a library (below)
        self._fmu = None
        self._unzipdir: str | None = None
        self._initialized = False
        self._messages: collections.deque[str] = collections.deque(maxlen=8)
        md = open_model_description(self.path, kind)
        self.model_description = md
        self.kind = interface_kind(md, kind)
        if str(solver).lower() not in ("cvode", "euler"):
            raise InvalidSettingError(f"solver={solver!r}; choose cvode or euler (FMPy's solvers for Model Exchange)")
        self.solver = "CVode" if str(solver).lower() == "cvode" else "Euler"
        self._relative_tolerance = relative_tolerance
        self.fmi_version = "2.0" if md.fmiVersion == "2.0" else "3.0"
        self._vars = {v.name: v for v in md.modelVariables}
        # every value by name, FMI 3 arrays element by element (A[1,2]); only numbers are driven and recorded
        self._signals = expand_signals(md.modelVariables)
        numeric = [s for s in self._signals.values() if s.kind in NUMERIC and not (s.shape and s.offset is None)]
        all_in = [s.name for s in numeric if s.var.causality == "input"]
        all_out = [s.name for s in numeric if s.var.causality == "output"]
        # anything else a user may record: a state or local (Modelica tools often expose a plant's position only
        # as `mass.s`), a calculated parameter... every number but time and the inputs
        recordable = [s.name for s in numeric if s.var.causality not in ("independent", "input")]
        self.declared_inputs = tuple(all_in)  # every numeric input, driven or not, in modelDescription order
        self.inputs = tuple(self._choose(inputs, all_in, "input"))
        self.outputs = tuple(recordable if outputs == "all" else all_out if outputs is None
                             else self._choose(outputs, recordable, "variable"))
        self._param_names = tuple(parameter_names(md))
        derivative_of = {}
        for v in md.modelVariables:
            if getattr(v, "derivative", None) is not None:
                derivative_of[v.derivative.name] = v.name
        self.states = tuple(name for name in self.outputs if self._signals[name].var.name in derivative_of)
        if dt is None:
            default = md.defaultExperiment
            dt = float(default.stepSize) if default is not None and default.stepSize else None
            if dt is None:
                raise InvalidSettingError(f"{self.path.name} declares no default step size; pass dt=...")
        self._dt = self._check_dt(dt)
        if t0 is None:  # the FMU's DefaultExperiment startTime, as FMPy and the exporting tools start
            default = md.defaultExperiment
            t0 = float(default.startTime) if default is not None and default.startTime not in (None, "") else 0.0
        if not math.isfinite(t0):
            raise InvalidSettingError(f"t0 must be a finite number, got {t0}")
        self._t0 = float(t0)
        self._counter = [0]  # steps taken since t0, shared with the bound step function
        self._ended_at: float | None = None  # when the FMU ended the simulation itself
        self._settings: dict[str, Any] = {}
        self._stage(parameters or {}, only_parameters=True)
        self._stage(start or {}, only_parameters=False)
        try:
            self._load(instance_name)
            self._initialize(finish=initialize)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ discovery and settings
    def check_names(self, names: Sequence[str], role: str = "input") -> None:
        """Refuse, in one line, a name that is not one of :attr:`inputs` (``role="input"``) or :attr:`outputs`:
        unknown (with the nearest names), not a number (a String), a whole array, an element out of range."""
        self._choose(names, list(self.inputs if role == "input" else self.outputs), role)

    def _choose(self, chosen: Sequence[str] | None, available: list[str], role: str) -> list[str]:
        if chosen is None:
            return available
        chosen = [chosen] if isinstance(chosen, str) else list(chosen)
        for name in chosen:
            if name in available:
                continue
            signal = self._signals.get(name)
            if signal is not None and signal.kind not in NUMERIC:
                raise InvalidSettingError(f"{name} of {self.path.name} is a {signal.var.type} variable: only "
                                          f"numbers can be {'driven' if role == 'input' else 'recorded'}; "
                                          f"set it before the run with start={{{name!r}: ...}} (--start)")
            if signal is not None and signal.shape and signal.offset is None:
                raise InvalidSettingError(f"{name} of {self.path.name} is an array: name its elements, "
                                          f"{name}[1]... (indices from 1)")
            raise unknown_element(name, self._signals) or UnknownVariableError(
                f"{self.path.name} has no {role} named {name!r}." + _close_matches(name, available))
        return chosen

    @staticmethod
    def _check_dt(dt: float) -> float:
        try:
            dt = float(dt)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"the step size must be a number, got {dt!r}") from None
        if not (math.isfinite(dt) and dt > 0):
            raise InvalidSettingError(f"the step size must be positive and finite, got dt={dt}; pass e.g. dt=1e-3")
        return dt

    def _variable(self, name: str):
        var = self._vars.get(name)
        if var is None:
            raise UnknownVariableError(f"{self.path.name} has no variable named {name!r}."
                                       + _close_matches(name, self._vars))
        return var

    def _signal(self, name: str) -> Signal:
        signal = self._signals.get(name)
        if signal is None:
            raise unknown_element(name, self._signals) or UnknownVariableError(
                f"{self.path.name} has no variable named {name!r}." + _close_matches(name, self._vars))
        return signal

    def _stage(self, values: Mapping[str, Any], *, only_parameters: bool) -> None:
        """Validate values by name (a variable, a whole array, an array element) and keep them to apply at
        (re-)initialisation."""
        for name, value in values.items():
            signal = self._signal(name)
            var = signal.var
            if only_parameters and var.name not in self._param_names:
                raise UnknownVariableError(
                    f"{name!r} is not a parameter of {self.path.name} (its causality is {var.causality}); "
                    f"set start values with start=... (--start on the command line). Parameters: "
                    f"{', '.join(self._param_names) or 'none'}")
            if not only_parameters and var.start is None and var.causality != "input":
                raise InvalidSettingError(f"{name!r} of {self.path.name} has no start value to set "
                                          f"(causality {var.causality}, initial {var.initial})")
            if not signal.shape:
                self._settings[var.name] = coerce(var, value)
            elif signal.offset is None:
                self._settings[var.name] = [coerce(var, v) for v in array_value(signal, value)]
            else:
                whole = self._settings.get(var.name) or [coerce(var, v) for v in str(var.start).split()]
                whole = list(whole) if len(whole) == signal.size else [whole[0]] * signal.size
                whole[signal.offset] = coerce(var, value)
                self._settings[var.name] = whole

    @property
    def left_inputs(self) -> tuple[str, ...]:
        """The FMU's numeric inputs this plant does not drive, in modelDescription order: left to the FMU after their
        start values (see `inputs` in the class docstring). :attr:`declared_inputs` holds them all.

        Examples
        --------
        >>> from cosim import FmuPlant, build_fmu
        >>> with FmuPlant(build_fmu(), dt=1e-3, inputs=["Tm"]) as plant:
        ...     plant.inputs, plant.left_inputs
        (('Tm',), ('TL',))
        """
        driven = set(self.inputs)
        return tuple(name for name in self.declared_inputs if name not in driven)

    @property
    def parameters(self) -> dict[str, Any]:
        """Current values of the parameters, read from the instance, by name."""
        return dict(zip(self._param_names, self.get(self._param_names), strict=True))

    @property
    def variables(self) -> Mapping[str, Any]:
        """The FMU's variables (FMPy ``ModelVariable`` objects: type, causality, unit, start...) by name."""
        return self._vars

    @property
    def dt(self) -> float:
        """Communication step size [s], fixed for the plant's life (create a new plant for another)."""
        return self._dt

    @property
    def t0(self) -> float:
        """Start time [s]."""
        return self._t0

    @property
    def time(self) -> float:
        """Current simulation time, ``t0 + k*dt`` (or when the FMU ended the simulation)."""
        if self._ended_at is not None:
            return self._ended_at
        return self.t0 + self._counter[0] * self.dt

    # ------------------------------------------------------------------ FMI life cycle
    def _on_log(self, status: int, category: bytes | None, message: bytes | None) -> None:
        text = (message or b"").decode("utf-8", "replace").strip()
        self._messages.append(text)
        level = logging.DEBUG if status == 0 else logging.WARNING if status in (1, 2) else logging.ERROR
        _log.log(level, "%s [%s] %s", self.path.name, status_name(status),
                 text)

    def _load(self, instance_name: str) -> None:
        import fmpy  # imported when an FMU is loaded, not with cosim (tens of ms)

        md = self.model_description
        self._unzipdir = fmpy.extract(str(self.path))
        interface = md.coSimulation if self.kind == "cs" else md.modelExchange
        common = dict(guid=md.guid, unzipDirectory=self._unzipdir,
                      modelIdentifier=interface.modelIdentifier, instanceName=instance_name)
        try:
            with _LIBRARY_LOAD:
                self._fmu = self._open(fmpy, common)
        except Exception as exc:
            raise FmuPlatformError(f"{self.path.name}: its binary cannot be loaded on this machine "
                                   f"({str(exc).splitlines()[0]}); re-export it for this platform") from None
        fmu = self._fmu
        try:
            if self.fmi_version == "2.0":
                callbacks = fmi2_callbacks(self)
                self._callbacks = callbacks
                fmu.instantiate(callbacks=callbacks)
            else:
                def log_message(env, status, category, message):
                    self._on_log(status, category, message)

                fmu.instantiate(logMessage=log_message)
        except Exception as exc:
            self._fmu_error("fmi2Instantiate" if self.fmi_version == "2.0" else "fmi3Instantiate" +
                            ("CoSimulation" if self.kind == "cs" else "ModelExchange"), exc)
        self._bind_hot_path()

    def _open(self, fmpy: Any, common: dict[str, Any]) -> Any:
        """FMPy's instance of the FMU (library loaded, not instantiated); called under ``_LIBRARY_LOAD``."""
        if self.kind == "me":  # integrated here by FMPy's solvers, stepped like a co-simulation slave
            return ModelExchangeSlave(**common, fmi_version=self.fmi_version, model_description=self.model_description,
                                      solver=self.solver, relative_tolerance=self._relative_tolerance,
                                      log=self._on_log)
        if self.fmi_version == "2.0":
            return fmpy.fmi2.FMU2Slave(**common)
        return fmpy.fmi3.FMU3Slave(**common)

    def _fmu_error(self, function: str, exc: Exception, status: int = 3) -> None:
        function = getattr(exc, "function", None) or function
        status = getattr(exc, "status", None) or status
        self._raise_call_error(function, status)

    def _raise_call_error(self, function: str, status: int, at: float | None = None) -> None:
        when = f" at t={at:.9g} s" if at is not None else ""
        advice = (f": the FMU says: {self._messages[-1]}" if self._messages
                  else "; check the parameters, start values and inputs")
        raise FmiCallError(f"{self.path.name}: {function} returned {status_name(status)}{when}{advice}",
                           function=function, status=status, time=at)

    def _initialize(self, finish: bool = True) -> None:  # finish: leave Initialization Mode too
        fmu = self._fmu
        self._apply_settings()
        try:
            if self.fmi_version == "2.0":
                fmu.setupExperiment(startTime=self.t0)
                fmu.enterInitializationMode()
            else:
                fmu.enterInitializationMode(startTime=self.t0)
        except Exception as exc:
            self._fmu_error("initialization", exc)
        self._initialized = True
        self._in_initialization = True
        self._counter[0] = 0
        if finish:
            self.exit_initialization()

    def exit_initialization(self) -> None:
        """Leave Initialization Mode (after ``initialize=False``); nothing to do when the plant steps already."""
        if not getattr(self, "_in_initialization", False):
            return
        try:
            self._fmu.exitInitializationMode()
        except Exception as exc:
            self._fmu_error("initialization", exc)
        self._in_initialization = False

    def _apply_settings(self) -> None:
        for name, value in self._settings.items():
            self._set_one(self._vars[name], value)

    def _set_one(self, var, value: Any) -> None:
        try:
            write_value(self._fmu, self.fmi_version, var, value)
        except Exception as exc:
            self._fmu_error("set " + var.name, exc)

    def get(self, names: Sequence[str]) -> list[Any]:
        """Current values of any variables, by name.

        Examples
        --------
        >>> from cosim import FmuPlant, build_fmu
        >>> with FmuPlant(build_fmu(), dt=1e-3, parameters={"Jm": 300.0}) as plant:
        ...     plant.get(["Jm"])
        [300.0]
        """
        out = []
        fmu = self._fmu
        for name in names:
            signal = self._signal(name)
            try:
                value = read_value(fmu, self.fmi_version, signal.var, signal.size if signal.shape else None)
            except InvalidSettingError:
                raise
            except Exception as exc:
                self._fmu_error("get " + name, exc)
            if signal.shape:  # an array: the element, or the whole as nested lists
                value = value[signal.offset] if signal.offset is not None else np.reshape(
                    np.array(value, dtype=object), signal.shape).tolist()
            out.append(value)
        return out

    def set_inputs(self, u: Sequence[float]) -> None:
        """Set the inputs now, without stepping, so that :meth:`read_outputs` shows their direct feedthrough
        (``y = C x + D u`` at the start time). :meth:`step` sets them anyway."""
        if len(u) != len(self.inputs):
            self._bad_input(u)
        for name, value in zip(self.inputs, u, strict=True):
            signal = self._signals[name]
            value = _input_value(signal, float(value), self.time)
            if signal.shape:
                whole = read_value(self._fmu, self.fmi_version, signal.var, signal.size)
                whole[signal.offset] = value
                value = whole
            self._set_one(signal.var, value)

    def read_outputs(self) -> np.ndarray:
        """The outputs now, in :attr:`outputs` order (after initialisation: their initial values)."""
        status = self._call_get()
        if status > 1:
            self._raise_call_error(self._get_name, status, self.time)
        return self._y_view.copy()

    def set_parameters(self, values: Mapping[str, Any] | None = None, **kw: Any) -> None:
        """Set parameters by name; tunable ones take effect at once, fixed ones at the next :meth:`reset`.

        Examples
        --------
        >>> from cosim import FmuPlant, build_fmu
        >>> with FmuPlant(build_fmu(), dt=1e-3) as plant:
        ...     plant.set_parameters(Fc=50.0)
        ...     plant.reset()
        ...     plant.parameters["Fc"]
        50.0
        """
        values = {**(values or {}), **kw}
        self._stage(values, only_parameters=True)
        for name in values:
            var = self._signal(name).var
            if var.variability == "tunable":
                self._set_one(var, self._settings[var.name])

    def reset(self, *, parameters: Mapping[str, Any] | None = None, start: Mapping[str, Any] | None = None,
              initialize: bool = True) -> None:
        """Back to ``t0`` and the start values; applies the parameters and start values given so far.

        Parameters
        ----------
        parameters, start : mapping, optional
            More values to apply, kept for later resets too.
        initialize : bool
            False leaves the FMU in Initialization Mode (see the class's `initialize`).
        """
        self._stage(parameters or {}, only_parameters=True)
        self._stage(start or {}, only_parameters=False)
        fmu = self._fmu
        try:
            fmu.reset()
        except Exception as exc:
            self._fmu_error("reset", exc)
        self._initialized = False
        self._initialize(finish=initialize)
        self._ended_at = None
        self._bind_hot_path()  # anew: the staged values of array inputs, and a step after the FMU ended

    # ------------------------------------------------------------------ the hot path
    def step(self, u: Sequence[float]) -> np.ndarray:
        """Hold the inputs `u` over one step of ``dt``, advance, and return the outputs at the new time.

        Parameters
        ----------
        u : sequence of float
            One value per name in :attr:`inputs`, in that order.

        Returns
        -------
        numpy.ndarray
            The outputs in :attr:`outputs` order, at ``time`` (after the step).
        """
        return self.step(u)  # replaced per instance by the bound fast path (see _bind_hot_path)

    def run(self, u: np.ndarray) -> np.ndarray:
        """Step through the rows of `u` (n_steps x n_inputs) and return the outputs after each step.

        Same as calling :meth:`step` in a loop, with the loop's lookups hoisted.
        """
        u = np.ascontiguousarray(u, dtype=np.float64)
        if u.ndim != 2 or u.shape[1] != self._n_in:
            raise InvalidSettingError(f"run() takes an array of shape (n_steps, {self._n_in}), got {u.shape}")
        if not np.all(np.isfinite(u)):
            bad = int(np.argwhere(~np.isfinite(u))[0][0])
            raise InvalidSettingError(f"input row {bad} is not finite ({u[bad]}); inputs must be finite")
        y = np.empty((u.shape[0], len(self.outputs)))
        loop = self._loop  # None once the FMU ended the run or the plant is closed
        if loop is not None:  # every step in one call of the C loop
            k = self._counter[0]
            done = loop.run(u, y)
            self._counter[0] = k + done
            if done < u.shape[0]:
                try:
                    loop.fail(k + done)
                except SimulationTerminated as ended:
                    ended.completed = y[:done]  # the outputs after the steps before the one the FMU ended in
                    raise
            return y
        step = self.step
        k = 0
        try:
            for k, row in enumerate(u.tolist()):
                y[k] = step(row)
        except SimulationTerminated as ended:
            ended.completed = y[:k]  # the outputs after the steps before the one the FMU ended in
            raise
        return y

    @property
    def types(self) -> dict[str, str]:
        """The FMI type of each input and output that is not a 64-bit float (``{"counter": "Int32"}``)."""
        return {name: self._signals[name].var.type for name in self.inputs + self.outputs
                if self._signals[name].var.type not in REAL_TYPES}

    def variable(self, name: str) -> Any:
        """The FMPy ``ModelVariable`` a signal name refers to (for an array element ``A[1,2]``: the array's)."""
        return self._signal(name).var

    # ------------------------------------------------------------------ clean-up
    def close(self) -> None:
        """Terminate and free the instance, unload the library and delete the extracted files. Idempotent."""
        fmu, self._fmu = self._fmu, None
        # The library is unloaded below: the bound function pointers must never be called again.
        self.step, self._call_get, self._loop = self._closed, self._closed, None
        if fmu is not None:
            try:
                if self._initialized:
                    fmu.terminate()
            except Exception:  # an FMU in error state may refuse to terminate: still free it
                pass
            finally:
                self._initialized = False
                try:
                    fmu.freeInstance()
                except Exception:
                    pass
        if self._unzipdir is not None:
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            self._unzipdir = None

    def _closed(self, *args: Any) -> int:
        raise InvalidSettingError(f"{self.path.name}: the plant is closed; create a new FmuPlant to go on")

    def __enter__(self) -> FmuPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_fmu", None) is not None or getattr(self, "_unzipdir", None) is not None:
            self.close()

    def __repr__(self) -> str:
        return (f"FmuPlant({self.path.name!r}, FMI {self.fmi_version}, dt={self.dt:g}, "
                f"inputs={list(self.inputs)}, outputs={list(self.outputs)})")
