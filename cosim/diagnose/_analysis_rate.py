"""The rate a diagnosis searches at: a long record sampled far faster than its band is decimated first.

Every screening, trial fit and held-out check of :func:`~cosim.diagnose.diagnosis.diagnose` simulates the model
and its sensitivities over every sample; its time grows with the record's length, and a 20 000-sample record at
1 kHz of a plant whose motion stands above the noise up to 30 Hz holds about three times more samples than its
content needs. System identification's usual rate is about ten times the band (Ljung, *System Identification*,
2nd ed., section 13.7), so the search runs at ``decimate="auto"``'s factor:

* the band is the highest frequency at which any of the model's states stands above its noise in any record
  (:func:`~cosim.data.decimation.signal_bandwidth`: a friction's harmonics or a cogging's ripple widen it as far
  as they are seen), or the model's fastest mode (its linear part's largest eigenvalue modulus over 2 pi) if
  higher: the search's rate stays at least ten times that
  (:data:`~cosim.data.decimation.RATE_PER_BAND`);
* a record is never brought below 4000 samples (all records together,
  :data:`~cosim.data.decimation.WORK_SAMPLES`): below that the search is fast already, and fewer samples leave
  the held-out check's halves and the nuisance grids coarse.

The search's result is then refitted at the record's own rate (:func:`~cosim.diagnose.diagnosis.diagnose`), so
the parameters and the before/after figures are those of the data as given.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..data.decimation import decimation_factor
from ..data.trajectory import Trajectory
from ..errors import DataError, InvalidSettingError
from ..identify._stability import fastest_mode_hz
from ..identify.model import IdentifiedModel
from ._trials import _FitOptions
from .candidates import EffectCandidate
from .effects import EFFECTS, delayed_name
from .screening import Nuisance, output_error_fit


def analysis_factor(model: IdentifiedModel, records: Sequence[Trajectory], decimate: int | str, *,
                    min_samples: int) -> int:
    """The decimation factor of the search: `decimate` itself when an integer, else chosen from the data
    (:func:`~cosim.data.decimation.decimation_factor` of the model's states, with the model's fastest mode;
    never leaving a record fewer than `min_samples` samples).

    Raises
    ------
    InvalidSettingError
        `decimate` neither ``"auto"`` nor a positive integer, or so large that a record keeps fewer than
        `min_samples` samples.
    """
    if isinstance(decimate, str):
        if decimate != "auto":
            raise InvalidSettingError(f'decimate must be "auto" or a positive integer, got {decimate!r}')
        return decimation_factor([r[list(model.states)].reshape(len(r), -1) for r in records], records[0].dt,
                                 mode_hz=fastest_mode_hz(model), min_samples=min_samples)
    if isinstance(decimate, bool) or not isinstance(decimate, (int, np.integer)) or decimate < 1:
        raise InvalidSettingError(f'decimate must be "auto" or a positive integer, got {decimate!r}')
    shortest = min(len(r) for r in records)
    if -(-shortest // int(decimate)) < min_samples:
        raise InvalidSettingError(f"decimating by {decimate} leaves {-(-shortest // int(decimate))} samples of a "
                                  f"{shortest}-sample record; a diagnosis needs {min_samples}: use a smaller "
                                  "factor")
    return int(decimate)


def at_record_rate(model: IdentifiedModel, accepted: Sequence[EffectCandidate], nuisances: Sequence[Nuisance],
                   columns: dict[str, np.ndarray], dt: float, fit: _FitOptions, factor: int,
                   ) -> tuple[IdentifiedModel, list[EffectCandidate], list[Nuisance], dict[str, np.ndarray]]:
    """The search's model (found at ``factor`` times the record's step) refitted on the record's own `columns`
    and step: the model, the effects, the nuisances and the columns the effects add at the record's rate.

    The model is a differential equation, the same at any step, except for a delay, whose taps are inputs held
    ``d`` and ``d + 1`` steps back: they are placed again at the record's step, at the delay the search found
    (the centroid of its taps, times the factor), their weight shared between the two so the centroid stays.
    If the refit fails, the search's model is kept (with the taps placed again).
    """
    terms, coef, inputs = list(model.terms), model.coef.copy(), list(model.inputs)
    found, added = list(accepted), {}
    for j, cand in enumerate(found):
        if not EFFECTS[cand.name].columns(cand.placement, cand.nuisance, columns):
            continue  # (an effect without columns of its own is the same at any step)
        signal, d = cand.placement.signals[0], int(round(cand.nuisance or 0))
        taps = [terms.index(delayed_name(signal, d + i)) for i in (0, 1)]
        weight = coef[:, taps].sum(axis=1)
        row = int(np.argmax(np.abs(weight)))
        centroid = (d * coef[row, taps[0]] + (d + 1) * coef[row, taps[1]]) / weight[row] * factor \
            if weight[row] != 0.0 else float(d * factor)
        centroid = max(centroid, 1.0)  # (tap 0 would be the input itself)
        whole = int(math.floor(centroid))
        share = centroid - whole
        coef[:, taps[0]], coef[:, taps[1]] = weight * (1.0 - share), weight * share
        renamed = {terms[k]: delayed_name(signal, whole + i) for i, k in enumerate(taps)}  # both at once
        terms = [renamed.get(name, name) for name in terms]
        inputs = [renamed.get(name, name) for name in inputs]  # (the taps are inputs of the model too)
        found[j] = replace(cand, nuisance=float(whole), terms=(terms[taps[0]], terms[taps[1]]))
        added.update(EFFECTS[cand.name].columns(cand.placement, float(whole), columns))
    placed = IdentifiedModel(states=model.states, inputs=tuple(inputs), terms=tuple(terms), coef=coef, dt=dt,
                             units=model.units, meta=model.meta)
    try:
        refitted, _, nuis = output_error_fit(placed, {**columns, **added}, dt, nuisances=nuisances, **fit.kw)
    except (DataError, np.linalg.LinAlgError, FloatingPointError):
        return placed, found, list(nuisances), added
    return refitted, found, nuis, added
