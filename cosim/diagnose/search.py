"""The diagnosis's search: effects chosen together, claimed when stable, fitted, and kept when they predict.

A pass (at most :data:`PASSES`, the second around the model with the first's effects) does:

1. **Select jointly** (:mod:`~cosim.diagnose.selection`): every catalogued effect at every place, in one
   linearised output-error problem with the base; a forward group selection by BIC with the samples counted by
   the residual's correlation (:func:`~cosim.diagnose.screening.correlation_factor`: a coloured residual holds
   fewer independent samples than it has).
2. **Claim** what half-samples of the record choose on at least
   :data:`~cosim.diagnose.selection.PI_CLAIM` of them (stability selection); a reading as good as another
   effect's on these data (within :data:`~cosim.diagnose.selection.EVIDENCE_MARGIN` of BIC) is reported with it
   as an ambiguity, with the experiment that would separate them (:mod:`~cosim.diagnose.ambiguity`).
3. **Fit** each claim for real (Gauss-Newton output error with its nuisance parameter,
   :func:`~cosim.diagnose._trials._fit_with`) and keep it only if the fit is physically possible and it lowers
   the free-run error on **held-out** data (:class:`~cosim.diagnose._holdout.HeldOutCheck`): the last word.
   A base term an effect made redundant (a spring standing in for friction) then goes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import DataError
from ..identify.model import IdentifiedModel
from ._holdout import HeldOutCheck
from ._ranking import record_band
from ._trials import _fit_with, _FitOptions, _retest_base, _write_back
from .ambiguity import Ambiguity, ambiguity_of
from .candidates import EffectCandidate
from .effects import EffectSelection
from .screening import OutputErrorScreen, correlation_factor
from .selection import PI_CLAIM, Gram, Option, equivalents, forward_select, library, stability

__all__ = ["PASSES", "SearchResult", "search"]

#: Most passes of the search: each adds at most one effect, and the next screens around the model with it (the
#: linearisation around a model that lacks a large effect misjudges the smaller ones).
PASSES = 4


@dataclass
class SearchResult:
    """What the search found (see :func:`search`)."""

    model: IdentifiedModel
    accepted: list[EffectCandidate] = field(default_factory=list)
    nuisances: list = field(default_factory=list)
    owners: list[int] = field(default_factory=list)
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    rounds: list[tuple[EffectCandidate, ...]] = field(default_factory=list)
    trials: list[tuple[EffectCandidate, ...]] = field(default_factory=list)
    steps: list[tuple[tuple[str, ...], IdentifiedModel]] = field(default_factory=list)
    rejected: list[EffectCandidate] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)
    ambiguous: list[Ambiguity] = field(default_factory=list)
    stability: list[dict[str, Any]] = field(default_factory=list)


def _candidate(option: Option, delta_bic: float, probability: float) -> EffectCandidate:
    return EffectCandidate(option.effect.name, option.attachment.label, option.rows, option.value, option.terms,
                           delta_bic, math.nan, {"selection_probability": probability}, True,
                           meaning=option.effect.meaning, coefficients=option.coefficients)


def _n_eff(gram: Gram, screen: OutputErrorScreen, max_groups: int) -> float:
    """The samples the joint fit's residual holds: its count over the correlation factor of the residual the
    whole record's selection leaves (a model error left over thins the samples; a white residual does not)."""
    G, g, yy = gram.whole
    picked = forward_select(G, g, yy, screen.n_obs, base=gram.base, groups=gram.groups, max_groups=max_groups)
    cols = list(gram.base) + [i for k in picked for i in gram.groups[k]]
    fitted = gram.fitted(cols)
    n_states = len(screen.model.states)
    left = (screen.residual - fitted).reshape(-1, n_states)
    return screen.n_obs / correlation_factor(left[:, screen.weight > 0])


