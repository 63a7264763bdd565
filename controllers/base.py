"""What every controller shares: the calling convention, the design model, limits, events and JSON files.

A controller is an object with ``reset()`` and ``__call__(t, y) -> u``:

* ``y`` holds the measured plant outputs named by :attr:`Controller.outputs`, in that order (the plant's
  output order);
* ``u`` holds the manipulated plant inputs named by :attr:`Controller.inputs`, in that order (the plant's
  input order), already within the controller's limits;
* the reference for the outputs named by :attr:`Controller.tracked` is the attribute
  :attr:`Controller.setpoint`, which the closed loop (or the user) sets before a call.

Each controller kind registers itself by name (``"pid"``, ``"mpc"``) so that :func:`load_controller`
rebuilds any of them from its JSON file. Inputs are held between calls (zero-order hold), as everywhere in
cosim; ``t = t0 + k*dt``.

Examples
--------
>>> import control
>>> model = DesignModel.from_statespace(control.ss([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]], 0.0,
...                                                  inputs=["u"], outputs=["x"], states=["x", "v"]), dt=0.1)
>>> model.A.round(3).tolist(), model.B.round(3).tolist(), model.dt
([[1.0, 0.1], [0.0, 1.0]], [[0.005], [0.1]], 0.1)
"""

from __future__ import annotations

import json
import math
import os
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import control
import numpy as np

from cosim.data._names import control_label, label_name
from cosim.errors import DataError, FmuNotFoundError, InvalidSettingError, UnknownVariableError
from cosim.files import check_file_format, write_text_atomic

__all__ = [
    "CONTROLLER_FORMAT",
    "CONTROLLER_VERSION",
    "KNOWN_CONSTANT_INPUTS",
    "Controller",
    "ControllerEvent",
    "DesignModel",
    "controller_from_json",
    "controller_kinds",
    "load_controller",
    "register",
]

CONTROLLER_FORMAT = "cosim.controller"
CONTROLLER_VERSION = 1
#: Model inputs that are not manipulated but held at 1: the constant term of an identified model
#: exported with ``constant="input"`` (see :mod:`cosim.export`).
KNOWN_CONSTANT_INPUTS = ("const",)

_REGISTRY: dict[str, type[Controller]] = {}


def register(kind: str) -> Callable[[type[Controller]], type[Controller]]:
    """Class decorator: make a controller class loadable from JSON under the name `kind`."""

    def decorate(cls: type[Controller]) -> type[Controller]:
        cls.kind = kind
        _REGISTRY[kind] = cls
        return cls

    return decorate


def controller_kinds() -> tuple[str, ...]:
    """Names of the registered controller kinds, e.g. ``("mpc", "pid")``."""
    _import_builtin_kinds()
    return tuple(sorted(_REGISTRY))


def _import_builtin_kinds() -> None:
    import importlib

    for module in ("controllers.pid", "controllers.mpc", "controllers.compensation"):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:  # a kind not written yet is simply not offered
            if exc.name != module:
                raise


def _matrix(value: Any, shape: tuple[int, int], name: str) -> np.ndarray:
    m = np.array(value, dtype=float).reshape(shape) if np.size(value) else np.zeros(shape)
    if not np.all(np.isfinite(m)):
        raise InvalidSettingError(f"design model matrix {name} has NaN or infinite entries; check the model")
    m.setflags(write=False)
    return m


