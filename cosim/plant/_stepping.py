"""FmuPlant's step: the FMI calls of one communication step bound once, for :class:`~cosim.plant.fmu_plant.FmuPlant`.

* the fast path: scalar 64-bit float inputs and outputs, through the FMU's own ``SetReal``/``DoStep``/``GetReal``
  function pointers with prebuilt ctypes arguments (a third of FMPy's cost per step);
* the typed path: inputs and outputs of any numeric FMI type and FMI 3 array elements, through FMPy's typed
  calls around the same bound ``DoStep``;
* the end of a run the FMU decides itself (:class:`~cosim.errors.SimulationTerminated`).

Written by hand because FMPy's slave methods build new ctypes arrays on every call, which costs more than a small
plant's step (benchmarks/bench_step.py).
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import InvalidSettingError, SimulationTerminated
from ._fmi_calls import REAL_TYPES, coerce, read_value, write_value
from ._variables import Signal

__all__: list[str] = []


def _input_value(signal: Signal, value: float, t: float) -> Any:
    """A step() input as its variable's type: a whole number for an integer, 0/1 for a Boolean."""
    kind = signal.kind
    if kind == "float":
        if not math.isfinite(value):
            raise InvalidSettingError(f"step() input {signal.name} is {value} at t={t:.9g} s; inputs must be finite "
                                      "numbers (check the controller or the signal feeding it)")
        return value
    if kind == "bool":
        if value not in (0.0, 1.0):
            raise InvalidSettingError(f"step() input {signal.name} is a Boolean: give 0 or 1, got {value} at "
                                      f"t={t:.9g} s")
        return value == 1.0
    if not math.isfinite(value) or value != int(value):
        raise InvalidSettingError(f"step() input {signal.name} is {signal.var.type}: give whole numbers, got "
                                  f"{value} at t={t:.9g} s")
    return coerce(signal.var, int(value))


