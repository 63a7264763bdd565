"""A plant of several FMUs run by a co-simulation master: :class:`SystemPlant`, with the interface of
:class:`~cosim.plant.fmu_plant.FmuPlant`.

The master (what its accuracy is, stated)
-----------------------------------------
Each communication step of length ``dt`` (a component with a step multiple ``m`` steps every ``m`` of them, over
``m * dt``), the components step in turn:

* ``algorithm="jacobi"``: every component from its sources' values at the step's start;
* ``algorithm="gauss-seidel"`` (default): in the order :func:`~cosim.plant.system_wiring.wire` derives from the
  FMUs' declared output dependencies, each from the newest values: a source stepped before it in this step gives
  its value at the step's end.

A co-simulation FMU holds an input constant over a step. With ``extrapolation=0`` that constant is the source's
last known value (Jacobi) or its value at the step's end (Gauss-Seidel): the coupling error is of first order in
``dt``. With ``extrapolation=1`` or ``2`` it is the value at the step's middle of the polynomial through the
source's last 2 or 3 known values (for Gauss-Seidel, the step's end among them): a held midpoint value makes the
coupling error second order, as the midpoint rule is. The default is 1. After the steps, every component whose
outputs depend directly on an input (its declared dependencies) is given its inputs' values at the step's end and
its outputs read again, so that the values recorded and passed on at a communication point are consistent with
each other; the same pass, in order, makes the initial values consistent (FMI's consistent initialisation of
connected FMUs).

An algebraic loop (a cycle of connections through outputs with direct feedthrough) is solved at each communication
point by Newton's method, where its FMUs can save and restore their state (:mod:`cosim.plant._algebraic_loops`),
and refused in one line naming its connectors where they cannot; a cycle only through outputs whose dependencies
an FMU does not declare (FMI's rule says to assume them all) is run without iteration, and logged.

Examples
--------
>>> from cosim.plant.build import build_ssp
>>> with SystemPlant(build_ssp(), dt=1e-3) as plant:
...     y = plant.step([100.0, 0.0])   # motor.Tm = 100 N m, load.TL = 0
...     plant.inputs, len(plant.outputs)
(('motor.Tm', 'load.TL'), 5)
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidSettingError, SimulationTerminated
from . import _algebraic_loops
from .fmu_plant import FmuPlant
from .system_structure import System, read_system, split_name
from .system_wiring import Wiring, check_names, description, wire

__all__ = ["ALGORITHMS", "SystemPlant"]

_log = logging.getLogger("cosim.system")

#: The master's algorithms.
ALGORITHMS = ("gauss-seidel", "jacobi")


def _weights(times: Sequence[float], at: float) -> list[float]:
    """Lagrange weights of the polynomial through `times` evaluated at `at`."""
    out = []
    for i, ti in enumerate(times):
        w = 1.0
        for j, tj in enumerate(times):
            if j != i:
                w *= (at - tj) / (ti - tj)
        out.append(w)
    return out


class SystemPlant:
    """A system of FMUs (SSP, OSP or :class:`~cosim.plant.system_structure.System`) stepped as one plant.

    Parameters
    ----------
    system : System or path-like
        The description, or an ``.ssp``, ``SystemStructure.ssd`` or ``OspSystemStructure.xml``.
    dt : float, optional
        The communication step (default: the system file's, e.g. an OSP BaseStepSize).
    algorithm : {"gauss-seidel", "jacobi"}
        The master's algorithm (module docstring).
    extrapolation : {0, 1, 2}
        The order of the polynomial an input is extrapolated with over a step (module docstring).
    parameters, start : mapping, optional
        Values by ``component.variable``, applied before initialisation over the system file's bindings.
    t0 : float
        Start time.
    inputs, outputs : sequence of str, optional
        The free inputs :meth:`step` drives (default: every input no connection drives) and the variables it
        returns (default: every component output; any variable of a component may be named, or ``"all"``).
    step_multiples : mapping, optional
        Component -> whole number: it steps every that many communication steps (overrides the system file's).
    solver : {"cvode", "euler"}
        The solver of Model Exchange components.
    hold_discrete : bool
        A connection whose output or input its FMU declares ``variability="discrete"`` (a controller's command, a
        sampled measurement: constant between communication points by their own declaration) carries the
        source's value at the step's start, not extrapolated, also in Gauss-Seidel; default True. An FMU that
        declares continuous signals discrete (the OSP quarter truck does) is coupled at first order then; False
        treats every connection as continuous.
    engine : {"auto", "c", "python"}
        Who runs the steps: the compiled loop (:mod:`cosim.plant._system_engine`; the same bits, a fraction of
        the time), or Python. ``"auto"``: C where every component is a co-simulation FMU with 64-bit float
        connections and a C compiler works (:attr:`engine` says which runs, :attr:`engine_note` why not C).
    """

    def __init__(self, system: System | str | os.PathLike, *, dt: float | None = None,
                 algorithm: str = "gauss-seidel", extrapolation: int = 1,
                 parameters: Mapping[str, Any] | None = None, start: Mapping[str, Any] | None = None,
                 t0: float = 0.0, inputs: Sequence[str] | None = None, outputs: Sequence[str] | str | None = None,
                 step_multiples: Mapping[str, int] | None = None, solver: str = "cvode",
                 engine: str = "auto", hold_discrete: bool = True) -> None:
        self.system = system if isinstance(system, System) else read_system(system)
        self.path = Path(self.system.source or self.system.name)
        if algorithm not in ALGORITHMS:
            raise InvalidSettingError(f"algorithm={algorithm!r}; choose {' or '.join(ALGORITHMS)}")
        if extrapolation not in (0, 1, 2):
            raise InvalidSettingError(f"extrapolation={extrapolation!r}; choose 0, 1 or 2 (the order of the "
                                      "polynomial an input is extrapolated with)")
        self.algorithm, self.extrapolation = algorithm, int(extrapolation)
        dt = dt if dt is not None else self.system.dt
        if dt is None or not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InvalidSettingError(f"dt={dt!r}: give the communication step in seconds (the system file "
                                      "proposes none)" if dt is None else f"dt={dt!r}; give a positive step")
        self._dt, self._t0 = float(dt), float(t0)
        self.wiring: Wiring = wire(self.system)
        for cycle in self.wiring.possible_loops:
            _log.info("a possible loop through undeclared output dependencies: %s (run without iteration)",
                      " -> ".join(cycle))
        comps = self.system.components
        self.multiples = {n: int((step_multiples or {}).get(n, c.step_multiple)) for n, c in comps.items()}
        for n, m in self.multiples.items():
            if m < 1:
                raise InvalidSettingError(f"step multiple {m} of {n}; give a whole number >= 1")
        self.declared_inputs = self.wiring.inputs
        if inputs is not None:
            check_names(self.wiring, list(inputs), "input")
        self.inputs = tuple(self.wiring.inputs if inputs is None else inputs)
        if outputs == "all":
            outputs = None
        if outputs is not None:
            check_names(self.wiring, list(outputs), "variable")
        self.outputs = tuple(self.wiring.outputs if outputs is None else outputs)
        self._settings = {"parameters": dict(parameters or {}), "start": dict(start or {})}
        self._solver = solver
        self.hold_discrete = bool(hold_discrete)
        if engine not in ("auto", "c", "python"):
            raise InvalidSettingError(f"engine={engine!r}; choose auto, c or python")
        self._engine_asked = engine
        self._plants: dict[str, FmuPlant] = {}
        self._description = None
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ building
    def _per_component(self, values: Mapping[str, Any], what: str) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {n: {} for n in self.system.components}
        for name, value in values.items():
            comp, var = split_name(name, self.system.components, what=what)
            out[comp][var] = value
        return out

    def _open(self) -> None:
        """Open every component (in Initialization Mode), route its inputs, start the master together."""
        comps, w = self.system.components, self.wiring
        links_into: dict[str, list] = {n: [lk for lk in w.links if lk.end[0] == n] for n in comps}
        wanted_out: dict[str, list[str]] = {n: [] for n in comps}  # what each component must read: linked, recorded
        for comp, var in [lk.start for lk in w.links] + [split_name(name, comps) for name in self.outputs]:
            if var not in wanted_out[comp]:
                wanted_out[comp].append(var)
        self._open_components(links_into, wanted_out)
        self._route(links_into, wanted_out)
        self._order = w.order if self.algorithm == "gauss-seidel" else tuple(comps)
        self._blocks = {n: block for block in _algebraic_loops.blocks(self) for n in block.components}
        self._initialize_together()
        self._start_history()
        self.engine_note = None if self._engine_asked != "python" else "engine='python' asked"
        if self._engine_asked != "python":
            from ._system_engine import why_not

            self.engine_note = why_not(self)
            if self.engine_note and self._engine_asked == "c":
                raise InvalidSettingError(f"engine='c' cannot run this system: {self.engine_note}; use "
                                          "engine='auto' or 'python'")
        self._bind_engine()

    def _open_components(self, links_into: Mapping[str, list], wanted_out: Mapping[str, list[str]]) -> None:
        """A FmuPlant per component, left in Initialization Mode: driven at its linked and free inputs, reading what
        is linked from it or recorded; the system file's values and the caller's, parameters apart from starts."""
        comps, w = self.system.components, self.wiring
        params = self._per_component(self._settings["parameters"], "parameter")
        starts = self._per_component(self._settings["start"], "start value")
        free = {split_name(n, comps) for n in self.inputs}
        self._plants, self._ins, self._feedthrough = {}, {}, {}
        for n, comp in comps.items():
            ins = {lk.end[1] for lk in links_into[n]} | {v for c, v in free if c == n}
            ins = [v for v in w.component_inputs[n] if v in ins]  # modelDescription order
            md = w.descriptions[n]
            kinds = {v.name: v.causality for v in md.modelVariables}
            given = {**comp.parameters, **params[n]}
            p_vals = {k: v for k, v in given.items() if kinds.get(k) == "parameter"}
            s_vals = {**{k: v for k, v in given.items() if kinds.get(k) != "parameter"}, **starts[n]}
            self._plants[n] = FmuPlant(comp.source, dt=self._dt * self.multiples[n], parameters=p_vals,
                                       start=s_vals, t0=self._t0, inputs=ins, outputs=wanted_out[n],
                                       instance_name=n, kind=w.kinds[n], solver=self._solver, initialize=False)
            self._ins[n] = ins
            deps = {o.variable.name: o.dependencies for o in md.outputs}
            self._feedthrough[n] = any(deps.get(o, None) is None or any(d.causality == "input" for d in deps[o])
                                       for o in wanted_out[n] if o in deps) and bool(ins)

    def _route(self, links_into: Mapping[str, list], wanted_out: Mapping[str, list[str]]) -> None:
        """Where each component input takes its value from (`_sources`: a link ``("link", source component,
        output position, factor, offset, held)`` or a free input ``("free", its position in step()'s u)``), which
        components answer a free input at once (`_pre`), and where the recorded outputs are read (`_picks`)."""
        comps = self.system.components
        self._sources: dict[str, list[tuple]] = {}
        for n in comps:
            src = []
            for v in self._ins[n]:
                lk = next((lk for lk in links_into[n] if lk.end[1] == v), None)
                if lk is not None:
                    source = self._plants[lk.start[0]]
                    hold = self.hold_discrete and "discrete" in (source.variable(lk.start[1]).variability,
                                                                 self._plants[n].variable(v).variability)
                    src.append(("link", lk.start[0], source.outputs.index(lk.start[1]), lk.factor, lk.offset, hold))
                else:
                    src.append(("free", self.inputs.index(f"{n}.{v}")))
            self._sources[n] = src
        self._pre = {}
        for n in comps:
            free = {v for v, src in zip(self._ins[n], self._sources[n], strict=True) if src[0] == "free"}
            deps = [o.dependencies for o in self.wiring.descriptions[n].outputs if o.variable.name in wanted_out[n]]
            self._pre[n] = bool(free) and any(d is None or any(x.name in free for x in d) for d in deps)
        self._picks = [(comp, self._plants[comp].outputs.index(var))
                       for comp, var in (split_name(name, comps) for name in self.outputs)]

    def _bind_engine(self) -> None:
        from ._system_engine import CEngine

        self._c = CEngine(self) if self.engine_note is None else None

    @property
    def engine(self) -> str:
        """``"c"`` or ``"python"``: who runs the steps."""
        return "c" if self._c is not None else "python"

    def _initialize_together(self) -> None:
        """FMI's consistent initialisation of connected FMUs: every component is in Initialization Mode; in the
        wiring's order each is given its inputs (the connected outputs' initial values, the free inputs' start
        values) and its outputs read, twice, so that a value that depends on another component's input arrives;
        then all leave Initialization Mode. An FMU that computes initial values from its inputs (a state started
        in steady state) sees its neighbours' there. (Algebraic loops are solved after, at the start time.)"""
        u_free = np.array([self._free_start(n) for n in self.inputs], dtype=float)
        self._y = {n: p.read_outputs() for n, p in self._plants.items()}
        for _ in range(2):
            for n in self.wiring.order:
                if self._ins[n]:
                    plant = self._plants[n]
                    plant.set_inputs(self._input_values(n, u_free, 0.0, 0.0, at_end=True))
                    self._y[n][:] = plant.read_outputs()
        for plant in self._plants.values():
            plant.exit_initialization()

    def _start_history(self) -> None:
        """Time and output history of each component (its last three communication points), made consistent."""
        self._k = 0
        self._u_free = np.array([self._free_start(n) for n in self.inputs], dtype=float)
        self._y = {n: p.read_outputs() for n, p in self._plants.items()}
        self._settle(self._u_free)
        self._hist = {n: [(self._t0, self._y[n].copy())] for n in self._plants}

    def _free_start(self, name: str) -> float:
        comp, var = split_name(name, self.system.components)
        value = self._plants[comp].get([var])[0]
        return float(value) if value is not None else 0.0

    # ------------------------------------------------------------------ the master
    def _input_values(self, n: str, u_free: np.ndarray, t: float, h: float, *, at_end: bool) -> list[float]:
        """The values component `n` holds over ``[t, t + h]`` (or, `at_end`, its inputs at the communication
        point reached: the sources' newest values)."""
        out = []
        p = self.extrapolation
        for src in self._sources[n]:
            if src[0] == "free":
                out.append(float(u_free[src[1]]))
                continue
            _, comp, index, factor, offset, hold = src
            if hold and not at_end:  # a discrete signal: its value at the step's start, whoever stepped first
                value = next(y[index] for tp, y in reversed(self._hist[comp]) if tp <= t)
            elif at_end or p == 0:
                value = self._y[comp][index] if at_end or self.algorithm == "gauss-seidel" else \
                    self._hist[comp][-1][1][index]
            else:
                points = self._hist[comp][-(p + 1):]
                if len(points) == 1:
                    value = points[0][1][index]
                else:
                    ws = _weights([tp for tp, _ in points], t + 0.5 * h)
                    value = sum(w * y[index] for w, (_, y) in zip(ws, points, strict=True))
            out.append(factor * value + offset)
        return out

    def _settle(self, u_free: np.ndarray, only: dict[str, bool] | None = None) -> None:
        """Components with direct feedthrough given their inputs' newest values and read again, in order; an
        algebraic loop's components solved together (:mod:`cosim.plant._algebraic_loops`). With `only`, just the
        components it flags (before a step: those answering a free input at once)."""
        solved = set()
        for n in self.wiring.order:
            if only is not None and not only[n]:
                continue
            block = self._blocks.get(n)
            if block is not None:
                if n not in solved:
                    _algebraic_loops.solve(self, block, u_free)
                    solved.update(block.components)
            elif only is not None or self._feedthrough[n]:
                plant = self._plants[n]
                plant.set_inputs(self._input_values(n, u_free, 0.0, 0.0, at_end=True))
                self._y[n][:] = plant.read_outputs()

    def step(self, u: Sequence[float]) -> np.ndarray:
        """Hold the free inputs `u` over one communication step, advance every component, and return the outputs
        at the new time (in :attr:`outputs` order)."""
        u_free = np.asarray(u, dtype=float)
        if u_free.shape != (len(self.inputs),):
            raise InvalidSettingError(f"step() got {u_free.size} input values, expected {len(self.inputs)} "
                                      f"({', '.join(self.inputs)}), in that order")
        self._check_finite(u_free[None, :])
        if self._c is not None:
            return self._c.run(u_free[None, :])[0]
        return self._step_python(u_free)

    def _check_finite(self, u: np.ndarray) -> None:
        if not np.all(np.isfinite(u)):
            row, col = (int(i) for i in np.argwhere(~np.isfinite(u))[0])
            raise InvalidSettingError(f"step() input {self.inputs[col]} is not finite at "
                                      f"t={self.time + row * self._dt:.9g} s; inputs must be finite numbers")

    def _step_python(self, u_free: np.ndarray) -> np.ndarray:
        """One communication step in Python (the C loop of :mod:`cosim.plant._system_engine` does the same)."""
        k = self._k
        t = self._t0 + k * self._dt
        if any(self._pre.values()):  # step()'s inputs hold from t: what answers them at once, answers now
            self._settle(u_free, self._pre)
            for n, pre in self._pre.items():
                h = self._hist[n]
                if pre and h[-1][0] == t:
                    h[-1] = (t, self._y[n].copy())
        stepped = [n for n in self._order if k % self.multiples[n] == 0]
        for n in stepped:
            m = self.multiples[n]
            h = (self._t0 + (k + m) * self._dt) - t
            values = self._input_values(n, u_free, t, h, at_end=False)
            try:
                self._y[n][:] = self._plants[n].step(values)
            except SimulationTerminated as exc:
                raise SimulationTerminated(f"component {n}: {exc}", time=exc.time, message=exc.message,
                                           outputs=None) from None
            if self.algorithm == "gauss-seidel":
                self._push(n, self._t0 + (k + m) * self._dt)
        if self.algorithm == "jacobi":
            for n in stepped:
                self._push(n, self._t0 + (k + self.multiples[n]) * self._dt)
        self._k = k + 1
        self._settle(u_free)
        for n in stepped:  # the settled values are the history's newest
            h = self._hist[n]
            h[-1] = (h[-1][0], self._y[n].copy())
        return self._collect()

    def _push(self, n: str, t_end: float) -> None:
        h = self._hist[n]
        h.append((t_end, self._y[n].copy()))
        del h[:-3]

    def _collect(self) -> np.ndarray:
        return np.array([self._y[c][i] for c, i in self._picks])

    def run(self, u: np.ndarray) -> np.ndarray:
        """Step through the rows of `u` (n_steps x n_inputs); the outputs after each step."""
        u = np.asarray(u, dtype=float)
        if u.ndim != 2 or u.shape[1] != len(self.inputs):
            raise InvalidSettingError(f"run() takes an array of shape (n_steps, {len(self.inputs)}), got {u.shape}")
        self._check_finite(u)
        if self._c is not None:
            return self._c.run(u)
        y = np.empty((u.shape[0], len(self.outputs)))
        k = 0
        try:
            for k, row in enumerate(u):
                y[k] = self.step(row)
        except SimulationTerminated as ended:
            ended.completed = y[:k]
            raise
        return y

    def set_inputs(self, u: Sequence[float]) -> None:
        """Set the free inputs now, without stepping (their direct feedthrough shows in :meth:`read_outputs`)."""
        self._u_free = np.asarray(u, dtype=float)
        for n in self._order:
            if self._ins[n]:
                self._plants[n].set_inputs(self._input_values(n, self._u_free, 0.0, 0.0, at_end=True))
                self._y[n][:] = self._plants[n].read_outputs()

    def read_outputs(self) -> np.ndarray:
        """The outputs now, in :attr:`outputs` order."""
        return self._collect()

    def get(self, names: Sequence[str]) -> list[Any]:
        """Current values of any variables, by ``component.variable``."""
        out = []
        for name in names:
            comp, var = split_name(name, self.system.components)
            out.extend(self._plants[comp].get([var]))
        return out

    def reset(self, *, parameters: Mapping[str, Any] | None = None, start: Mapping[str, Any] | None = None) -> None:
        """Back to ``t0``; the parameters and start values given (``component.variable``) kept for later resets."""
        self._settings["parameters"].update(parameters or {})
        self._settings["start"].update(start or {})
        params = self._per_component(parameters or {}, "parameter")
        starts = self._per_component(start or {}, "start value")
        for n, plant in self._plants.items():
            plant.reset(parameters=params[n], start=starts[n], initialize=False)
        self._initialize_together()
        self._start_history()
        self._bind_engine()

    def variable(self, name: str) -> Any:
        """The FMPy ``ModelVariable`` of ``component.variable``."""
        comp, var = split_name(name, self.system.components)
        return self._plants[comp].variable(var)

    # ------------------------------------------------------------------ FmuPlant's read-only surface
    @property
    def dt(self) -> float:
        return self._dt

    @property
    def t0(self) -> float:
        return self._t0

    @property
    def time(self) -> float:
        return self._t0 + self._k * self._dt

    @property
    def parameters(self) -> dict[str, Any]:
        """Every component's parameters, by ``component.parameter``."""
        return {f"{n}.{k}": v for n, p in self._plants.items() for k, v in p.parameters.items()}

    @property
    def left_inputs(self) -> tuple[str, ...]:
        """Free inputs not driven by :meth:`step` (left at their start values)."""
        return tuple(n for n in self.wiring.inputs if n not in self.inputs)

    @property
    def states(self) -> tuple[str, ...]:
        return tuple(f"{n}.{s}" for n, p in self._plants.items() for s in p.states if f"{n}.{s}" in self.outputs)

    @property
    def types(self) -> dict[str, str]:
        return {f"{n}.{k}": v for n, p in self._plants.items() for k, v in p.types.items()
                if f"{n}.{k}" in self.inputs + self.outputs}

    @property
    def kind(self) -> str:
        return "system"

    @property
    def fmi_version(self) -> str:
        return "/".join(sorted({p.fmi_version for p in self._plants.values()}))

    @property
    def model_description(self) -> Any:
        """The system described as one FMU (:func:`cosim.plant.system_wiring.description`)."""
        if self._description is None:
            self._description = description(self.wiring)
        return self._description

    @property
    def components(self) -> dict[str, FmuPlant]:
        """The components' plants, by name."""
        return dict(self._plants)

    # ------------------------------------------------------------------ clean-up
    def close(self) -> None:
        """Close every component. Idempotent."""
        for plant in getattr(self, "_plants", {}).values():
            plant.close()
        self._plants = {}

    def __enter__(self) -> SystemPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"SystemPlant({self.system.name!r}, {len(self.system.components)} components, dt={self._dt:g}, "
                f"{self.algorithm}, extrapolation {self.extrapolation})")
