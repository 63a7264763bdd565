"""The system master's steps in C (``cosim/plant/_master.c``), for :class:`~cosim.plant.system_plant.SystemPlant`.

The C loop calls the components' own ``SetReal``/``DoStep``/``GetReal`` (FMI 3: ``SetFloat64``/``DoStep``/
``GetFloat64``) function pointers, on the FMU instances the components' :class:`~cosim.plant.fmu_plant.FmuPlant`
opened, with the Python master's arithmetic in the same order: the same bits (tests/test_system.py). A step then
costs the FMUs' own work and one ctypes call, not a Python loop over the components (benchmarks/bench_system.py).

It runs where every component is a co-simulation FMU whose driven inputs and recorded outputs are 64-bit floats,
and a C compiler works; elsewhere :class:`SystemPlant` steps in Python (:func:`why_not`).
"""

from __future__ import annotations

import ctypes
import sys
from importlib import resources
from typing import TYPE_CHECKING, Any

import numpy as np

from ._fmi_calls import REAL_TYPES

if TYPE_CHECKING:
    from .system_plant import SystemPlant

__all__ = ["CEngine", "why_not"]

_D, _I, _U = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_uint)


class _Comp(ctypes.Structure):
    _fields_ = [(n, ctypes.c_int) for n in ("version", "n_in", "n_out", "multiple", "feedthrough", "n_hist")] + [
        ("k", ctypes.c_long), ("dt", ctypes.c_double),
        ("instance", ctypes.c_void_p), ("set", ctypes.c_void_p), ("get", ctypes.c_void_p), ("step", ctypes.c_void_p),
        ("in_vr", _U), ("out_vr", _U), ("u", _D), ("y", _D), ("hist_t", _D), ("hist_y", _D),
        ("src_kind", _I), ("src_comp", _I), ("src_index", _I), ("src_factor", _D), ("src_offset", _D),
        ("terminated", ctypes.c_bool), ("early", ctypes.c_bool), ("last_time", ctypes.c_double),
        ("pre", ctypes.c_int), ("src_hold", _I)]


class _Master(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int), ("jacobi", ctypes.c_int), ("extrapolation", ctypes.c_int),
                ("k", ctypes.c_long), ("t0", ctypes.c_double), ("dt", ctypes.c_double),
                ("comps", ctypes.POINTER(_Comp)), ("order", _I), ("settle", _I),
                ("failed_comp", ctypes.c_int), ("failed_call", ctypes.c_int), ("status", ctypes.c_int),
                ("failed_time", ctypes.c_double)]


_LIBRARY: list[Any] = []


def _library() -> Any:
    """The compiled master (once a process; the machine code is kept in cosim's cache), or None."""
    if not _LIBRARY:
        from .native import compiled_c

        source = resources.files("cosim.plant").joinpath("_master.c").read_text()
        lib = compiled_c(source, "cosim_master")
        if lib is not None:
            lib.cosim_master_run.restype = ctypes.c_long
            lib.cosim_master_run.argtypes = [ctypes.POINTER(_Master), ctypes.c_long, _D, ctypes.c_int, _D,
                                             ctypes.c_int, _I, _I]
        _LIBRARY.append(lib)
    return _LIBRARY[0]


def why_not(plant: SystemPlant) -> str | None:
    """Why the C loop cannot run `plant`'s components (None: it can)."""
    if plant.wiring.loops:
        return "an algebraic loop is iterated in Python"
    for name, p in plant.components.items():
        if p.kind != "cs":
            return f"{name} is a Model Exchange FMU (integrated in Python)"
        if any(p._signals[s].var.type not in REAL_TYPES or p._signals[s].shape for s in p.inputs + p.outputs):
            return f"{name} has inputs or outputs that are not 64-bit floats"
    if sys.platform.startswith("win"):
        return "no C loop on Windows"
    if _library() is None:
        return "no working C compiler"
    return None


def _pointer(array: np.ndarray, kind: Any) -> Any:
    return array.ctypes.data_as(kind)


