"""A leading candidate's trial fit in :func:`~cosim.diagnose.diagnosis.diagnose`, from several starts where one
is not enough.

The screening picks an effect's nuisance value on the base model's sensitivities, to first order; the trial fit
from there can settle in a local minimum when the effect is large beside the noise or the base's free run
drifts. For an effect with :attr:`~cosim.diagnose.effects.Effect.multistart`:

* a continuous nuisance (a Stribeck velocity, whose fit's basin spans about a factor 3, the grid's step) is
  started from every value of its grid, :data:`START_ITERATIONS` each;
* a whole-number one (a cogging's periods per revolution, whose score over the periods is nearly flat on a
  drifting two-mass free run: record 83 of the generalisation benchmark scores 65 periods at -17 800 and the
  true 19 at -15 800 to -17 100, and their trial fits give -315 and -19 976) is started from the best-scoring
  values, :data:`PEAKS` more at every place it attaches, each a peak of the score (not next to a better value).

An effect on an input whose base took it up elsewhere (a delay) is also started from the base identified again
with the effect's input copies; an effect on states whose trial realises less than half of the BIC change its
screening promised (:func:`_unrealised`), from the equation-error fit of the base's terms and its own
(:mod:`._joint_start`). For a round's two leading candidates while none has paid off, one that still
realises less than half of its promise is also started from the base identified again with its terms
(:func:`~._joint_start.identified_start`): on the generalisation benchmark's two-mass drives with a strong
cogging or Stribeck friction the linear base takes the effect up in its shaft (the twist mode missing, its
free run at 2.5-6.4 times the noise's cost), and only the identification's multi-start finds the plant
(records 45, 148, 150, 165: 0.97-1.15 times).

The lowest output error is kept. A fit that ends at a value the record does not show
(:attr:`~cosim.diagnose.effects.Effect.shown`: a Stribeck velocity the speeds never reach twice of, a Coulomb
friction fading at the top speed) is not kept; when none is left, the candidate is not significant.

The round's trials are then taken best first, except that gravity goes before a softening spring to ground it
ties with (``_bounded_first``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..identify.model import IdentifiedModel
from . import _record_band as rb
from ._joint_start import has_joint_start, has_state_start, identified_start, joint_start
from ._ranking import TIE_BIC, _scores, record_band
from ._record_band import RecordBand
from ._trials import _cost_of, _final_parameters, _fit_with, _FitOptions, _Trial
from .candidates import EffectCandidate
from .effects import EFFECTS, Effect
from .screening import Nuisance, OutputErrorScreen

#: Gauss-Newton iterations of each start of a continuous nuisance's fit. From a start a grid step away a
#: Stribeck fit takes 5-8 to reach its basin's floor when the base model has not taken the effect up; when it
#: has (a damping and a stiffness bent towards the friction), the base's terms must give it back along a
#: curved valley first: 20-30 (record 25 of the generalisation benchmark: after 8 iterations the start at the
#: true vs = 5.5 is still at 4713, above a wrong start's 4184; after 25 it is at 3083).
START_ITERATIONS = 25
#: Best-scoring values of a whole-number nuisance tried at each place, besides the screening's.
PEAKS = 2


def trial_fit(current: IdentifiedModel, cand: EffectCandidate, columns: dict[str, np.ndarray], dt: float,
              nuisances: list[Nuisance], screen: OutputErrorScreen, alpha: float, bic_margin: float,
              min_size: float, fit: _FitOptions, names: Sequence[str], iterations: int,
              band: RecordBand | None = None, realised: float = 0.0, identify_again: bool = False
              ) -> _Trial | None:
    """`cand` fitted with `iterations` Gauss-Newton steps, from several starts if its effect asks (module notes).

    `names` is the effect selection: a nuisance value the user fixed (``"stribeck:vs=0.3"``) is not searched;
    `band` what the record shows (default: from the screen, as the round's ranking had it); `realised` the best
    BIC change a trial of the round has realised so far: a re-identified start, which costs an identification,
    is made only for a candidate whose screening promises more (it could not come first otherwise);
    `identify_again` allows the start from the base identified again with the effect's terms (a few seconds)."""
    effect = EFFECTS[cand.name]
    searched = effect.multistart and cand.nuisance is not None \
        and not any(n.startswith(cand.name + ":") for n in names)
    if not searched:
        trial = _fit_with(current, cand, columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit,
                          iterations=iterations)
        if cand.delta_bic < realised and (has_joint_start(cand.name)
                                          or (has_state_start(cand.name) and _unrealised(trial, cand))):
            trial = _joint(trial, current, cand, columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit,
                           iterations)
        return _identified(trial, current, cand, columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit,
                           iterations, realised) if identify_again else trial
    band = band if band is not None else record_band(screen)
    if effect.integer:
        starts = [cand, *_score_peaks(screen, effect, cand, band, alpha, bic_margin, min_size)]
    else:
        grid = effect.grid(cand.placement, screen.free_run, band)
        starts = [cand] + [replace(cand, nuisance=v, coefficients=()) for v in grid
                           if v is not None and abs(math.log(v / cand.nuisance)) >= 0.5 * math.log(rb.LOG_STEP)]
        iterations = max(iterations, START_ITERATIONS)
    first, best = None, None
    for k, start in enumerate(starts):
        trial = _fit_with(current, start, columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit,
                          iterations=iterations)
        first = trial if k == 0 else first
        if trial is None or (effect.shown is not None and not effect.shown(
                trial.candidate.nuisance, effect.signal(trial.candidate.placement, screen.free_run))):
            continue
        if best is None or _cost_of(trial.model) < _cost_of(best.model):
            best = trial
    if best is None and first is not None:  # every fit left what the record shows
        first.candidate = replace(first.candidate, significant=False,
                                  explained={**first.candidate.explained, "outside_band": 1.0})
        return first
    if not identify_again:
        return best
    return _identified(best, current, replace(cand, nuisance=best.candidate.nuisance) if best is not None else cand,
                       columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit, iterations, realised)


def _identified(trial: _Trial | None, current: IdentifiedModel, cand: EffectCandidate,
                columns: dict[str, np.ndarray], dt: float, nuisances: list[Nuisance], screen: OutputErrorScreen,
                alpha: float, bic_margin: float, min_size: float, fit: _FitOptions, iterations: int,
                realised: float) -> _Trial | None:
    """`trial`, or when it realised less than half of what its screening promised (and the promise could put it
    first), the better of it and the trial from the base identified again with the effect's terms
    (:func:`~._joint_start.identified_start`: a second or few, so only then)."""
    if not (has_state_start(cand.name) and cand.delta_bic < realised and _unrealised(trial, cand)):
        return trial
    return _joint(trial, current, cand, columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit, iterations,
                  starting=identified_start)


def _unrealised(trial: _Trial | None, cand: EffectCandidate) -> bool:
    """Whether the trial fit realised less than half the BIC change the screening promised."""
    return trial is None or not trial.candidate.significant or trial.candidate.delta_bic > 0.5 * cand.delta_bic


def _joint(trial: _Trial | None, current: IdentifiedModel, cand: EffectCandidate, columns: dict[str, np.ndarray],
           dt: float, nuisances: list[Nuisance], screen: OutputErrorScreen, alpha: float, bic_margin: float,
           min_size: float, fit: _FitOptions, iterations: int, starting=joint_start) -> _Trial | None:
    """The better of `trial` and the trial started from the base re-identified with the effect's input copies
    or refitted by equation error with its terms (`starting`: :func:`~._joint_start.joint_start`; or identified
    again with its terms, :func:`~._joint_start.identified_start`); the winner remembers its start for the fit
    to convergence."""
    start = starting(current, cand, columns, dt, fit.segments)
    if start is None:
        return trial
    other = _fit_with(start[0], start[1], columns, dt, nuisances, screen, alpha, bic_margin, min_size, fit,
                      iterations=iterations, own_start=True)
    if other is None or (trial is not None and _cost_of(trial.model) <= _cost_of(other.model)):
        return trial
    other.start = start[0]
    return other


def _score_peaks(screen: OutputErrorScreen, effect: Effect, cand: EffectCandidate, band, alpha: float,
                 bic_margin: float, min_size: float) -> list[EffectCandidate]:
    """At every place `effect` attaches, the :data:`PEAKS` best-scoring whole-number values of its nuisance that
    are peaks of the score (no neighbour scores better), other than `cand`'s own."""
    out = []
    for attachment in effect.attachments(screen.roles):
        values = effect.grid(attachment, screen.free_run, band)
        scored = {c.nuisance: c for c in _scores(screen, effect, attachment, values, alpha, bic_margin, min_size)}
        peaks = [c for v, c in scored.items()
                 if all(scored[n].delta_bic >= c.delta_bic for n in (v - 1, v + 1) if n in scored)
                 and not (attachment.label == cand.attached_to and v == cand.nuisance)]
        out += sorted(peaks, key=lambda c: c.delta_bic)[:PEAKS]
    return out


def _bounded_first(trials: list[_Trial], n_obs: int) -> list[_Trial]:
    """Trials best first, except that gravity goes before a softening spring to ground it ties with.

    A cubic spring to ground with ``k3 < 0`` (softening) and gravity (the sine of an angle) bend a restoring
    force the same way, ``sin x = x - x^3/6 + ...``: over a travel of a radian or two they fit alike, the
    spring one parameter cheaper (gravity has a phase). Beyond the travel the softening spring turns over and
    the model runs away; the sine stays bounded. So when the gravity trial's BIC change is within one
    parameter's price (``log n``, plus :data:`~cosim.diagnose._ranking.TIE_BIC`) of the softening spring's, the
    bounded explanation is taken first. A hardening spring, or a gravity trial that fits worse by more, keeps
    the order.
    """
    if len(trials) < 2:
        return trials
    top = trials[0]
    cand = top.candidate
    if cand.name != "cubic_stiffness" or "-" in cand.attached_to:
        return trials
    if not _final_parameters(cand, top.model).parameters.get("k3", 0.0) < 0.0:
        return trials
    n_eff = n_obs / max(float(cand.explained.get("correlation_factor", 1.0)), 1.0)
    price = math.log(n_eff) + TIE_BIC
    for j, trial in enumerate(trials[1:], start=1):
        if trial.candidate.name == "gravity" and trial.candidate.delta_bic < cand.delta_bic + price:
            return [trial, *trials[:j], *trials[j + 1:]]
    return trials
