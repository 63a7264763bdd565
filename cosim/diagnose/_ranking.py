"""One screening round of :func:`~cosim.diagnose.diagnosis.diagnose`: every catalogued effect ranked by its score.

Each effect is scored on the output error (:class:`~cosim.diagnose.screening.OutputErrorScreen`) at every place
it can attach, with every row choice and over its nuisance grid; its best placement becomes an
:class:`~cosim.diagnose.candidates.EffectCandidate`. The round ranks the effects by change of BIC, a tie between
two placements going to the collocated one (``_better``), and refines the leading ones' nuisance parameters by
a bounded scalar search (``_refine``; a whole-number one, such as a delay, by trying the whole numbers between
its grid neighbours). ``_round`` is the entry.

The nuisance grids come from the record (:class:`~cosim.diagnose._record_band.RecordBand`: the screen's sample
time, length and noise levels, with the free run's signals): an effect the record cannot show at a place is
not tried there. A whole-number nuisance whose best value is its grid's last is not a finding (the truth may lie
beyond the band). An effect given a fixed nuisance (``"cogging:periods=120"``) is tried at that value only, and a
value outside the band the record shows is refused before any screening (:func:`check_effect_selection`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy import optimize

from ..errors import InvalidSettingError
from ..identify.model import IdentifiedModel
from . import _record_band as rb
from ._record_band import RecordBand
from .candidates import EffectCandidate, _uncertainty
from .effects import EFFECTS, Attachment, Effect, EffectSelection, Roles, effect_selection
from .screening import OutputErrorScreen, effect_specs, noise_level
from .user_candidates import UserEffect


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
    scores = screen.test_specs(flat)  # the score test of every spec, projected in batches
    out, k = [], 0
    for v, specs in per_value:
        best = None
        for terms, rows in specs:
            cand = _candidate(effect, attachment, v, terms, rows, scores[k], screen, alpha, bic_margin, min_size)
            k += 1
            # more rows must pay for themselves: the joint placement wins only by more than the BIC margin
            margin = bic_margin if best is not None and len(rows) > len(best.rows) else 0.0
            if best is None or cand.delta_bic < best.delta_bic - margin:
                best = cand
        if best is not None:
            out.append(best)
    return out


def _refine(screen: OutputErrorScreen, cand: EffectCandidate, alpha: float, bic_margin: float,
            min_size: float, band: RecordBand | None = None) -> EffectCandidate:
    """A bounded scalar search of the nuisance parameter between the grid neighbours of the best value."""
    effect = EFFECTS[cand.name]
    if effect.nuisance is None or cand.nuisance is None:
        return cand
    band = band if band is not None else record_band(screen)
    attachment = next(a for a in effect.attachments(screen.roles) if a.label == cand.attached_to)
    grid = [g for g in effect.grid(attachment, screen.free_run, band) if g is not None]
    if len(grid) < 2:
        return cand
    i = min(range(len(grid)), key=lambda j: abs(math.log(grid[j] / cand.nuisance)))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if lo >= hi:
        return cand
    if effect.integer:
        if hi - lo <= 2.0:  # every whole number between the neighbours is on the grid
            return cand
        return _refine_whole(screen, cand, effect, attachment, lo, hi, alpha, bic_margin, min_size)

    def cost(log_v: float) -> float:
        found = _scores(screen, effect, attachment, [float(math.exp(log_v))], alpha, bic_margin, min_size)
        return found[0].delta_bic if found else 0.0

    res = optimize.minimize_scalar(cost, bounds=(math.log(lo), math.log(hi)), method="bounded",
                                   options={"xatol": 2e-3, "maxiter": 18})
    found = _scores(screen, effect, attachment, [float(math.exp(res.x))], alpha, bic_margin, min_size)
    return found[0] if found and found[0].delta_bic < cand.delta_bic else cand


#: Most whole numbers tried in one pass of the whole-number refinement.
_WHOLE_TRIES = 12


def _refine_whole(screen: OutputErrorScreen, cand: EffectCandidate, effect: Effect, attachment: Attachment,
                  lo: float, hi: float, alpha: float, bic_margin: float, min_size: float) -> EffectCandidate:
    """The best whole number between the grid neighbours `lo` and `hi`: a batch spread over them, then every
    whole number around the best of it."""
    best, tried = cand, {float(cand.nuisance)}
    for _ in range(3):
        values = sorted({float(v) for v in np.round(np.linspace(lo, hi, _WHOLE_TRIES))} - tried)
        if not values:
            break
        tried.update(values)
        for found in _scores(screen, effect, attachment, values, alpha, bic_margin, min_size):
            if found.delta_bic < best.delta_bic:
                best = found
        spacing = (hi - lo) / (_WHOLE_TRIES - 1)
        if spacing <= 1.0:
            break
        lo, hi = max(lo, best.nuisance - math.ceil(spacing)), min(hi, best.nuisance + math.ceil(spacing))
    return best


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


def record_band(screen: OutputErrorScreen) -> RecordBand:
    """What the screen's record can show (:attr:`OutputErrorScreen.band`, made once per screen)."""
    return screen.band