def _component(p: Any, sources: list[tuple], index: dict[str, int], multiple: int, feedthrough: bool,
               y: np.ndarray, keep: list[Any], pre: bool = False) -> _Comp:
    """The C loop's view of the FMU of `p` (a FmuPlant): its calls, buffers and where each input comes from
    (`sources`: ``("free", position)`` or ``("link", component, output position, factor, offset, held)``)."""
    v2 = p.fmi_version == "2.0"
    calls = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal") if v2 else ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64")
    set_, step, get = (ctypes.cast(p._fmu.dll[c], ctypes.c_void_p).value for c in calls)
    kind = np.array([0 if s[0] == "free" else 1 for s in sources], dtype=np.intc)
    comp = np.array([0 if s[0] == "free" else index[s[1]] for s in sources], dtype=np.intc)
    pos = np.array([s[1] if s[0] == "free" else s[2] for s in sources], dtype=np.intc)
    factor = np.array([1.0 if s[0] == "free" else s[3] for s in sources])
    offset = np.array([0.0 if s[0] == "free" else s[4] for s in sources])
    hold = np.array([0 if s[0] == "free" else int(s[5]) for s in sources], dtype=np.intc)
    in_vr = np.array([p._vars[v].valueReference for v in p.inputs], dtype=np.uintc)
    out_vr = np.array([p._vars[v].valueReference for v in p.outputs], dtype=np.uintc)
    u = np.zeros(len(p.inputs))
    hist_t = np.array([p.t0, 0.0, 0.0])
    hist_y = np.zeros((3, len(p.outputs)))
    hist_y[0] = y
    keep += [kind, comp, pos, factor, offset, hold, in_vr, out_vr, u, y, hist_t, hist_y]
    return _Comp(2 if v2 else 3, len(p.inputs), len(p.outputs), multiple, int(feedthrough), 1, p._counter[0], p.dt,
                 p._fmu.component, set_, get, step, _pointer(in_vr, _U), _pointer(out_vr, _U), _pointer(u, _D),
                 _pointer(y, _D), _pointer(hist_t, _D), _pointer(hist_y, _D), _pointer(kind, _I), _pointer(comp, _I),
                 _pointer(pos, _I), _pointer(factor, _D), _pointer(offset, _D), False, False, 0.0, int(pre),
                 _pointer(hold, _I))


