"""A model's free run on data records and its scaled residual: the pieces the screening and the fits share.

Records (``segments``: each record's start in the concatenated columns) each run from their own initial state;
the residual of each state is scaled by its noise level (:func:`noise_level`, from second differences), and a
state that is not a measurement (``measured``) counts nowhere: its scale is 0 (:func:`measured_weights`).
:func:`correlation_factor` says how many samples of a coloured residual carry one sample's information.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..data.datafile import derived_velocities
from ..data.trajectory import Trajectory
from ..errors import InvalidSettingError
from ..identify.model import IdentifiedModel

__all__ = ["checked_noise", "correlation_factor", "free_run_cost", "free_run_residual", "measured_states",
           "measured_weights", "noise_level"]


def _bounds(segments: Sequence[int] | None, length: int) -> list[tuple[int, int]]:
    """(start, stop) of each record in columns of `length` samples, checked."""
    if segments is None:
        return [(0, length)]
    starts = [int(s) for s in segments]
    if not starts or starts[0] != 0 or any(b - a < 2 for a, b in zip(starts, [*starts[1:], length], strict=True)):
        raise InvalidSettingError(f"segments must be increasing start indices from 0, each record at least 2 "
                                  f"samples long, within {length} samples; got {list(segments)}")
    return list(zip(starts, [*starts[1:], length], strict=True))


def _matrices(model: IdentifiedModel, columns: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The model's states (samples, n) and inputs (samples, inputs) from the columns."""
    X = np.column_stack([np.asarray(columns[s], dtype=float) for s in model.states])
    U = np.column_stack([np.asarray(columns[u], dtype=float) for u in model.inputs]) if model.inputs \
        else np.zeros((len(X), 0))
    return X, U


def _starts(x0: Any, n_segments: int, n: int) -> np.ndarray:
    """Initial states as given, checked: (n,) for one record, (records, n) for several."""
    start = np.asarray(x0, dtype=float)
    if n_segments == 1 and start.shape == (1, n):
        start = start[0]
    want = (n,) if n_segments == 1 else (n_segments, n)
    if start.shape != want:
        raise InvalidSettingError(f"x0 must hold {n} values per record ({n_segments} record(s)), shape {want}; "
                                  f"got shape {start.shape}")
    return start


def _simulate(model: IdentifiedModel, U: np.ndarray, dt: float, start: np.ndarray,
              bounds: Sequence[tuple[int, int]]) -> tuple[np.ndarray | None, str]:
    """Each record's free run from its initial state, one after the other (None and why, if one diverges)."""
    if len(bounds) == 1:
        sim = model.simulate(start, U[:-1], dt=dt)
        return (sim.states, "") if sim.ok else (None, sim.message)
    parts = []
    for (a, b), x0 in zip(bounds, start, strict=True):
        sim = model.simulate(x0, U[a:b - 1], dt=dt)
        if not sim.ok:
            return None, sim.message
        parts.append(sim.states)
    return np.concatenate(parts), ""


def noise_level(y: np.ndarray, segments: Sequence[int] | None = None) -> float:
    """Standard deviation of white measurement noise on a smooth signal, from its second differences (MAD);
    with `segments`, of each record's second differences (none across a record boundary)."""
    y = np.asarray(y, dtype=float)
    d2 = np.concatenate([np.diff(y[a:b], 2) for a, b in _bounds(segments, len(y))]) if segments is not None \
        else np.diff(y, 2)
    if d2.size == 0:
        return 1.0
    mad = float(np.median(np.abs(d2 - np.median(d2)))) * 1.4826
    sigma = mad / math.sqrt(6.0)
    return sigma if sigma > 0 else max(float(np.std(y)) * 1e-6, 1e-300)


def measured_weights(states: Sequence[str], measured: Sequence[str] | None) -> np.ndarray:
    """1 for each state that is measured, 0 for the others (`measured` None: all are), checked."""
    if measured is None:
        return np.ones(len(states))
    names = [measured] if isinstance(measured, str) else [str(m) for m in measured]
    unknown = [m for m in names if m not in states]
    if unknown or not names:
        raise InvalidSettingError(f"measured must name at least one of the model's states ({', '.join(states)}); "
                                  f"got {list(names)}")
    return np.array([1.0 if s in names else 0.0 for s in states])


