"""`IdentifiedModel`: an identified continuous-time model ``dx/dt = coef @ theta(x, u)`` as a value.

A model is its state and input names, its library terms (expressions, see :mod:`cosim.identify.terms`) and its
coefficient matrix. It simulates itself with zero-order-hold inputs, writes its equations, and saves to and
loads from versioned JSON. The estimator that produces it lives in :mod:`cosim.identify.sindyc`; exports to
python-control, MATLAB and FMI in :mod:`cosim.export`.

Simulation: a model whose terms are only the constant, states and inputs (linear) is stepped with its exact
zero-order-hold discretisation (matrix exponential); any other model with classical RK4, `nsub` substeps per
sample. A simulation that leaves ``|x| < 1e12`` or meets a non-finite value stops and says so in its
:class:`SimulationResult` (``status="diverged"``), keeping the trajectory up to that point.

Examples
--------
>>> import numpy as np
>>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 1.0]]))
>>> model.equations()
["x' = -1 x + 1 u"]
>>> sim = model.simulate([0.0], np.ones((100, 1)), dt=0.01)
>>> round(float(sim.states[-1, 0]), 6)   # 1 - exp(-1)
0.632121
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy.linalg import expm

from ..data.trajectory import Trajectory
from ..errors import DataError, InvalidSettingError
from ..files import check_file_format, write_text_atomic
from .terms import _JIT_MIN_STEPS, Term, compile_linear_run, compile_rhs, compile_rk4, compile_rk4_casadi

__all__ = ["IdentifiedModel", "SimulationResult", "MODEL_FORMAT", "MODEL_VERSION", "DIVERGENCE_LIMIT"]

MODEL_FORMAT = "cosim-identified-model"
MODEL_VERSION = 1
#: A simulated state beyond this magnitude counts as diverged.
DIVERGENCE_LIMIT = 1e12


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """Free-run simulation of a model: time, states, and whether it ran to the end.

    Attributes
    ----------
    time : ndarray, shape (n+1,)
    states : ndarray, shape (n+1, n_states)
        Rows after a divergence are NaN.
    inputs : ndarray, shape (n, n_inputs)
        The zero-order-hold inputs, row k held from ``time[k]`` to ``time[k+1]``.
    status : str
        ``"ok"``, or ``"diverged"`` (the model is unstable or the inputs drive it out of range).
    message : str
        What happened, in one line.
    """

    time: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    status: str = "ok"
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_trajectory(self) -> Trajectory:
        """The simulation as a Trajectory (inputs' last row repeated at the final time; NaN rows dropped)."""
        good = np.all(np.isfinite(self.states), axis=1)
        n = int(np.argmin(good)) if not good.all() else len(good)
        u = np.vstack([self.inputs, self.inputs[-1:]]) if len(self.inputs) else np.zeros((n, 0))
        data = {name: self.states[:n, i] for i, name in enumerate(self.state_names)}
        data.update({name: u[:n, j] for j, name in enumerate(self.input_names)})
        roles = {**{s: "state" for s in self.state_names}, **{s: "input" for s in self.input_names}}
        return Trajectory.from_arrays(self.time[:n], data, roles=roles,
                                      meta={"source": "model simulation", "status": self.status})


@dataclass(frozen=True, eq=False)
class IdentifiedModel:
    """``dx/dt = coef @ theta(x, u)``, with ``theta`` the library terms.

    Parameters
    ----------
    states, inputs : tuple of str
        Names, in the order of ``x`` and ``u``.
    terms : tuple of str
        Library term expressions (``"1"`` is the constant term).
    coef : ndarray, shape (n_states, n_terms)
    dt : float, optional
        Sampling step of the data the model was identified from.
    units : mapping, optional
        Unit of each state and input.
    meta : mapping, optional
        How the model was made (library, threshold, derivative method, refinement, data), JSON-serialisable.
    """

    states: tuple[str, ...]
    inputs: tuple[str, ...]
    terms: tuple[str, ...]
    coef: np.ndarray
    dt: float | None = None
    units: Mapping[str, str] = field(default_factory=dict)
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        states, inputs = tuple(self.states), tuple(self.inputs)
        if not states:
            raise InvalidSettingError("a model needs at least one state")
        if len(set(states + inputs)) != len(states + inputs):
            raise InvalidSettingError(f"state and input names must be unique, got {states + inputs}")
        parsed = _checked_terms(tuple(self.terms), states + inputs)
        coef = np.array(self.coef, dtype=float, copy=True)
        if coef.shape != (len(states), len(parsed)):
            raise InvalidSettingError(f"coef has shape {coef.shape}, expected (n_states, n_terms) = "
                                      f"({len(states)}, {len(parsed)})")
        if not np.all(np.isfinite(coef)):
            raise InvalidSettingError("coef holds NaN or inf; the identification failed")
        coef.setflags(write=False)
        object.__setattr__(self, "states", states)
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "terms", tuple(t.text for t in parsed))
        object.__setattr__(self, "coef", coef)
        object.__setattr__(self, "units", dict(self.units))
        object.__setattr__(self, "meta", json.loads(json.dumps(dict(self.meta), default=_jsonable)))
        object.__setattr__(self, "_parsed", parsed)

    # ------------------------------------------------------------------ structure
    @property
    def is_linear(self) -> bool:
        """True when every term with a non-zero coefficient is the constant, a state or an input."""
        allowed = {"1", *self.states, *self.inputs}
        return all(t in allowed for k, t in enumerate(self.terms) if np.any(self.coef[:, k] != 0.0))

    def linear_part(self) -> IdentifiedModel:
        """The model without its nonlinear terms: only the constant, state and input terms, same coefficients.

        A model augmented by :func:`cosim.diagnose.diagnose` keeps the refitted linear dynamics here (no
        longer biased by the effect it lacked), which a linear controller design needs; the dropped terms are what a
        model-based compensation (:mod:`controllers.compensation`) adds back. ``meta["linear_part_of"]`` lists
        the dropped terms.

        Examples
        --------
        >>> model = IdentifiedModel(states=("v",), inputs=("u",), terms=("v", "u", "tanh(v/0.001)"),
        ...                         coef=np.array([[-2.0, 1.0, -0.5]]))
        >>> model.linear_part().equations(), model.linear_part().meta["linear_part_of"]
        (["v' = -2 v + 1 u"], ['tanh(v/0.001)'])
        """
        allowed = {"1", *self.states, *self.inputs}
        keep = [k for k, t in enumerate(self.terms) if t in allowed]
        dropped = [t for k, t in enumerate(self.terms) if t not in allowed and np.any(self.coef[:, k] != 0.0)]
        return IdentifiedModel(states=self.states, inputs=self.inputs, terms=tuple(self.terms[k] for k in keep),
                               coef=self.coef[:, keep], dt=self.dt, units=self.units,
                               meta={**self.meta, "linear_part_of": dropped})

    def linear_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A, B, c`` of ``dx/dt = A x + B u + c`` for a linear model (see :attr:`is_linear`).

        Raises
        ------
        InvalidSettingError
            If the model has nonlinear terms: linearise it at an operating point instead.
        """
        if not self.is_linear:
            nonlinear = [t for k, t in enumerate(self.terms)
                         if t not in {"1", *self.states, *self.inputs} and np.any(self.coef[:, k] != 0.0)]
            raise InvalidSettingError(f"the model has nonlinear terms ({', '.join(nonlinear)}); linearise it at "
                                      "an operating point first (to_statespace(operating_point=...))")
        n, m = len(self.states), len(self.inputs)
        a, b, c = np.zeros((n, n)), np.zeros((n, m)), np.zeros(n)
        for k, term in enumerate(self.terms):
            if term == "1":
                c += self.coef[:, k]
            elif term in self.states:
                a[:, self.states.index(term)] += self.coef[:, k]
            elif term in self.inputs:
                b[:, self.inputs.index(term)] += self.coef[:, k]
        return a, b, c

    def rhs(self, x: Sequence[float], u: Sequence[float]) -> np.ndarray:
        """``dx/dt`` at one state and input."""
        return np.array(self._point_rhs()(list(map(float, x)), list(map(float, u))))

    def _point_rhs(self):
        """``f(x, u) -> dx/dt`` on lists of floats (generated Python), made on first use and kept: a diagnosis
        builds a thousand models and asks almost none for it."""
        rhs = self.__dict__.get("_rhs")
        if rhs is None:
            rhs = compile_rhs(self.states, self.inputs, self._parsed, self.coef)
            object.__setattr__(self, "_rhs", rhs)
        return rhs

    def features(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The library evaluated on data: ``theta``, shape (n_samples, n_terms)."""
        x, u = np.atleast_2d(x), np.atleast_2d(u) if len(self.inputs) else np.zeros((len(x), 0))
        values = {name: x[:, i] for i, name in enumerate(self.states)}
        values.update({name: u[:, j] for j, name in enumerate(self.inputs)})
        return np.column_stack([term.evaluate(values) for term in self._parsed])

    def predict(self, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """``dx/dt`` on data (n_samples x n_states)."""
        u = np.zeros((len(np.atleast_2d(x)), 0)) if u is None else u
        return self.features(x, u) @ self.coef.T

    # ------------------------------------------------------------------ simulation
    def simulate(self, x0: Sequence[float], u: np.ndarray | None = None, *, dt: float | None = None,
                 n_steps: int | None = None, t0: float = 0.0, nsub: int = 1) -> SimulationResult:
        """Free-run simulation from `x0` with zero-order-hold inputs `u` (row k held over step k).

        Parameters
        ----------
        x0 : sequence of float
            Initial state.
        u : ndarray, shape (n_steps, n_inputs), optional
            Inputs per step; omit for a model without inputs (then give `n_steps`).
        dt : float, optional
            Step; defaults to the model's :attr:`dt`.
        nsub : int
            RK4 substeps per step for a nonlinear model (a linear one is discretised exactly).
        """
        dt = self._step(dt)
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.shape != (len(self.states),) or not np.all(np.isfinite(x0)):
            raise InvalidSettingError(f"x0 must hold {len(self.states)} finite values ({', '.join(self.states)}), "
                                      f"got {x0.tolist()}")
        if u is None:
            if self.inputs or n_steps is None:
                raise InvalidSettingError(f"give the inputs u, shape (n_steps, {len(self.inputs)}): "
                                          f"{', '.join(self.inputs)}")
            u = np.zeros((n_steps, 0))
        u = np.asarray(u, dtype=float)
        u = u.reshape(-1, 1) if u.ndim == 1 and len(self.inputs) == 1 else u
        if u.ndim != 2 or u.shape[1] != len(self.inputs):
            raise InvalidSettingError(f"u must have shape (n_steps, {len(self.inputs)}), got {u.shape}")
        if not np.all(np.isfinite(u)):
            raise DataError("the inputs hold NaN or inf; clean the data before simulating")
        n = u.shape[0]
        x = np.full((n + 1, len(self.states)), np.nan)
        x[0] = x0
        if self.is_linear:
            status, k = self._simulate_linear(x, u, dt)
        else:
            status, k = self._simulate_rk4(x, u, dt, int(nsub))
        time = t0 + dt * np.arange(n + 1)
        message = "" if status == "ok" else (
            f"the simulation diverged at t={time[k]:.6g} s (a state passed {DIVERGENCE_LIMIT:g} or became "
            "non-finite): the model is unstable or the inputs drive it out of range")
        return SimulationResult(time, x, u, self.states, self.inputs, status, message)

    def _step(self, dt: float | None) -> float:
        dt = self.dt if dt is None else dt
        if dt is None or not (math.isfinite(dt) and dt > 0):
            raise InvalidSettingError(f"the simulation step must be positive, got dt={dt}")
        return float(dt)

    def discretize(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact zero-order-hold discretisation ``x[k+1] = Ad x[k] + Bd u[k] + cd`` of a linear model."""
        a, b, c = self.linear_matrices()
        n, m = a.shape[0], b.shape[1]
        big = np.zeros((n + m + 1, n + m + 1))
        big[:n, :n], big[:n, n:n + m], big[:n, -1] = a, b, c
        phi = expm(big * dt)
        return phi[:n, :n], phi[:n, n:n + m], phi[:n, -1]

    def to_statespace(self, **options: Any) -> Any:
        """The model as a python-control ``StateSpace``: :func:`cosim.export.to_statespace` of this model.

        Parameters
        ----------
        **options
            Options of :func:`cosim.export.to_statespace`: ``dt`` (the ZOH-discrete system), ``operating_point``
            (required for a nonlinear model), ``constant``, ``name``.

        Examples
        --------
        >>> import numpy as np
        >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-2.0, 1.0]]))
        >>> sys = model.to_statespace()
        >>> sys.A.tolist(), sys.B.tolist(), sys.input_labels
        ([[-2.0]], [[1.0]], ['u'])
        """
        from .. import export  # the export room sits above this one: imported when called, as SINDYc does

        return export.to_statespace(self, **options)

    def _simulate_linear(self, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[str, int]:
        ad, bd, cd = self.discretize(dt)
        if u.shape[0] >= _JIT_MIN_STEPS:  # a long record: the same arithmetic, compiled (terms.compile_linear_run)
            run = compile_linear_run(ad)
            if run is not None:
                status, k, states = run(x[0], u @ bd.T + cd, DIVERGENCE_LIMIT)
                x[1:len(states) + 1] = states
                return status, k
        step = _linear_step(ad)
        drive = (u @ bd.T + cd).tolist()
        state = x[0].tolist()
        for k in range(u.shape[0]):
            state = step(state, drive[k])
            if not all(abs(v) < DIVERGENCE_LIMIT for v in state):  # also catches NaN
                return "diverged", k
            x[k + 1] = state
        return "ok", u.shape[0]

    def _simulate_rk4(self, x: np.ndarray, u: np.ndarray, dt: float, nsub: int) -> tuple[str, int]:
        if nsub < 1:
            raise InvalidSettingError(f"nsub must be at least 1, got {nsub}")
        run = self.__dict__.get("_rk4")
        if run is None:  # made on the first nonlinear simulation, then kept
            try:  # CasADi steps it several times faster than the generated Python (terms.compile_rk4)
                run = (compile_rk4_casadi(self.states, self.inputs, self._parsed, self.coef), True)
            except ImportError:
                run = (compile_rk4(self.states, self.inputs, self._parsed, self.coef), False)
            object.__setattr__(self, "_rk4", run)
        step, takes_arrays = run  # the CasADi run takes the arrays as they are (no list round trip)
        status, k, states = step(x[0] if takes_arrays else x[0].tolist(), u if takes_arrays else u.tolist(),
                                 dt / nsub, nsub, DIVERGENCE_LIMIT)
        if len(states):
            x[1:len(states) + 1] = states
        return status, k

    def state_jacobian(self, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """The exact Jacobian ``d(dx/dt)/dx`` at each sample, shape (n_samples, n_states, n_states): each term's
        derivative by forward mode over its expression (:meth:`~cosim.identify.terms.Term.derivative`)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = np.zeros((len(x), 0)) if u is None else np.asarray(u, dtype=float).reshape(len(x), len(self.inputs))
        values = {name: x[:, i] for i, name in enumerate(self.states)}
        values.update({name: u[:, j] for j, name in enumerate(self.inputs)})
        jac = np.zeros((len(x), len(self.states), len(self.states)))
        for k, term in enumerate(self._parsed):
            if not np.any(self.coef[:, k] != 0.0):
                continue
            for j, name in enumerate(self.states):
                d = term.derivative(values, name)
                if not (isinstance(d, float) and d == 0.0):
                    jac[:, :, j] += self.coef[:, k] * np.asarray(d, dtype=float)[..., None]
        return jac

    # ------------------------------------------------------------------ text and files
    def equations(self, precision: int = 6) -> list[str]:
        """One line per state: ``theta_m' = 1 omega_m``; zero terms omitted."""
        lines = []
        for i, state in enumerate(self.states):
            parts = [f"{self.coef[i, k]:.{precision}g} {'' if t == '1' else t}".strip()
                     for k, t in enumerate(self.terms) if self.coef[i, k] != 0.0]
            rhs = " + ".join(parts).replace("+ -", "- ") if parts else "0"
            lines.append(f"{state}' = {rhs}")
        return lines

    def to_dict(self) -> dict[str, Any]:
        return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "states": list(self.states),
                "inputs": list(self.inputs), "terms": list(self.terms), "coef": self.coef.tolist(),
                "dt": self.dt, "units": dict(self.units), "meta": dict(self.meta),
                "equations": self.equations(precision=10)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> IdentifiedModel:
        check_file_format(data, MODEL_FORMAT, MODEL_VERSION, what="model",
                          hint="save models with IdentifiedModel.save or `cosim identify -o`")
        try:
            return cls(states=tuple(data["states"]), inputs=tuple(data["inputs"]), terms=tuple(data["terms"]),
                       coef=np.array(data["coef"], dtype=float), dt=data.get("dt"), units=data.get("units", {}),
                       meta=data.get("meta", {}))
        except KeyError as exc:
            raise DataError(f"the model file lacks the field {exc.args[0]!r}") from None

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_json(cls, text: str) -> IdentifiedModel:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"the model file is not JSON ({exc.msg} at line {exc.lineno})") from None
        return cls.from_dict(data)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the model as versioned JSON, atomically."""
        return write_text_atomic(path, self.to_json() + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> IdentifiedModel:
        from ..errors import FmuNotFoundError

        path = Path(path)
        if not path.is_file():
            raise FmuNotFoundError(f"model file not found: {path}; create one with `cosim identify ... -o {path}`")
        return cls.from_json(path.read_text(encoding="utf-8"))


@lru_cache(maxsize=1024)
def _checked_terms(terms: tuple[str, ...], names: tuple[str, ...]) -> tuple[Term, ...]:
    """The terms parsed and checked against `names` (cached: a diagnosis builds a thousand models from the same
    few libraries; a Term is immutable, so one parse serves them all)."""
    parsed = tuple(Term(t) for t in terms)
    for term in parsed:
        term.check_names(names)
    return parsed


def _linear_step(ad: np.ndarray):
    """Generate ``f(s, d) -> ad @ s + d`` on plain floats: 3x faster than NumPy for a handful of states."""
    n = ad.shape[0]
    rows = [" + ".join([f"{float(ad[i, j])!r}*s[{j}]" for j in range(n) if ad[i, j] != 0.0] + [f"d[{i}]"])
            for i in range(n)]
    namespace: dict[str, Any] = {}
    exec(f"def step(s, d):\n    return [{', '.join(rows)}]", namespace)  # only numbers and indices
    return namespace["step"]


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)