def _round(screen: OutputErrorScreen, names: Sequence[str] | EffectSelection, alpha: float, bic_margin: float,
           min_size: float, refine_top: int = 3, taken: Sequence[tuple[str, str]] = (),
           band: RecordBand | None = None) -> list[EffectCandidate]:
    """One screening round: each effect's best placement and nuisance value, best first.

    `names` are catalogue names or a selection (:func:`~cosim.diagnose.effects.effect_selection`, items such as
    ``"cogging:periods=120"`` included); `band` is the record (default: from the screen, :func:`record_band`).
    """
    selection = effect_selection(names)
    band = band if band is not None else record_band(screen)
    data = screen.free_run
    if not taken:  # a fixed value the record cannot show is a setting error, before anything is screened
        _check_fixed(selection, screen.roles, data, band)
    ranking = []
    for name in selection.names:
        effect = EFFECTS[name]
        if name == "offset" and "1" in screen.model.terms:
            continue
        fixed = selection.fixed.get(name)
        best = None
        for attachment in effect.attachments(screen.roles):
            if (name, attachment.label) in taken:
                continue
            if fixed is not None:
                values = [fixed] if effect.admits(fixed, attachment, data, band) else []
            else:
                values = effect.grid(attachment, data, band)
            for cand in _scores(screen, effect, attachment, values, alpha, bic_margin, min_size):
                cand = replace(cand, fixed=fixed is not None)
                if effect.integer and fixed is None and len(values) >= 3 and cand.nuisance == values[-1]:
                    # at the top of the band: the truth may lie beyond it, and this value only stands in
                    cand = replace(cand, significant=False, explained={**cand.explained, "at_edge": 1.0})
                edge = ("at_edge" in cand.explained, "at_edge" in best.explained) if best is not None else None
                if best is None or edge == (False, True) or (edge[0] == edge[1] and _better(cand, best, screen.roles)):
                    best = cand
        if best is not None and best.rows:
            ranking.append(best)
    ranking.sort(key=lambda c: c.delta_bic)
    ranking[:refine_top] = [c if c.name in selection.fixed or "at_edge" in c.explained
                            else _refine(screen, c, alpha, bic_margin, min_size, band) for c in ranking[:refine_top]]
    ranking.sort(key=lambda c: c.delta_bic)
    return _one_reading_each(ranking)


def _one_reading_each(ranking: list[EffectCandidate]) -> list[EffectCandidate]:
    """`ranking` without a catalogue candidate that a user's candidate repeats term for term (the same features in
    the same rows: one model, one fit, not two readings the data cannot tell apart): the reading keeps the name
    the user gave it."""
    brought = {(c.terms, c.rows) for c in ranking if isinstance(EFFECTS[c.name], UserEffect)}
    return [c for c in ranking if isinstance(EFFECTS[c.name], UserEffect) or (c.terms, c.rows) not in brought]


# ---------------------------------------------------------------------------------------------- fixed values
def check_effect_selection(selection: str | Sequence[str] | EffectSelection, model: IdentifiedModel,
                           columns: Mapping[str, np.ndarray], dt: float,
                           noise: Mapping[str, float] | None = None) -> EffectSelection:
    """The parsed selection, or a one-line :class:`~cosim.errors.InvalidSettingError` when a fixed nuisance value
    (``"cogging:periods=120"``) lies outside what the data can show at every place the effect attaches to in
    `model` (a period above the record's Nyquist band or with fewer than two periods over the travel, a delay
    longer than the record allows...). Call it before any screening; `columns` are the measured data, `noise` the
    states' noise levels where known (else estimated from the data)."""
    parsed = effect_selection(selection)
    if not parsed.fixed:
        return parsed
    levels = {s: float(noise[s]) if noise and s in noise else noise_level(np.asarray(columns[s], dtype=float))
              for s in model.states if s in columns}
    motion = {**columns, **{s: rb.smoothed(np.asarray(columns[s], dtype=float), dt) for s in model.states
                            if s in columns}}
    _check_fixed(parsed, Roles.of(model), motion, RecordBand.of(motion, dt, levels, model=model))
    return parsed


def _check_fixed(selection: EffectSelection, roles: Roles, data: Mapping[str, np.ndarray], band: RecordBand) -> None:
    for name, value in selection.fixed.items():
        effect = EFFECTS[name]
        item = f"{name}:{effect.nuisance}={value:.12g}"
        places = effect.attachments(roles)
        if not places:
            raise InvalidSettingError(f"{item}: the model has no {effect.attaches_to.replace('_', ' ')} for "
                                      f"{name} to act on")
        if any(effect.admits(value, a, data, band) for a in places):
            continue
        bands = "; ".join(_describe(effect, a, data, band) for a in places)
        raise InvalidSettingError(f"{item} is outside what these data can show ({bands}); give a value in that "
                                  f"band, or {name!r} alone to search it, or record the plant over a wider range "
                                  f"or at a faster sampling")


def _describe(effect: Effect, attachment: Attachment, data: Mapping[str, np.ndarray], band: RecordBand) -> str:
    span = effect.nuisance_span(attachment, data, band)
    where = f"on {attachment.label}"
    sampled = f"{1 / band.dt:.4g} Hz sampling" if band.dt else "no sample time"
    if effect.unit == "periods":
        signal = effect.signal(attachment, data)
        speed = rb.typical_speed(rb.speed_of(signal, band))
        facts = (f"range {np.ptp(signal):.3g}, speed {speed:.3g}/s at the {rb.SPEED_PERCENTILE:.0f}th percentile, "
                 f"{sampled}")
    else:
        facts = f"{band.samples} samples, {sampled}"
    if span is None:
        return f"{where} none ({facts})"
    return f"{where} {effect.nuisance} {span[0]:.4g} to {span[1]:.4g} ({facts})"