def _free_run(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, x0: Any,
              segments: Sequence[int] | None) -> np.ndarray | None:
    """The states of `model`'s free run of each record (None if it diverges)."""
    _, U = _matrices(model, columns)
    bounds = _bounds(segments, len(U))
    return _simulate(model, U, dt, _starts(x0, len(bounds), len(model.states)), bounds)[0]


def _cost(run: np.ndarray | None, columns: Mapping[str, np.ndarray], model: IdentifiedModel,
          scale: np.ndarray) -> float:
    """Sum of squares of the free run's error, each state's multiplied by `scale` (1/sigma, 0 if unmeasured)."""
    if run is None:
        return math.inf
    r = (_matrices(model, columns)[0] - run) * scale
    return float(np.sum(r * r))


def free_run_residual(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, x0: Sequence[float],
                      sigma: np.ndarray, *, segments: Sequence[int] | None = None,
                      measured: Sequence[str] | None = None) -> np.ndarray | None:
    """Free-run residual of `model` from `x0`, each state scaled by its noise level (None if it diverges).

    With `segments`, each record runs from its own initial state (`x0`: one per record, shape (records, n)).
    The columns of states not in `measured` (None: all are) are zero.
    """
    run = _free_run(model, columns, dt, x0, segments)
    scale = measured_weights(model.states, measured) / np.asarray(sigma, dtype=float)
    return None if run is None else (_matrices(model, columns)[0] - run) * scale


def free_run_cost(model: IdentifiedModel, columns: Mapping[str, np.ndarray], dt: float, x0: np.ndarray,
                  sigma: np.ndarray, *, segments: Sequence[int] | None = None,
                  measured: Sequence[str] | None = None) -> float:
    """Scaled free-run cost of `model` from `x0` (inf if it diverges); `segments` and `measured` as
    :func:`free_run_residual`."""
    scale = measured_weights(model.states, measured) / np.asarray(sigma, dtype=float)
    return _cost(_free_run(model, columns, dt, x0, segments), columns, model, scale)


def correlation_factor(residual: np.ndarray, lags: int = 50) -> float:
    """How many samples of a residual carry one sample's worth of information: its long-run variance over its
    variance, ``1 + 2 sum_k (1 - k/(L+1)) rho_k`` (Bartlett weights, L lags), averaged over the columns, at
    least 1.

    Tests that treat a coloured residual as white overstate their evidence by this factor: a model that
    leaves a slow, structured error (an effect the catalogue lacks) makes chance correlations look
    significant. Dividing the sample count by it keeps them honest; after a right effect the residual is
    white and the factor is about 1.
    """
    r = np.atleast_2d(np.asarray(residual, dtype=float).T).T
    n = r.shape[0]
    lags = max(1, min(lags, n // 20))
    weights = 1.0 - np.arange(1, lags + 1) / (lags + 1)
    factors = []
    for col in r.T:
        c = col - col.mean()
        var = float(c @ c)
        if var <= 0.0:
            continue
        rho = np.array([float(c[k:] @ c[:-k]) / var for k in range(1, lags + 1)])
        factors.append(1.0 + 2.0 * float(weights @ rho))
    return max(1.0, float(np.mean(factors))) if factors else 1.0


def checked_noise(model: IdentifiedModel, noise: Mapping[str, float] | None) -> dict[str, float] | None:
    """`diagnose`'s `noise`, checked: positive levels of the model's states."""
    if not noise:
        return None
    for name, level in noise.items():
        if name not in model.states:
            raise InvalidSettingError(f"noise names {name!r}, which is not a state of the model; states are "
                                      f"{list(model.states)}")
        if not (math.isfinite(float(level)) and float(level) > 0):
            raise InvalidSettingError(f"the noise level of {name!r} must be positive, got {level}")
    return {name: float(level) for name, level in noise.items()}


def measured_states(model: IdentifiedModel, records: Sequence[Trajectory],
              noise: Mapping[str, float] | None) -> tuple[str, ...] | None:
    """The states that are measurements: all but the velocities derived from measured positions (their
    derivative filter's output is no measurement and would count the position's noise twice), unless a noise
    level is given for one. None when all are measured."""
    derived: set[str] = set()
    for record in records:
        derived.update(derived_velocities(record))
    derived -= set(noise or ())
    measured = tuple(s for s in model.states if s not in derived)
    return None if len(measured) == len(model.states) or not measured else measured