class CEngine:
    """The C loop bound to `plant`'s components and master state (rebuilt after each reset)."""

    def __init__(self, plant: SystemPlant) -> None:
        self.plant = plant
        names = list(plant.components)
        index = {n: i for i, n in enumerate(names)}
        self._keep: list[Any] = []  # every buffer the C structs point into
        comps = (_Comp * len(names))()
        for i, n in enumerate(names):
            # y: the master's own array, where Python reads the C loop's outputs
            comps[i] = _component(plant.components[n], plant._sources[n], index, plant.multiples[n],
                                  plant._feedthrough[n], plant._y[n], self._keep, plant._pre[n])
        order = np.array([index[n] for n in plant._order], dtype=np.intc)
        settle = np.array([index[n] for n in plant.wiring.order], dtype=np.intc)
        self._pick_comp = np.array([index[c] for c, _ in plant._picks], dtype=np.intc)
        self._pick_index = np.array([i for _, i in plant._picks], dtype=np.intc)
        self._keep += [comps, order, settle]
        self._comps, self._names = comps, names
        self.master = _Master(len(names), int(plant.algorithm == "jacobi"), plant.extrapolation, 0, plant.t0,
                              plant.dt, comps, _pointer(order, _I), _pointer(settle, _I), -1, -1, 0, 0.0)
        self._run = _library().cosim_master_run

    def run(self, u: np.ndarray) -> np.ndarray:
        """Steps for the rows of `u` (n_steps x free inputs, finite); the picked outputs after each."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        n_steps, n_free = u.shape
        y = np.empty((n_steps, len(self._pick_comp)))
        done = self._run(ctypes.byref(self.master), n_steps, _pointer(u, _D), n_free, _pointer(y, _D),
                         len(self._pick_comp), _pointer(self._pick_comp, _I), _pointer(self._pick_index, _I))
        self._sync()
        if done < n_steps:
            self._raise(y[:done])
        return y

    def _sync(self) -> None:
        """The components' step counters and the master's, where Python reads them."""
        plant = self.plant
        for i, n in enumerate(self._names):
            plant.components[n]._counter[0] = self._comps[i].k
        plant._k = self.master.k

    def _raise(self, completed: np.ndarray) -> None:
        from ..errors import InvalidSettingError, SimulationTerminated

        m = self.master
        name = self._names[m.failed_comp]
        if m.status == -2:
            raise InvalidSettingError(f"component {name}: an input is not finite at t={m.failed_time:.9g} s (a "
                                      "connected output diverged)")
        try:
            _raise_call(self.plant.components[name], self._comps[m.failed_comp], m.failed_call, m.status,
                        m.failed_time)
        except SimulationTerminated as exc:  # the component ended the simulation: the system's run ends there
            ended = SimulationTerminated(f"component {name}: {exc}", time=exc.time, message=exc.message, outputs=None)
            ended.completed = completed
            raise ended from None


_CALLS = {"2.0": ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal"),
          "3.0": ("fmi3SetFloat64", "fmi3DoStep", "fmi3GetFloat64")}


def _raise_call(p: Any, c: _Comp, call: int, status: int, t: float) -> None:
    """Raise what FmuPlant's Python step raises when its `call` (0 set, 1 doStep, 2 get) failed with `status` at
    `t`: a doStep may have ended the simulation (FmuPlant._ended tells, from FMI 3's flags as the C loop left them)."""
    if call == 1:
        if p.fmi_version != "2.0":
            flags, last_time = p._step_flags
            flags[1].value, flags[2].value, last_time.value = c.terminated, c.early, c.last_time
        p._ended(status, t)
    p._raise_call_error(_CALLS[p.fmi_version][call], status, t)


class SingleLoop:
    """One co-simulation FMU's steps through the same C loop: :class:`~cosim.plant.fmu_plant.FmuPlant`'s fast path
    (``set``, ``doStep`` and ``get`` in one ctypes call instead of three; bulk runs in one call for all steps).

    `call(*args)` steps once from the plant's input buffer into its output buffer and returns 1, or 0 when a call
    failed (then :meth:`fail` raises what FmuPlant's Python step raises)."""

    def __init__(self, plant: Any) -> None:
        self.plant = plant
        self._keep: list[Any] = []
        y = np.frombuffer(plant._y_buf, dtype=np.float64)
        n_in, n_out = len(plant.inputs), len(plant.outputs)
        comp = _component(plant, [("free", i) for i in range(n_in)], {}, 1, False, y, self._keep)
        self.comps = (_Comp * 1)(comp)
        zero = np.zeros(1, dtype=np.intc)
        self.pick_index = np.arange(n_out, dtype=np.intc)
        self.pick_comp = np.zeros(n_out, dtype=np.intc)
        self._keep += [zero, self.comps, self.pick_index, self.pick_comp]
        self.master = _Master(1, 0, 0, plant._counter[0], plant.t0, plant.dt, self.comps, _pointer(zero, _I),
                              _pointer(zero, _I), -1, -1, 0, 0.0)
        self.call = _library()["cosim_master_run"]  # a function object of its own: no argtypes, nothing converted
        self.call.restype = ctypes.c_long
        self.call.argtypes = None
        self.args = (ctypes.byref(self.master), ctypes.c_long(1), ctypes.cast(plant._u_buf, _D), ctypes.c_int(n_in),
                     ctypes.cast(plant._y_buf, _D), ctypes.c_int(n_out), _pointer(self.pick_comp, _I),
                     _pointer(self.pick_index, _I))

    def run(self, u: np.ndarray, y: np.ndarray) -> int:
        """Steps for the rows of `u` (C-contiguous, finite checked by C) into the rows of `y`; the steps done."""
        p = self.plant
        return self.call(ctypes.byref(self.master), ctypes.c_long(u.shape[0]), _pointer(u, _D),
                         ctypes.c_int(u.shape[1]), _pointer(y, _D), ctypes.c_int(len(p.outputs)),
                         _pointer(self.pick_comp, _I), _pointer(self.pick_index, _I))

    def fail(self, k: int) -> None:
        """Raise as FmuPlant's Python step does for the call that failed at its step `k`."""
        p, m, c = self.plant, self.master, self.comps[0]
        t = p.t0 + k * p.dt
        m.k = c.k = k  # where the step failed (FmuPlant's counter says the same)
        if m.status == -2:
            p._nonfinite_input(t)
        _raise_call(p, c, m.failed_call, m.status, t + (p.dt if m.failed_call == 2 else 0.0))


def single_loop(plant: Any) -> SingleLoop | None:
    """The C fast path of a co-simulation FMU with 64-bit float inputs and outputs, or None (no compiler)."""
    if sys.platform.startswith("win") or _library() is None:
        return None
    return SingleLoop(plant)