@dataclass(frozen=True)
class DesignModel:
    """The discrete-time linear model a controller is designed on: ``x+ = A x + B u``, ``y = C x + D u``.

    Built from a ``control.StateSpace`` by :meth:`from_statespace` (continuous models are discretised by
    zero-order hold at the controller's sample time). Signal names come from the StateSpace labels.

    Attributes
    ----------
    A, B, C, D : numpy.ndarray
        Discrete-time matrices.
    dt : float
        Sample time [s].
    states, inputs, outputs : tuple of str
        Names of the state, input and output signals.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]

    def __post_init__(self) -> None:
        n, m, p = len(self.states), len(self.inputs), len(self.outputs)
        for name, shape in (("A", (n, n)), ("B", (n, m)), ("C", (p, n)), ("D", (p, m))):
            value = getattr(self, name)
            try:
                object.__setattr__(self, name, _matrix(value, shape, name))
            except ValueError as exc:
                raise InvalidSettingError(f"design model matrix {name} has shape {np.shape(value)}, "
                                          f"expected {shape} for {n} states, {m} inputs, {p} outputs") from exc
        if not (isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0):
            raise InvalidSettingError(f"design model sample time must be a positive number, got {self.dt!r}")
        object.__setattr__(self, "dt", float(self.dt))
        for role in ("states", "inputs", "outputs"):
            names = tuple(str(s) for s in getattr(self, role))
            if len(set(names)) != len(names):
                raise InvalidSettingError(f"design model {role} have repeated names: {list(names)}")
            object.__setattr__(self, role, names)

    @classmethod
    def from_statespace(cls, sys: control.StateSpace, *, dt: float | None = None) -> DesignModel:
        """Discretise `sys` (zero-order hold) at `dt`, or take a discrete `sys` as it is.

        Parameters
        ----------
        sys : control.StateSpace
            Continuous or discrete; its ``state_labels``, ``input_labels`` and ``output_labels`` name
            the signals (``cosim.to_statespace`` sets them from the identified model; a label's ``:`` reads as
            the ``.`` of a name as FMUs write it, ``mass:s`` as ``mass.s``: :func:`cosim.export.label_name`).
        dt : float, optional
            Controller sample time. Required for a continuous `sys`; for a discrete one it must equal
            ``sys.dt`` (or be left out).
        """
        if not isinstance(sys, control.StateSpace):
            raise InvalidSettingError(f"a controller is designed from a control.StateSpace, got {type(sys).__name__}; "
                                      "convert an identified model with cosim.to_statespace(model)")
        if sys.isctime():
            if dt is None:
                raise InvalidSettingError("the model is continuous-time: pass the controller sample time dt=...")
            if not (math.isfinite(dt) and dt > 0):
                raise InvalidSettingError(f"dt must be a positive number of seconds, got {dt!r}")
            disc = control.sample_system(sys, dt, method="zoh")
        else:
            if sys.dt is True or sys.dt is None:
                raise InvalidSettingError("the discrete model has no sample time; build it with dt=<seconds>")
            if dt is not None and not math.isclose(dt, sys.dt, rel_tol=1e-9):
                raise InvalidSettingError(f"the model is discrete with dt={sys.dt}, but dt={dt} was asked; "
                                          "pass the continuous model or leave dt out")
            disc, dt = sys, sys.dt
        return cls(A=disc.A, B=disc.B, C=disc.C, D=disc.D, dt=float(dt),
                   states=tuple(map(label_name, sys.state_labels)), inputs=tuple(map(label_name, sys.input_labels)),
                   outputs=tuple(map(label_name, sys.output_labels)))

    def to_statespace(self) -> control.StateSpace:
        """The model as a discrete named ``control.StateSpace`` (an input or output name's dots written ``:``, as
        python-control wants them: :func:`cosim.export.control_label`)."""
        return control.ss(self.A, self.B, self.C, self.D, self.dt,
                          states=[control_label(s, keep_dots=True) for s in self.states],
                          inputs=[control_label(u) for u in self.inputs],
                          outputs=[control_label(y) for y in self.outputs])

    def index(self, names: Sequence[str], role: str) -> list[int]:
        """Positions of `names` among the model's `role` ("states", "inputs" or "outputs")."""
        available = getattr(self, role)
        missing = [n for n in names if n not in available]
        if missing:
            raise UnknownVariableError(f"the design model has no {role[:-1]} named {missing[0]!r}; "
                                       f"its {role} are {list(available)}")
        return [available.index(n) for n in names]

    def static_gain(self, input: str, output: str) -> float | None:
        """Steady-state gain ``C (I - A)^-1 B + D`` from `input` to `output`, or None where the model has no steady
        state to speak of: a pole on or outside the unit circle (an integrator holds any output with no input), or
        one a thousand times slower than its fastest (an identified integrator comes out so, a slow drift where
        the record could not tell).

        Examples
        --------
        >>> import control
        >>> lag = DesignModel.from_statespace(control.ss(-2.0, 1.0, 3.0, 0.0, inputs=["u"], outputs=["y"]), dt=0.1)
        >>> round(lag.static_gain("u", "y"), 6)
        1.5
        """
        (i,), (j,) = self.index([input], "inputs"), self.index([output], "outputs")
        lam = np.linalg.eigvals(self.A)
        lam = lam[np.abs(lam) > 1e-12]  # poles at z = 0 (delays) have no continuous-time counterpart
        s = (np.log(np.abs(lam)) + 1j * np.angle(lam)) / self.dt
        if s.size and (np.any(s.real > -1e-6 / self.dt) or np.abs(s).min() < 1e-3 * np.abs(s).max()):
            return None
        try:
            gain = float((self.C[j] @ np.linalg.solve(np.eye(self.A.shape[0]) - self.A, self.B[:, i])) + self.D[j, i])
        except np.linalg.LinAlgError:
            return None
        return gain if math.isfinite(gain) else None

    def to_dict(self) -> dict[str, Any]:
        return {"A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(), "D": self.D.tolist(),
                "dt": self.dt, "states": list(self.states), "inputs": list(self.inputs),
                "outputs": list(self.outputs)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DesignModel:
        try:
            return cls(**{k: data[k] for k in ("A", "B", "C", "D", "dt", "states", "inputs", "outputs")})
        except KeyError as exc:
            raise DataError(f"controller file's model lacks {exc.args[0]!r}; save the controller again") from None


@dataclass(frozen=True)
class ControllerEvent:
    """Something a controller did that the closed loop should report: a fallback, an infeasible problem...

    Attributes
    ----------
    time : float
        Time of the call [s].
    kind : str
        Short name, e.g. ``"infeasible"``, ``"solver_failed"``, ``"fallback"``.
    message : str
        What happened and what the controller did about it.
    """

    time: float
    kind: str
    message: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "kind": self.kind, "message": self.message}