class _Stepping:
    """The step methods of FmuPlant (a mix-in: it reads the plant's FMU, signals, buffers and counter)."""

    def _bind_hot_path(self) -> None:
        """Bind the set-inputs / do-step / get-outputs calls once, with preallocated buffers.

        The function objects are fresh (``dll[name]``, so FMPy's own stay untouched) and have no argtypes:
        every argument is a prebuilt ctypes object, so ctypes converts nothing per call. This is what makes
        a step cost about a third of FMPy's ``setReal``/``doStep``/``getReal``. Inputs or outputs other than
        scalar 64-bit floats (integers, Booleans, Float32, array elements) go through FMPy's typed calls
        instead (:meth:`_bind_typed_path`), around the same bound ``doStep``.
        """
        n_in, n_out = len(self.inputs), len(self.outputs)
        u_buf, y_buf = (ctypes.c_double * n_in)(), (ctypes.c_double * n_out)()
        self._u_buf, self._y_buf = u_buf, y_buf
        y_view = np.frombuffer(y_buf, dtype=np.float64)
        self._y_view = y_view
        self._n_in = n_in
        self._loop = None  # the C loop (below): only for co-simulation FMUs with 64-bit float inputs and outputs
        if self.kind == "me":  # a Model Exchange FMU: integrated in Python by FMPy's solvers, no doStep to bind
            self._get_name = "get outputs"
            self._bind_typed_path(self._advance_model_exchange)
            return
        dll = self._fmu.dll
        comp = ctypes.c_void_p(self._fmu.component)
        t_c, h_c = ctypes.c_double(self.t0), ctypes.c_double(self.dt)
        v2 = self.fmi_version == "2.0"
        names = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal") if v2 else ("fmi3SetFloat64", "fmi3DoStep",
                                                                         "fmi3GetFloat64")
        self._get_name = names[2]
        set_real, do_step, get_real = (dll[name] for name in names)
        for f in (set_real, do_step, get_real):
            f.restype = ctypes.c_int
            f.argtypes = None
        if v2:
            step_args = (comp, t_c, h_c, ctypes.c_int(1))
            flags = last_time = None
        else:
            flags = [ctypes.c_bool() for _ in range(3)]  # event encountered, terminate, early return
            last_time = ctypes.c_double()
            step_args = (comp, t_c, h_c, ctypes.c_bool(True), *map(ctypes.byref, flags), ctypes.byref(last_time))
        self._step_flags = (flags, last_time)
        fast = all(self._signals[n].var.type in REAL_TYPES and not self._signals[n].shape
                   for n in self.inputs + self.outputs)
        if not fast:
            terminated_flag = None if v2 else flags[1]

            def advance(t: float, h: float) -> None:
                t_c.value, h_c.value = t, h
                status = do_step(*step_args)
                if status > 1 or (terminated_flag is not None and terminated_flag.value):
                    self._ended(status, t)

            self._bind_typed_path(advance)
            return
        n_in_c, n_out_c = ctypes.c_size_t(n_in), ctypes.c_size_t(n_out)
        u_vr, y_vr = self._value_refs(self.inputs), self._value_refs(self.outputs)
        t0, dt, counter, fail, bad_input = self.t0, self.dt, self._counter, self._raise_call_error, self._bad_input
        nonfinite, ended = self._nonfinite_input, self._ended
        set_args = (comp, u_vr, n_in_c, u_buf) + (() if v2 else (n_in_c,))
        get_args = (comp, y_vr, n_out_c, y_buf) + (() if v2 else (n_out_c,))
        terminated = None if v2 else flags[1]

        def step(u: Sequence[float]) -> np.ndarray:
            try:
                u_buf[:] = u
            except (ValueError, TypeError):
                bad_input(u)
            k = counter[0]
            t = t0 + k * dt
            total = sum(u_buf)
            if total - total != 0.0:  # a NaN or an infinity (or a sum that overflowed: looked at one by one)
                nonfinite(t)
            t_c.value = t
            h_c.value = (t0 + (k + 1) * dt) - t  # the step ends exactly on the next point (as FMPy steps)
            status = set_real(*set_args)
            if status > 1:
                fail(names[0], status, t)
            status = do_step(*step_args)
            if status > 1 or (terminated is not None and terminated.value):
                ended(status, t)
            status = get_real(*get_args)
            if status > 1:
                fail(names[2], status, t + dt)
            counter[0] = k + 1
            return y_view.copy()

        if not n_in:  # a plant without inputs (an autonomous model): nothing to set, the step is only doStep
            # (the lines below repeat the step above on purpose: a shared inner call would cost every step a Python
            # call, 5 % of the closed loop's step; benchmarks/bench_step.py)

            def step(u: Sequence[float]) -> np.ndarray:  # noqa: F811 - the same step, without the inputs
                if u:
                    bad_input(u)
                k = counter[0]
                t = t0 + k * dt
                t_c.value = t
                h_c.value = (t0 + (k + 1) * dt) - t
                status = do_step(*step_args)
                if status > 1 or (terminated is not None and terminated.value):
                    ended(status, t)
                status = get_real(*get_args)
                if status > 1:
                    fail(names[2], status, t + dt)
                counter[0] = k + 1
                return y_view.copy()

        from ._system_engine import single_loop

        loop = single_loop(self)  # set, doStep and get in one call of the system master's C loop, where it builds
        self._loop = loop
        if loop is not None:
            call, args, loop_fail = loop.call, loop.args, loop.fail

            def step(u: Sequence[float]) -> np.ndarray:  # noqa: F811 - the same step, its three calls in C
                try:
                    u_buf[:] = u
                except (ValueError, TypeError):
                    bad_input(u)
                k = counter[0]
                if call(*args) != 1:  # a call failed, or an input is not finite: raised as above
                    loop_fail(k)
                counter[0] = k + 1
                return y_view.copy()

        def read() -> int:
            return get_real(*get_args)

        step.__doc__ = type(self).step.__doc__
        self.step = step  # the instance's own, bound to this FMU's buffers
        self._call_get = read

    def _advance_model_exchange(self, t: float, h: float) -> None:
        """One communication step of a Model Exchange FMU (:class:`~cosim.plant.model_exchange.ModelExchangeSlave`)."""
        try:
            done = self._fmu.doStep(t, h)
        except Exception as exc:  # FMPy's FMICallException or the solver's SolverError: function and status
            self._fmu_error("doStep", exc)
        if done:
            self._ended(0, t)

    def _bind_typed_path(self, advance: Any) -> None:
        """The step for inputs or outputs of any numeric type or array elements, through FMPy's typed calls, around
        ``advance(t, h)`` (the bound ``doStep`` of a co-simulation FMU, or a Model Exchange FMU's integration)."""
        fmu, version, signals = self._fmu, self.fmi_version, self._signals
        t0, dt, counter, bad_input = self.t0, self.dt, self._counter, self._bad_input
        y_view, n_in = self._y_view, self._n_in
        # inputs: one write per variable; an array is written whole, from its staged or start values
        writes: dict[str, list] = {}
        for position, name in enumerate(self.inputs):
            signal = signals[name]
            entry = writes.setdefault(signal.var.name, [signal, [], None])
            entry[1].append((position, signal.offset))
            if signal.shape and entry[2] is None:
                staged = self._settings.get(signal.var.name)
                entry[2] = list(staged) if staged else [coerce(signal.var, v) for v in str(signal.var.start).split()]
        reads: dict[str, list] = {}
        for position, name in enumerate(self.outputs):
            signal = signals[name]
            reads.setdefault(signal.var.name, [signal, []])[1].append((position, signal.offset))

        def read() -> int:
            for signal, picks in reads.values():
                value = read_value(fmu, version, signal.var, signal.size if signal.shape else None)
                for position, offset in picks:
                    y_view[position] = float(value if offset is None else value[offset])
            return 0

        def step(u: Sequence[float]) -> np.ndarray:
            try:
                values = [float(v) for v in u]
            except (ValueError, TypeError):
                bad_input(u)
            if len(values) != n_in:
                bad_input(u)
            k = counter[0]
            t = t0 + k * dt
            for signal, picks, whole in writes.values():
                for position, offset in picks:
                    value = _input_value(signal, values[position], t)
                    if whole is None:
                        whole = value
                    else:
                        whole[offset] = value
                try:
                    write_value(fmu, version, signal.var, whole)
                except Exception as exc:
                    self._fmu_error("set " + signal.var.name, exc)
            advance(t, (t0 + (k + 1) * dt) - t)  # the step ends exactly on the next point (as FMPy steps)
            try:
                read()
            except Exception as exc:
                self._fmu_error("get outputs", exc)
            counter[0] = k + 1
            return y_view.copy()

        step.__doc__ = type(self).step.__doc__
        self.step = step
        self._call_get = read

    def _ended(self, status: int, t: float) -> None:
        """A doStep that did not complete: the FMU ended the simulation (SimulationTerminated), or it failed."""
        fmu = self._fmu
        if self.kind == "me":
            at = fmu.terminated_at
        elif self.fmi_version == "2.0":
            try:  # fmi2Discard: the FMU may have ended the simulation (fmi2Terminated, FMI 2.0 section 4.2.3)
                ended = status == 2 and fmu.getBooleanStatus(3)
                at = fmu.getRealStatus(2) if ended else None  # fmi2LastSuccessfulTime
            except Exception:
                ended, at = False, None
            if not ended:
                self._raise_call_error("fmi2DoStep", status, t)
        else:
            if status > 1:
                self._raise_call_error("fmi3DoStep", status, t)
            flags, last_time = self._step_flags
            at = last_time.value if flags[2].value else t + self.dt  # an early return ends before the step's end
        at = t + self.dt if at is None or not math.isfinite(at) else at
        self._counter[0] += 1
        self._ended_at = at
        outputs = self.read_outputs()
        message = self._messages[-1] if self._messages else ""
        self.step = self._after_end
        self._loop = None
        raise SimulationTerminated(f"{self.path.name} ended the simulation at t={at:.9g} s"
                                   + (f": {message}" if message else ""), time=at, message=message,
                                   outputs=outputs)

    def _after_end(self, *args: Any) -> np.ndarray:
        raise SimulationTerminated(f"{self.path.name} ended the simulation at t={self._ended_at:.9g} s; "
                                   "reset() to run it again", time=self._ended_at, message="", outputs=None)

    def _value_refs(self, names: Sequence[str]) -> ctypes.Array:
        return (ctypes.c_uint32 * len(names))(*[self._vars[n].valueReference for n in names])

    def _bad_input(self, u: Any) -> None:
        try:
            n = len(u)
        except TypeError:
            raise InvalidSettingError(f"step() takes a sequence of {self._n_in} numbers "
                                      f"({', '.join(self.inputs)}), got {u!r}") from None
        if n != self._n_in:
            raise InvalidSettingError(f"step() got {n} input values, expected {self._n_in} "
                                      f"({', '.join(self.inputs)}), in that order")
        raise InvalidSettingError(f"step() inputs must be numbers, got {u!r}")

    def _nonfinite_input(self, t: float) -> None:
        """Refuse a NaN or infinite input of the step at `t`, naming it (a finite one passes)."""
        for name, value in zip(self.inputs, self._u_buf, strict=True):
            if not math.isfinite(value):
                raise InvalidSettingError(f"step() input {name} is {value} at t={t:.9g} s; inputs must be finite "
                                          "numbers (check the controller or the signal feeding it)")