def search(base: IdentifiedModel, columns: dict[str, np.ndarray], dt: float, fit: _FitOptions,
           selection: EffectSelection, max_effects: int, check: HeldOutCheck | None, bar: Any = None) -> SearchResult:
    """Effects for `base` in `columns` (see the module notes): the model with them and what was tried."""
    out = SearchResult(model=base, columns=dict(columns))
    for _ in range(PASSES):
        left = max_effects - len(out.accepted)
        if left <= 0:
            break
        try:
            screen = OutputErrorScreen(out.model, dict(out.columns), dt, **fit.kw)
        except DataError:
            if not out.accepted:
                raise
            break
        band = record_band(screen)
        options = library(screen, selection, band, taken=[(c.name, c.attached_to) for c in out.accepted])
        if bar is not None:
            bar.set_postfix_str(f"selecting among {len(options)} candidates")
        if not options:
            break
        gram = Gram(screen, options)
        n_eff = _n_eff(gram, screen, left)
        stab = stability(gram, n_eff, left)
        same = equivalents(gram, options, stab.chosen, n_eff)
        ranked = sorted(range(len(options)), key=lambda k: (options[k].delta_bic, k))
        out.rounds.append(tuple(_candidate(options[k], options[k].delta_bic, stab.probability[k]) for k in ranked))
        out.stability.append({"options": len(options), "n_eff": n_eff, "per_half": stab.per_half,
                              "expected_false_claims_bound": stab.bound(len(options)),
                              "chosen": [{"effect": options[k].effect.name, "attached_to": options[k].attachment.label,
                                          "probability": stab.probability[k]} for k in stab.chosen]})
        claims = []
        for k in stab.chosen:
            other = same.get(k)
            probability = stab.probability[k] + (stab.probability[other] if other is not None else 0.0)
            if probability < PI_CLAIM:
                continue
            claims.append(k)
            if other is not None:
                out.ambiguous.append(ambiguity_of(options[k], options[other], screen, band))
        if bar is not None:
            bar.update(1)
        added = _fit_claims(out, [options[k] for k in claims], [stab.probability[k] for k in claims], dt, fit,
                            check, base)
        if not added:
            break
    return out


def _fit_claims(out: SearchResult, claims: list[Option], probabilities: list[float], dt: float, fit: _FitOptions,
                check: HeldOutCheck | None, base: IdentifiedModel) -> int:
    """Fit every claim for real onto `out`'s model; add the one whose fit lowers BIC most (ties: the
    selection's order) among those that are physically possible and that held-out data confirm. Returns 1 if
    one was added, else 0."""
    try:
        screen = OutputErrorScreen(out.model, dict(out.columns), dt, **fit.kw)
    except DataError:
        return 0
    trials = []
    for option, probability in zip(claims, probabilities, strict=True):
        trial = _fit_with(out.model, _candidate(option, option.delta_bic, probability), out.columns, dt,
                          out.nuisances, screen, 1.0, -math.inf, 0.0, fit)
        if trial is not None:
            trials.append(trial)
    out.trials.append(tuple(t.candidate for t in trials))
    order = sorted(range(len(trials)), key=lambda k: (round(trials[k].candidate.delta_bic, 6), k))
    for k in order:
        trial = trials[k]
        if not trial.candidate.explained.get("plausible", True) or not trial.candidate.delta_bic < 0.0:
            out.rejected.append(trial.candidate)
            continue
        if check is not None:
            evidence = check.judge(out.model, trial.model, {**out.columns, **trial.new_columns})
            trial.candidate = replace(trial.candidate, explained={**trial.candidate.explained,
                                                                  **evidence.as_explained()})
            if not evidence.passed:
                out.rejected.append(trial.candidate)
                continue
        out.accepted.append(trial.candidate)
        if trial.nuisance is not None:
            out.owners.append(len(out.accepted) - 1)
        out.model, out.nuisances = trial.model, trial.nuisances
        out.columns.update(trial.new_columns)
        out.model, out.nuisances, gone = _retest_base(out.model, base, out.columns, dt, out.nuisances, fit)
        out.dropped += gone
        _write_back(out.accepted, out.owners, out.nuisances)
        out.steps.append((tuple(c.name for c in out.accepted), out.model))
        return 1
    return 0
