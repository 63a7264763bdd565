"""Model Exchange FMUs stepped like co-simulation ones: `ModelExchangeSlave`, integrated by FMPy's own solvers.

A Model Exchange FMU only evaluates its equations; the importer integrates them. `ModelExchangeSlave` wraps an
FMI 2.0 or 3.0 Model Exchange FMU (FMPy's ``FMU2Model`` / ``FMU3Model``) behind the calls of an FMPy
co-simulation slave (``instantiate``, ``setupExperiment``, ``enterInitializationMode``,
``exitInitializationMode``, ``doStep``, ``reset``, ``terminate``, ``freeInstance``, and the ``setReal`` /
``getFloat64``... value calls, delegated to the FMU), so that code written for ``FMU2Slave`` / ``FMU3Slave``
drives it unchanged.

Each :meth:`ModelExchangeSlave.doStep` integrates from the current time to the end of the communication step
with FMPy's CVode (``fmpy.sundials.CVodeSolver``) or forward Euler (``fmpy.simulation.ForwardEuler``), and
handles every event on the way exactly as ``fmpy.simulation.simulateME`` (FMPy 0.3.32) does: time events (the
FMU's next event time cuts the step), state events (zero crossings of the event indicators, located by CVode's
root finding or detected by Euler at the end of a step), step events (``completedIntegratorStep``), the event
iteration (``newDiscreteStates`` / ``updateDiscreteStates`` until no new discrete states are needed), the FMU's
request to terminate, and the solver's re-initialisation after each event.

A value set between two steps (an input, a tunable parameter) that changes the FMU's value is an event at the
current time, as an input event is in FMPy: the FMU enters Event Mode before the value is set (so discrete
inputs can be set too), and the next :meth:`~ModelExchangeSlave.doStep` first iterates the event, then
re-initialises the solver, so that CVode never carries the old input past the communication point. Only the
inputs its :class:`~cosim.plant.fmu_plant.FmuPlant` drives are set; an input nobody drives keeps the value it has
after initialisation, as in FMPy's ``simulateME``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import FunctionType, MethodType
from typing import Any

__all__ = ["ModelExchangeSlave", "SolverError"]

# the value setters of FMPy's FMU2Model / FMU3Model that go through the event handling of ModelExchangeSlave
_SETTERS = frozenset({"setReal", "setInteger", "setBoolean", "setString", "setFloat32", "setFloat64", "setInt8",
                      "setUInt8", "setInt16", "setUInt16", "setInt32", "setUInt32", "setInt64", "setUInt64",
                      "setBinary"})


class SolverError(RuntimeError):
    """A step the integration could not take, with the failing `function` and an FMI status (3: error).

    FMI calls that fail raise FMPy's ``FMICallException``, which has the same two attributes.
    """

    def __init__(self, message: str, function: str, status: int = 3) -> None:
        super().__init__(message)
        self.function = function
        self.status = status


class _NoInput:
    """The solvers' `input`: a ModelExchangeSlave's inputs are set by its caller between steps, not from signals."""

    @staticmethod
    def apply(*args: Any, **kwargs: Any) -> None:
        pass


def _isclose(a: float, b: float) -> bool:
    return math.isclose(a, b)  # FMPy's comparison of times (relative 1e-9), kept identical to take its steps


class ModelExchangeSlave:
    """An FMI 2.0 or 3.0 Model Exchange FMU with the interface of an FMPy co-simulation slave.

    Parameters
    ----------
    guid, unzipDirectory, modelIdentifier, instanceName : str
        As for FMPy's ``FMU2Model`` / ``FMU3Model`` (`modelIdentifier`: the Model Exchange one; `guid` is the
        instantiation token in FMI 3.0).
    fmi_version : {"2.0", "3.0"}
        The FMI version of the FMU.
    model_description : fmpy.model_description.ModelDescription
        The FMU's model description (numbers of states and event indicators, default experiment...).
    solver : {"CVode", "Euler"}
        FMPy's CVode (BDF, variable step, root finding for state events) or forward Euler (fixed step, state
        events detected at the end of a step).
    relative_tolerance : float, optional
        CVode's relative tolerance; the absolute one is it times the states' nominal values (as in FMPy).
        Default: the DefaultExperiment tolerance, else 1e-5 (FMPy's defaults).
    fixed_step : float, optional
        Euler's largest step; a communication step is cut into equal steps no longer than this. Default: the
        DefaultExperiment stepSize, else the communication step.
    max_step : float, optional
        CVode's largest step. Default: FMPy's ``(stop - start) / 50`` with the DefaultExperiment's times, else
        unbounded.
    log : callable, optional
        ``log(status, category, message)`` (status an int, category and message bytes or None) receives the
        FMU's log messages; without it they are printed by FMPy.

    Attributes
    ----------
    model : fmpy.fmi2.FMU2Model or fmpy.fmi3.FMU3Model
        The wrapped FMU; any attribute not defined here (``getReal``, ``setFloat64``, ``dll``...) is its own.
    terminated_at : float or None
        The time at which the FMU requested to terminate the simulation, else None.
    time : float
        The model's current time.
    """

    def __init__(self, guid: str, unzipDirectory: str, modelIdentifier: str, instanceName: str, *,
                 fmi_version: str, model_description: Any, solver: str = "CVode",
                 relative_tolerance: float | None = None, fixed_step: float | None = None,
                 max_step: float | None = None,
                 log: Callable[[int, bytes | None, bytes | None], None] | None = None) -> None:
        if fmi_version not in ("2.0", "3.0"):
            raise ValueError(f"fmi_version must be '2.0' or '3.0', got {fmi_version!r}")
        if solver not in ("CVode", "Euler"):
            raise ValueError(f"solver must be 'CVode' or 'Euler', got {solver!r}")
        for name, value in (("relative_tolerance", relative_tolerance), ("fixed_step", fixed_step),
                            ("max_step", max_step)):
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")
        from fmpy import fmi2, fmi3  # with an FMU, not with cosim (tens of ms)

        self._v2 = fmi_version == "2.0"
        model_class = fmi2.FMU2Model if self._v2 else fmi3.FMU3Model
        self.model = model_class(guid=guid, unzipDirectory=unzipDirectory, modelIdentifier=modelIdentifier,
                                 instanceName=instanceName)
        md = model_description
        experiment = md.defaultExperiment
        self._nx = int(md.numberOfContinuousStates)
        self._nz = int(md.numberOfEventIndicators)
        self._needs_completed_step = bool(md.modelExchange is not None
                                          and md.modelExchange.needsCompletedIntegratorStep)
        self.solver = solver
        if relative_tolerance is None:
            relative_tolerance = float(experiment.tolerance) if experiment and experiment.tolerance else 1e-5
        self.relative_tolerance = float(relative_tolerance)
        if fixed_step is None and experiment is not None and experiment.stepSize:
            fixed_step = float(experiment.stepSize)
        self.fixed_step = fixed_step
        if max_step is None:
            start = float(experiment.startTime or 0.0) if experiment is not None else 0.0
            stop = float(experiment.stopTime) if experiment is not None and experiment.stopTime else None
            max_step = (stop - start) / 50 if stop is not None and stop > start else math.inf
        self.max_step = float(max_step)
        # inputs and parameters read back before a set, to skip the event when the value is unchanged (scalars only:
        # a get with the wrong number of values is an error, which puts some FMUs in a state refusing all else)
        self._comparable = frozenset(v.valueReference for v in md.modelVariables if v.causality in
                                     ("input", "parameter") and not getattr(v, "dimensions", None))
        self._log = log
        self._callbacks: Any = None
        self._solver: Any = None
        self._callback_error: BaseException | None = None
        self._mode = "none"  # instantiated, initialization, continuous, event, terminated
        self._start_time = 0.0
        self.time = 0.0
        self._next_event: float | None = None
        self.terminated_at: float | None = None

    # ------------------------------------------------------------------ delegation to the FMU
    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or name == "model":  # not set yet (during __init__): no recursion
            raise AttributeError(name)
        attr = getattr(self.model, name)
        if name in _SETTERS:
            attr = self._setter(name, attr)
        if isinstance(attr, (MethodType, FunctionType)):
            self.__dict__[name] = attr  # found here next time, without __getattr__
        return attr

    def _setter(self, name: str, method: Callable[..., Any]) -> Callable[..., Any]:
        """`method` (a value setter of the FMU) that makes a change of value in Continuous-Time Mode an event."""
        getter = getattr(self.model, "g" + name[1:], None)

        def set_values(vr: Any, values: Any, *args: Any, **kwargs: Any) -> Any:
            if self._mode == "continuous":
                unchanged = False
                if getter is not None and len(vr) == len(values) and self._comparable.issuperset(vr):
                    try:
                        unchanged = list(getter(vr)) == list(values)
                    except Exception:  # a variable the FMU does not let us read: take the value as changed
                        pass
                if unchanged:
                    return None
                self.model.enterEventMode()
                self._mode = "event"
            return method(vr, values, *args, **kwargs)

        set_values.__name__ = name
        return set_values

    def _on_log(self, status: int, category: bytes | None, message: bytes | None) -> None:
        """Where cosim's FMI 2.0 logger (``cosim.plant._fmi_callbacks``) sends this instance's messages."""
        if self._log is not None:
            self._log(status, category, message)

    # ------------------------------------------------------------------ life cycle
    def instantiate(self, visible: bool = False, callbacks: Any = None, loggingOn: bool = False,
                    logMessage: Callable[..., Any] | None = None) -> None:
        """Instantiate the FMU, its messages going to `log` (or to the `callbacks` / `logMessage` given)."""
        if self._v2:
            if callbacks is None and self._log is not None:
                from ._fmi_callbacks import fmi2_callbacks

                callbacks = fmi2_callbacks(self)
            self._callbacks = callbacks  # kept for the instance's life: FMPy passes a pointer to it
            self.model.instantiate(visible=visible, callbacks=callbacks, loggingOn=loggingOn)
        else:
            log = self._log
            if logMessage is None and log is not None:
                def logMessage(env: Any, status: int, category: bytes | None, message: bytes | None) -> None:
                    log(status, category, message)

            self.model.instantiate(visible=visible, loggingOn=loggingOn, logMessage=logMessage)
        self._mode = "instantiated"

    def setupExperiment(self, tolerance: float | None = None, startTime: float = 0.0,
                        stopTime: float | None = None) -> Any:
        """FMI 2.0: pass the experiment to the FMU and keep `startTime` as the start of the integration."""
        if not self._v2:
            raise AttributeError("setupExperiment is an FMI 2.0 call; FMI 3.0 passes it to enterInitializationMode")
        self._start_time = float(startTime)
        return self.model.setupExperiment(tolerance=tolerance, startTime=startTime, stopTime=stopTime)

    def enterInitializationMode(self, tolerance: float | None = None, startTime: float | None = None,
                                stopTime: float | None = None) -> Any:
        """Enter Initialization Mode (FMI 3.0: with the experiment, `startTime` default 0)."""
        self._mode = "initialization"
        if self._v2:
            if startTime is not None:
                self._start_time = float(startTime)
            return self.model.enterInitializationMode()
        self._start_time = 0.0 if startTime is None else float(startTime)
        return self.model.enterInitializationMode(tolerance=tolerance, startTime=self._start_time,
                                                  stopTime=stopTime)

    def exitInitializationMode(self) -> Any:
        """Exit Initialization Mode, iterate the initial event, enter Continuous-Time Mode, create the solver."""
        status = self.model.exitInitializationMode()
        self._mode = "event"
        self.time = self._start_time
        self._next_event = None
        self.terminated_at = None
        if self._update_discrete_states():
            return status  # the next doStep answers True at once
        self.model.enterContinuousTimeMode()
        self._mode = "continuous"
        self._make_solver()
        return status

    def reset(self) -> Any:
        """Back to Instantiated (values to set, then the initialisation calls again, as for a slave)."""
        self._solver = None
        status = self.model.reset()
        self._mode = "instantiated"
        self.time, self._next_event, self.terminated_at = self._start_time, None, None
        return status

    def terminate(self) -> Any:
        """Free the solver and terminate the FMU."""
        self._solver = None
        status = self.model.terminate()
        self._mode = "terminated"
        return status

    def freeInstance(self) -> None:
        """Free the solver and the FMU instance, and unload the library."""
        self._solver = None
        self._mode = "none"
        self.model.freeInstance()

    # ------------------------------------------------------------------ integration
    def _make_solver(self) -> None:
        fmu = self.model
        args = dict(nx=self._nx, nz=self._nz, get_x=fmu.getContinuousStates, set_x=fmu.setContinuousStates,
                    get_dx=fmu.getDerivatives if self._v2 else fmu.getContinuousStateDerivatives,
                    get_z=fmu.getEventIndicators, input=_NoInput())
        if self.solver == "Euler":
            from fmpy.simulation import ForwardEuler

            self._solver = ForwardEuler(**args)
            return
        from fmpy.sundials import CVodeSolver

        guard = self._guarded  # CVode calls these from C: an exception would be printed and lost, so keep it
        args = {key: guard(value) if key.startswith(("get", "set")) else value for key, value in args.items()}
        self._callback_error = None
        self._solver = CVodeSolver(get_nominals=guard(fmu.getNominalsOfContinuousStates),
                                   set_time=guard(fmu.setTime), startTime=self.time, maxStep=self.max_step,
                                   relativeTolerance=self.relative_tolerance, **args)
        self._raise_callback_error()

    def _guarded(self, function: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any) -> Any:
            if self._callback_error is None:  # after a failure, call the FMU no more until it is reported
                try:
                    return function(*args)
                except Exception as exc:
                    self._callback_error = exc
            return None

        return call

    def _raise_callback_error(self) -> None:
        error, self._callback_error = self._callback_error, None
        if error is not None:
            raise error

    def _update_discrete_states(self) -> bool:
        """The event iteration, in Event Mode; True if the FMU requests to terminate (then `terminated_at`)."""
        update = self.model.newDiscreteStates if self._v2 else self.model.updateDiscreteStates
        needed, terminate = True, False
        while needed and not terminate:
            needed, terminate, _, _, defined, next_time = update()
        self._next_event = next_time if defined else None
        if terminate:
            self.terminated_at = self.time
        return terminate

    def _event(self) -> bool:
        """Handle an event at the current time, from Continuous-Time or Event Mode; True to terminate."""
        if self._mode != "event":
            self.model.enterEventMode()
            self._mode = "event"
        if self._update_discrete_states():
            return True
        self.model.enterContinuousTimeMode()
        self._mode = "continuous"
        self._solver.reset(self.time)
        if self._callback_error is not None:
            self._raise_callback_error()
        return False

    def doStep(self, currentCommunicationPoint: float, communicationStepSize: float,
               noSetFMUStatePriorToCurrentPoint: bool = True) -> bool:
        """Integrate over one communication step, handling every event on the way.

        Parameters
        ----------
        currentCommunicationPoint : float
            The start of the step; must be the model's current time.
        communicationStepSize : float
            The length of the step (positive).
        noSetFMUStatePriorToCurrentPoint : bool
            Accepted for the slave's signature; the solver steps only forward.

        Returns
        -------
        bool
            True if the FMU requested to terminate the simulation: the model then stays at that time,
            :attr:`terminated_at`, and every later call returns True at once.
        """
        if self.terminated_at is not None:
            return True
        if self._mode not in ("continuous", "event") or self._solver is None:
            raise SolverError(f"doStep in mode {self._mode!r}: initialise the FMU first", "doStep")
        t_start, h = float(currentCommunicationPoint), float(communicationStepSize)
        if not (h > 0 and math.isfinite(h)):
            raise SolverError(f"communicationStepSize must be positive, got {h}", "doStep")
        if abs(t_start - self.time) > 1e-9 * max(1.0, abs(t_start)):
            raise SolverError(f"currentCommunicationPoint={t_start!r} is not the model's time {self.time!r}",
                              "doStep")
        if self._mode == "event" and self._event():  # values were set since the last step
            return True
        fmu, solver, completed_step = self.model, self._solver, self._needs_completed_step
        n = 1
        if self.solver == "Euler" and self.fixed_step is not None and self.fixed_step < h:
            n = math.ceil(h / self.fixed_step - 1e-9)
        time, k = self.time, 1
        while k <= n:
            target = t_start + h if k == n else t_start + k * h / n
            next_point = target
            next_event = self._next_event
            if next_event is not None and next_point > next_event and not _isclose(next_point, next_event):
                next_point = next_event
            time_event = next_event is not None and _isclose(next_point, next_event)
            try:
                state_event, _, time = solver.step(time, next_point)
            except Exception as exc:
                if self._callback_error is not None:
                    self._raise_callback_error()
                raise SolverError(f"{self.solver} failed at t={time:.9g} s: {exc}", self.solver) from exc
            if self._callback_error is not None:
                self._raise_callback_error()
            self.time = time
            fmu.setTime(time)
            if _isclose(time, target):
                k += 1
            step_event = False
            if completed_step:
                step_event, terminate = fmu.completedIntegratorStep()
                if terminate:
                    self.terminated_at = time
                    return True
            if (time_event or state_event or step_event) and self._event():
                return True
        return False

    def __repr__(self) -> str:
        return (f"ModelExchangeSlave({self.model.instanceName!r}, FMI {'2.0' if self._v2 else '3.0'}, "
                f"solver={self.solver!r}, t={self.time:g})")
