"""The records a :class:`~cosim.identify.sindyc.SINDYc` fit learns from, read into state and input arrays.

:func:`_prepare` checks the records (the columns exist, at least 3 samples, a uniform step common to all
records, finite values), derives the velocity states the fit asks for (``velocities=``) and finds the inputs
that are constant, hence not persistently exciting: the fit warns about them and leaves them out.
:func:`_measured` and :func:`_stacked` read one trajectory (for ``predict`` and ``score`` too), and
:func:`_known_initial_states` reads the ``x0`` given to ``fit``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.trajectory import Trajectory
from ..errors import DataError, IdentificationWarning, InvalidSettingError, UnknownVariableError

#: ``derive(position, t, name)``: the velocity state `name` from samples of its position at times `t`.
_Derive = Callable[[np.ndarray, np.ndarray, str], np.ndarray]


@dataclass(frozen=True)
class _Records:
    """The records as arrays: ``runs`` holds ``(x, u)`` per record, the inputs without the constant ones."""

    runs: list[tuple[np.ndarray, np.ndarray]]
    states: list[str]
    inputs: list[str]
    dt: float
    #: Constant inputs left out of ``inputs``, name -> value.
    constant_inputs: dict[str, Any]
    units: dict[str, str]


def _measured(record: Trajectory, states: Sequence[str], inputs: Sequence[str], velocities: Mapping[str, str],
              label: str) -> dict[str, np.ndarray]:
    """The measured columns of `record` (the states that are not derived velocities, the inputs), by name."""
    measured = [n for n in states if n not in velocities] + list(inputs)
    missing = [n for n in measured if n not in record.names]
    if missing:
        raise UnknownVariableError(f"{label} has no column {', '.join(map(repr, missing))}; available: "
                                   f"{', '.join(record.names)}")
    return {n: np.asarray(record[n], dtype=float) for n in measured}


def _stacked(values: Mapping[str, np.ndarray], t: np.ndarray, states: Sequence[str], inputs: Sequence[str],
             velocities: Mapping[str, str], derive: _Derive) -> tuple[np.ndarray, np.ndarray]:
    """States ``x`` and inputs ``u`` as arrays (one row per sample) from measured `values` at times `t`."""
    values = dict(values)
    for vel, pos in velocities.items():
        values[vel] = derive(values[pos], t, vel)
    x = np.column_stack([values[n] for n in states])
    u = np.column_stack([values[n] for n in inputs]) if inputs else np.zeros((len(x), 0))
    return x, u


def _prepare(data: Trajectory | Sequence[Trajectory], states: Sequence[str] | None,
             inputs: Sequence[str] | None, velocities: dict[str, str], derive: _Derive) -> _Records:
    """Check the records of a fit and read them; default states and inputs from the first record's roles."""
    records = [data] if isinstance(data, Trajectory) else list(data) if isinstance(data, Sequence) else None
    if not records or not all(isinstance(r, Trajectory) for r in records):
        raise InvalidSettingError("data must be a Trajectory or a non-empty list of Trajectories")
    first = records[0]
    if states is None:
        state_names = [s for s in first.states if s not in velocities]
        state_names += [v for v in velocities if v not in state_names]
    else:
        state_names = [states] if isinstance(states, str) else list(states)
    input_names = list(first.inputs) if inputs is None else ([inputs] if isinstance(inputs, str)
                                                             else list(inputs))
    if not state_names:
        raise InvalidSettingError(f"no states to identify: the data has no signal with role 'state'; pass "
                                  f"states=[...] (available: {', '.join(first.names)})")
    both = state_names + input_names
    repeated = sorted({n for n in both if both.count(n) > 1})
    if repeated:
        raise InvalidSettingError(f"{', '.join(repeated)} named more than once among states and inputs")
    for pos in velocities.values():
        if pos not in state_names and pos not in input_names:
            raise InvalidSettingError(f"velocities derives from {pos!r}, which is not among the states "
                                      f"{state_names}; add it to states")
    for vel in velocities:
        if vel not in state_names:
            raise InvalidSettingError(f"derived velocity {vel!r} is not among the states {state_names}")
    dt = None
    runs = []
    for number, record in enumerate(records):
        label = f"record {number}" if len(records) > 1 else "the data"
        values = _measured(record, state_names, input_names, velocities, label)
        if len(record) < 3:
            raise DataError(f"{label} has {len(record)} samples; identification needs a longer record")
        if not record.is_uniform():
            raise DataError(f"{label} is not uniformly sampled (steps vary by more than 1e-6 relative); "
                            "resample it to one step")
        step = record.dt
        if dt is None:
            dt = step
        elif abs(step - dt) > 1e-9 * dt:
            raise DataError(f"{label} has step {step:g} s but record 0 has {dt:g} s; all records must "
                            "have the same step (resample them)")
        for name, column in values.items():
            bad = ~np.isfinite(column)
            if bad.any():
                k = int(np.argmax(bad))
                raise DataError(f"signal {name!r} of {label} is {column[k]} at t={record.time[k]:.9g} s; "
                                "expected finite values; drop or fill the bad samples")
        runs.append(_stacked(values, record.time, state_names, input_names, velocities, derive))
    constant = {}
    for j, name in enumerate(input_names):
        column = np.concatenate([u[:-1, j] for _, u in runs])
        if np.ptp(column) <= 1e-12 * max(1.0, float(np.max(np.abs(column)))):
            constant[name] = column[0]
    keep = [j for j, n in enumerate(input_names) if n not in constant]
    input_names = [input_names[j] for j in keep]
    units = {}
    for n in state_names + input_names:
        if n in first.names:
            units[n] = first.units[first.names.index(n)]
    for vel, pos in velocities.items():
        units[vel] = f"{units.get(pos, '')}/s" if units.get(pos) else ""
    return _Records(runs=[(x, u[:, keep]) for x, u in runs], states=state_names, inputs=input_names,
                    dt=float(dt), constant_inputs=constant, units=units)


def _known_initial_states(x0: Any, state_names: Sequence[str], n_runs: int) -> list[np.ndarray] | None:
    """The initial state of each record from ``fit(x0=...)``, in state order (None: not given)."""
    if x0 is None:
        return None
    items = [x0] if isinstance(x0, Mapping) or (np.ndim(x0) == 1 and n_runs == 1) else list(x0)
    if len(items) != n_runs:
        raise InvalidSettingError(f"x0 gives {len(items)} initial states for {n_runs} records; give one per record")
    out = []
    for item in items:
        if isinstance(item, Mapping):
            missing = [s for s in state_names if s not in item]
            if missing:
                raise UnknownVariableError(f"x0 lacks {', '.join(missing)}; give a value for every state "
                                           f"({', '.join(state_names)})")
            item = [item[s] for s in state_names]
        try:
            vec = np.asarray(item, dtype=float).ravel()
        except (TypeError, ValueError):
            raise InvalidSettingError(f"x0 must hold numbers, got {item!r}") from None
        if vec.shape != (len(state_names),) or not np.all(np.isfinite(vec)):
            raise DataError(f"x0 must hold {len(state_names)} finite values ({', '.join(state_names)}), "
                            f"got {vec.tolist()}")
        out.append(vec)
    return out


def _warn_constant_inputs(constant: Mapping[str, float]) -> None:
    """Warn about each input that is constant in the data (left out of the model)."""
    for name, value in constant.items():
        warnings.warn(f"input {name!r} is constant ({value:g}) in the data: it is not persistently "
                      "exciting, so its effect cannot be identified; it is left out of the model "
                      "(excite it, or pass inputs=[...] without it)", IdentificationWarning, stacklevel=4)
