"""One screening round of :func:`~cosim.diagnose.diagnosis.diagnose`: every catalogued effect ranked by its score.

Each effect is scored on the output error (:class:`~cosim.diagnose.screening.OutputErrorScreen`) at every place
it can attach, with every row choice and over its nuisance grid; its best placement becomes an
:class:`~cosim.diagnose.candidates.EffectCandidate`. The round ranks the effects by change of BIC, a tie between
two placements going to the collocated one (``_better``), and refines the leading ones' nuisance parameters by
a bounded scalar search (``_refine``). ``_round`` is the entry.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import optimize

from .candidates import EffectCandidate, _uncertainty
from .effects import EFFECTS, Attachment, Effect, Roles
from .screening import OutputErrorScreen, effect_specs


def _candidate(effect: Effect, attachment: Attachment, value: float | None, terms: tuple[str, ...],
               rows: tuple[str, ...], score: dict[str, Any], screen: OutputErrorScreen, alpha: float,
               bic_margin: float, min_size: float) -> EffectCandidate:
    coef, se = {}, {}
    if score["coef"] is not None:
        q = len(terms)
        for r_i, row in enumerate(rows):
            coef[row] = score["coef"][r_i * q:(r_i + 1) * q]
            se[row] = score["se"][r_i * q:(r_i + 1) * q]
    placed = Attachment(attachment.label, attachment.signals, rows)
    params = effect.parameters(coef, value, screen.roles, placed) if coef else {}
    significant = bool(score["p_value"] < alpha and score["delta_bic"] < -bic_margin and score["size"] >= min_size)
    return EffectCandidate(effect.name, attachment.label, rows, value, terms, score["delta_bic"], score["p_value"],
                           {"size": score["size"]}, significant, parameters=params,
                           uncertainty=_uncertainty(effect, coef, np.diag(np.concatenate(list(se.values())) ** 2)
                                                    if se else None, value, screen.roles, placed),
                           meaning=effect.meaning,
                           coefficients=tuple(float(c) for c in score["coef"]) if score["coef"] is not None else ())


def _scores(screen: OutputErrorScreen, effect: Effect, attachment: Attachment, values: Sequence[float | None],
            alpha: float, bic_margin: float, min_size: float) -> list[EffectCandidate]:
    """The best row choice of the effect at `attachment` for each nuisance value (one batched integration)."""
    per_value = [(v, effect_specs(effect, attachment, v, screen)) for v in values]
    flat = [spec for _, specs in per_value for spec in specs]
    if not flat:
        return []
    sens = screen.candidate_sensitivities(flat)
    out, k = [], 0
    for v, specs in per_value:
        best = None
        for terms, rows in specs:
            cand = _candidate(effect, attachment, v, terms, rows, screen.test(sens[k]), screen, alpha, bic_margin,
                              min_size)
            k += 1
            # more rows must pay for themselves: the joint placement wins only by more than the BIC margin
            margin = bic_margin if best is not None and len(rows) > len(best.rows) else 0.0
            if best is None or cand.delta_bic < best.delta_bic - margin:
                best = cand
        if best is not None:
            out.append(best)
    return out


def _refine(screen: OutputErrorScreen, cand: EffectCandidate, alpha: float, bic_margin: float,
            min_size: float) -> EffectCandidate:
    """A bounded scalar search of the nuisance parameter between the grid neighbours of the best value."""
    effect = EFFECTS[cand.name]
    if effect.nuisance is None or effect.integer or cand.nuisance is None:
        return cand
    attachment = next(a for a in effect.attachments(screen.roles) if a.label == cand.attached_to)
    grid = [g for g in effect.grid(attachment, screen.free_run) if g is not None]
    i = min(range(len(grid)), key=lambda j: abs(math.log(grid[j] / cand.nuisance)))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if lo >= hi:
        return cand

    def cost(log_v: float) -> float:
        found = _scores(screen, effect, attachment, [float(math.exp(log_v))], alpha, bic_margin, min_size)
        return found[0].delta_bic if found else 0.0

    res = optimize.minimize_scalar(cost, bounds=(math.log(lo), math.log(hi)), method="bounded",
                                   options={"xatol": 2e-3, "maxiter": 18})
    found = _scores(screen, effect, attachment, [float(math.exp(res.x))], alpha, bic_margin, min_size)
    return found[0] if found and found[0].delta_bic < cand.delta_bic else cand


#: Two placements whose BIC changes differ by less than this (or 0.2 %) are told apart by collocation.
TIE_BIC = 2.0


def _collocated(cand: EffectCandidate, roles: Roles) -> bool:
    """The effect acts in the equation of the signal it reads (gravity of the load in the load's equation)."""
    own = roles.velocity_of.get(cand.attached_to, cand.attached_to)
    return cand.rows == (own,)


def _better(cand: EffectCandidate, best: EffectCandidate, roles: Roles) -> bool:
    """`cand` explains more than `best`; in a tie (two positions a stiff coupling keeps together, whose data
    cannot tell apart) the collocated placement wins."""
    tie = max(TIE_BIC, 0.002 * abs(best.delta_bic))
    if abs(cand.delta_bic - best.delta_bic) < tie and _collocated(cand, roles) != _collocated(best, roles):
        return _collocated(cand, roles)
    return cand.delta_bic < best.delta_bic


def _round(screen: OutputErrorScreen, names: Sequence[str], alpha: float, bic_margin: float, min_size: float,
           refine_top: int = 3, taken: Sequence[tuple[str, str]] = ()) -> list[EffectCandidate]:
    """One screening round: each effect's best placement and nuisance value, best first."""
    ranking = []
    for name in names:
        effect = EFFECTS[name]
        if name == "offset" and "1" in screen.model.terms:
            continue
        best = None
        for attachment in effect.attachments(screen.roles):
            if (name, attachment.label) in taken:
                continue
            values = effect.grid(attachment, screen.free_run)
            for cand in _scores(screen, effect, attachment, values, alpha, bic_margin, min_size):
                if best is None or _better(cand, best, screen.roles):
                    best = cand
        if best is not None and best.rows:
            ranking.append(best)
    ranking.sort(key=lambda c: c.delta_bic)
    ranking[:refine_top] = [_refine(screen, c, alpha, bic_margin, min_size) for c in ranking[:refine_top]]
    ranking.sort(key=lambda c: c.delta_bic)
    return ranking