def _limits(value: Any, n: int, name: str, default: float) -> np.ndarray:
    if value is None:
        return np.full(n, default)
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidSettingError(f"{name} must be numbers, got {value!r}") from None
    if arr.size == 1:
        arr = np.full(n, arr[0])
    if arr.shape != (n,):
        raise InvalidSettingError(f"{name} needs one value per manipulated input ({n}), got {arr.size}")
    if np.any(np.isnan(arr)):
        raise InvalidSettingError(f"{name} has NaN entries")
    return arr


class Controller(ABC):
    """Base class: a discrete controller called once per sample with the measured outputs.

    Subclasses implement :meth:`reset`, :meth:`__call__`, :meth:`_settings` (the constructor keywords
    that rebuild them) and register a kind with :func:`register`.

    Attributes
    ----------
    kind : str
        Registered name of the controller class.
    dt : float
        Sample time [s]; the closed loop calls the controller every `dt`.
    inputs : tuple of str
        Manipulated plant inputs, in the order of the returned ``u``.
    outputs : tuple of str
        Measured plant outputs, in the order of the ``y`` it expects.
    tracked : tuple of str
        Outputs that follow :attr:`setpoint` (a subset of `outputs`).
    u_min, u_max : numpy.ndarray
        Input limits the controller respects (``-inf``/``inf`` when none).
    du_max : numpy.ndarray
        Largest change of each input per sample (``inf`` when none).
    events : list of ControllerEvent
        What happened since the last :meth:`reset` (fallbacks, infeasible problems).
    design_model : DesignModel or None
        The model it was designed on, saved with it; :func:`cosim.loop.closed_loop.closed_loop` also runs the
        controller against it.
    info : dict
        Design figures (margins, weights, solver...), saved with the controller.
    """

    kind: ClassVar[str] = ""

    def __init__(self, *, dt: float, inputs: Sequence[str], outputs: Sequence[str], tracked: Sequence[str],
                 u_min: Any = None, u_max: Any = None, du_max: Any = None,
                 info: Mapping[str, Any] | None = None) -> None:
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InvalidSettingError(f"controller sample time dt must be a positive number, got {dt!r}")
        self.dt = float(dt)
        self.inputs = tuple(inputs)
        self.outputs = tuple(outputs)
        self.tracked = tuple(tracked)
        if not self.inputs or not self.outputs or not self.tracked:
            raise InvalidSettingError("a controller needs at least one input, one measured output and one tracked "
                                      f"output; got inputs={list(self.inputs)}, outputs={list(self.outputs)}, "
                                      f"tracked={list(self.tracked)}")
        stray = [name for name in self.tracked if name not in self.outputs]
        if stray:
            raise InvalidSettingError(f"tracked output {stray[0]!r} is not measured; measured outputs are "
                                      f"{list(self.outputs)}")
        m = len(self.inputs)
        self.u_min = _limits(u_min, m, "u_min", -np.inf)
        self.u_max = _limits(u_max, m, "u_max", np.inf)
        self.du_max = _limits(du_max, m, "du_max", np.inf)
        if np.any(self.u_min >= self.u_max):
            raise InvalidSettingError(f"input limits need u_min < u_max, got u_min={self.u_min.tolist()}, "
                                      f"u_max={self.u_max.tolist()}")
        if np.any(self.du_max <= 0):
            raise InvalidSettingError(f"du_max must be positive, got {self.du_max.tolist()}")
        self.info: dict[str, Any] = dict(info or {})
        self.events: list[ControllerEvent] = []
        #: The model the controller was designed on (saved with it); the closed loop also runs against it.
        self.design_model: DesignModel | None = None
        self._setpoint = np.zeros(len(self.tracked))

    # ------------------------------------------------------------------ the calling convention
    @property
    def setpoint(self) -> np.ndarray:
        """Reference for the :attr:`tracked` outputs (a number sets all of them)."""
        return self._setpoint

    @setpoint.setter
    def setpoint(self, value: Any) -> None:
        try:
            r = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"setpoint needs {len(self.tracked)} number(s) for {list(self.tracked)}, "
                                      f"got {value!r}") from None
        if r.ndim == 0:
            r = np.full(len(self.tracked), float(r))
        if r.shape != (len(self.tracked),) or not np.all(np.isfinite(r)):
            raise InvalidSettingError(f"setpoint needs {len(self.tracked)} finite value(s) for {list(self.tracked)}, "
                                      f"got {value!r}")
        self._set_setpoint(r)

    def _set_setpoint(self, r: np.ndarray) -> None:
        """Store a checked setpoint; subclasses may react (bumpless transfer, target update)."""
        self._setpoint = r

    @abstractmethod
    def reset(self) -> None:
        """Return to the initial internal state (integrators, observer, warm start); clear :attr:`events`."""

    @abstractmethod
    def __call__(self, t: float, y: Sequence[float]) -> np.ndarray:
        """The manipulated inputs to hold over ``[t, t + dt)`` given the outputs `y` measured at `t`."""

    def _event(self, t: float, kind: str, message: str) -> None:
        self.events.append(ControllerEvent(float(t), kind, message))

    # ------------------------------------------------------------------ files
    @abstractmethod
    def _settings(self) -> dict[str, Any]:
        """JSON-compatible keyword arguments that rebuild this controller with ``type(self)(**settings)``."""

    def to_dict(self) -> dict[str, Any]:
        """The controller as a JSON-compatible dictionary (``kind``, ``settings``, ``info``)."""
        cls = type(self)
        data = {"format": CONTROLLER_FORMAT, "version": CONTROLLER_VERSION, "kind": self.kind,
                "class": f"{_public_module(cls)}:{cls.__qualname__}",
                "settings": _jsonable(self._settings()), "info": _jsonable(self.info)}
        if self.design_model is not None:
            data["design_model"] = self.design_model.to_dict()
        return data

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=True)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the controller as versioned JSON, atomically; :func:`load_controller` reads it back."""
        return write_text_atomic(path, self.to_json() + "\n")

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(dt={self.dt:g}, inputs={list(self.inputs)}, outputs={list(self.outputs)}, "
                f"tracked={list(self.tracked)})")


def _public_module(cls: type) -> str:
    """The shortest module path below the top-level package that exposes `cls` (``controllers.pid`` for the
    PID defined in ``controllers.pid.controller``): what saved files record, so that they outlive a split."""
    import sys

    module = cls.__module__
    parent = module.rpartition(".")[0]
    while "." in parent and getattr(sys.modules.get(parent), cls.__name__, None) is cls:
        module, parent = parent, parent.rpartition(".")[0]
    return module


def _jsonable(value: Any) -> Any:
    if isinstance(value, DesignModel):
        return value.to_dict()
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def controller_from_json(data: str | Mapping[str, Any]) -> Controller:
    """Rebuild a controller from :meth:`Controller.to_json` output (a string or the parsed dictionary)."""
    if isinstance(data, str):
        try:
            data = json.loads(data)
        except json.JSONDecodeError as exc:
            raise DataError(f"controller file is not JSON ({exc.msg} at line {exc.lineno}); "
                            "write it with `cosim design ... -o CTRL.json`") from None
    check_file_format(data, CONTROLLER_FORMAT, CONTROLLER_VERSION, what="controller",
                      hint="write one with `cosim design pid|mpc MODEL.json -o CTRL.json`")
    _import_builtin_kinds()
    kind = data.get("kind")
    cls = _REGISTRY.get(kind) or _class_named(data.get("class"))
    if cls is None:
        raise DataError(f"unknown controller kind {kind!r}; known kinds: {sorted(_REGISTRY)} (a user-defined "
                        "controller must be importable where it is loaded)")
    settings = dict(data.get("settings") or {})
    settings = {k: _unjson(v) for k, v in settings.items()}
    try:
        controller = cls(**settings)
    except TypeError as exc:
        raise DataError(f"controller file does not fit kind {kind!r}: {exc}") from None
    for key, value in (data.get("info") or {}).items():  # what the constructor computed here wins over the file
        controller.info.setdefault(key, _unjson(value))
    if data.get("design_model") and controller.design_model is None:
        controller.design_model = DesignModel.from_dict(data["design_model"])
    return controller


def _class_named(path: Any) -> type[Controller] | None:
    """The controller class ``"module:Qualname"`` (saved by :meth:`Controller.to_dict`), if it can be imported."""
    import importlib

    if not isinstance(path, str) or ":" not in path:
        return None
    module, _, qualname = path.partition(":")
    try:
        obj: Any = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        return None
    return obj if isinstance(obj, type) and issubclass(obj, Controller) else None


def _unjson(value: Any) -> Any:
    if value == "inf":
        return math.inf
    if value == "-inf":
        return -math.inf
    if isinstance(value, list):
        return [_unjson(v) for v in value]
    if isinstance(value, dict):
        if {"A", "B", "C", "D", "dt", "states", "inputs", "outputs"} <= set(value):
            return DesignModel.from_dict(value)
        return {k: _unjson(v) for k, v in value.items()}
    return value


def load_controller(path: str | os.PathLike) -> Controller:
    """Read a controller file written by :meth:`Controller.save` (any registered kind).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> class Hold(Controller):
    ...     def reset(self): self.events.clear()
    ...     def __call__(self, t, y): return self.u_min.copy()
    ...     def _settings(self): return {"dt": self.dt, "inputs": self.inputs, "outputs": self.outputs,
    ...                                  "tracked": self.tracked, "u_min": self.u_min, "u_max": self.u_max}
    >>> _ = register("hold")(Hold)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "hold.json"
    >>> _ = Hold(dt=0.01, inputs=["u"], outputs=["y"], tracked=["y"], u_min=-1, u_max=1).save(path)
    >>> c = load_controller(path)
    >>> c.kind, c.dt, c(0.0, [0.5]).tolist()
    ('hold', 0.01, [-1.0])
    """
    path = Path(path)
    if not path.is_file():
        raise FmuNotFoundError(f"controller file not found: {path}; write one with "
                               f"`cosim design pid|mpc MODEL.json -o {path}`")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read controller file {path}: {exc}") from None
    return controller_from_json(text)

