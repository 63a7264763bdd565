"""A trial's second start: the base re-identified with the effect's input beside it (an effect on an input), or
refitted by equation error with the effect's terms (an effect on states).

A base model identified without a delay on its input takes the delay up in its other coefficients: the gain
moves to the rows the input reaches late, the damping and the coupling bend (record 4 of the generalisation
benchmark, a two-mass drive with 14.5 samples of delay: the input acts on the load's row with five times its
gain on the motor's). From there the trial fit, a local Gauss-Newton search, does not find its way back: the
delay's screening promises a BIC change of -14 300, the trial realises +1.

An effect whose terms are copies of an input (a delay's delayed inputs; not an input tied to its own gain, as
a saturation is) keeps the model linear in its coefficients. So the base can be identified again with those
copies as inputs, by the identification's own multi-start output-error refinement (exact Jacobians, a second
or two; only its starts without the continuation prior, the winners on records 4 and 28; on the first
:data:`JOINT_SAMPLES` of each record: together they take the timing record's diagnosis from 12.6 s to 9.5),
and the trial started from that fit as well: on record 4 it realises -28 000 and the delay comes out at 14.2
samples; on record 78 at 10.7 (true 10.75), where the first start had left it at -27.8 and nothing was named.

An effect on states (a friction, a cogging, gravity) has terms of the simulated states, which the output-error
identification cannot take as inputs: with its terms evaluated on the measured signals as inputs it fits a model
that is not the one simulated (record 112: the trial from that start begins at a cost of 3e7, the base's is
2.1e4). Its second start
(:func:`state_start`, taken when the trial from the base realises less than half of the BIC change its
screening promised) is instead the equation error: each dynamic row refitted by least squares on the measured
signals' derivatives, the base's terms and the effect's together. That fit does not follow the base's free
run, so it is not caught where the base took the effect up: record 112 of the benchmark, a two-mass plant
moving as one body under a Coulomb friction, whose linear base stands in for it with an unstable oscillation,
gives a trial from the base that stalls after 4 Gauss-Newton steps at 20 905 (base 21 207, screening's promise
-2 118 in BIC) and one from the equation error that falls to 18 200 and names the friction.

When that too falls short, the base is identified again with the effect's terms in the library beside the
linear ones (:func:`identified_start`): the identification's own multi-start, whose continuation and starts
find a shaft the equation error misses; with the exact sensitivities of a nonlinear model's free run it takes
a few seconds.

These starts are made from a linear base only, in the first round. The linear identification cannot hold an
effect found before and would drop it (no delay was named after another effect on the benchmark's 280 records;
skipping those starts took the timing record's diagnosis from 9.9 s to 8.7). An equation-error start after a
first effect moves every coefficient the output-error fit had settled: on EMPS the asymmetry found that way
(after Coulomb friction) kept a constant beside it and took the validation record's simulation from 12.8 mm
to 15.6.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from ..data.derivatives import differentiate
from ..data.trajectory import Trajectory
from ..errors import CosimError
from ..identify.model import IdentifiedModel
from ..identify.sindyc import SINDYc
from ..identify.terms import Term
from ._free_run import _bounds
from .candidates import EffectCandidate
from .effects import EFFECTS, Roles

#: Samples of each record the start is identified on (their first): it is only a start, refined on the whole
#: record by the trial fit. The benchmark's records of up to 4000 samples are used whole.
JOINT_SAMPLES = 4000


def has_joint_start(name: str) -> bool:
    """Whether the effect `name` adds copies of an input the base can be identified with (an untied input
    effect: a delay)."""
    effect = EFFECTS[name]
    return effect.attaches_to == "input" and effect.input_tie is None


def has_state_start(name: str) -> bool:
    """Whether the effect `name` acts on states through terms that can be evaluated on the measured signals."""
    effect = EFFECTS[name]
    return effect.attaches_to in ("velocity", "position", "pair", "position_or_pair") and effect.input_tie is None


def state_start(current: IdentifiedModel, cand: EffectCandidate, columns: Mapping[str, np.ndarray], dt: float,
                segments: list[int] | None) -> tuple[IdentifiedModel, EffectCandidate] | None:
    """The dynamic rows refitted by equation error with `cand`'s terms beside the current model's: least squares
    of each measured dynamic state's derivative (Savitzky-Golay, its window chosen from the data) on the terms
    evaluated on the measured signals, the current model's structure kept, every coefficient of it free.
    None when the terms or derivatives are not finite."""
    effect = EFFECTS[cand.name]
    terms = effect.fit_terms(cand.placement, cand.nuisance) or cand.terms
    roles = Roles.of(current)
    rows = roles.dynamic_rows
    n = len(columns[current.states[0]])
    bounds = _bounds(segments, n)
    try:
        with np.errstate(all="ignore"):
            values = {t: np.broadcast_to(np.asarray(Term(t).evaluate(columns), dtype=float), (n,))
                      for t in [*current.terms, *terms]}
            slopes = {r: np.concatenate([np.asarray(differentiate(np.asarray(columns[r][a:b], dtype=float), dt))
                                         .reshape(-1)[:b - a] for a, b in bounds]) for r in rows}
    except (CosimError, ValueError, FloatingPointError):
        return None
    coef = np.array(current.coef, dtype=float)
    weights = []
    for r in rows:  # the effect in the rows its screening placed it in only (a friction of the load: its row)
        i = current.states.index(r)
        own = [k for k, t in enumerate(current.terms) if current.coef[i, k] != 0.0]
        added = list(terms) if r in cand.rows else []
        design = np.column_stack([values[current.terms[k]] for k in own] + [values[t] for t in added])
        if not np.all(np.isfinite(design)) or not np.all(np.isfinite(slopes[r])):
            return None
        scale = np.linalg.norm(design, axis=0)
        scale[scale == 0.0] = 1.0
        solution = np.linalg.lstsq(design / scale, slopes[r], rcond=None)[0] / scale
        coef[i, own] = solution[:len(own)]
        weights += [float(w) for w in solution[len(own):]]
    start = replace(current, coef=coef)
    return start, replace(cand, terms=terms, rows=tuple(r for r in rows if r in cand.rows),
                          coefficients=tuple(weights))


def identified_start(current: IdentifiedModel, cand: EffectCandidate, columns: Mapping[str, np.ndarray],
                     dt: float, segments: list[int] | None) -> tuple[IdentifiedModel, EffectCandidate] | None:
    """The base identified again with an effect on states, `cand`'s terms in the library beside the linear
    ones (the default identification: output-error multi-start, exact sensitivities), on the first
    :data:`JOINT_SAMPLES` of each record; the start's base part and the candidate with its coefficients in every
    dynamic row. None when the current model is not linear, the effect is not on states or the fit fails.

    The equation-error start cannot give back what a linear base took up when the effect is large: a cogging
    torque of a two-mass drive stands in for the shaft's twist in the base (record 165 of the generalisation
    benchmark: free-run cost 2.6 times the noise's, the twist mode missing), and a refit of its equation error
    keeps that. The identification's multi-start with the cogging's terms finds the plant (0.99 of the noise).
    """
    if not set(current.terms) <= {"1", *current.states, *current.inputs} or not has_state_start(cand.name):
        return None
    effect = EFFECTS[cand.name]
    terms = effect.fit_terms(cand.placement, cand.nuisance) or cand.terms
    roles = Roles.of(current)
    kinds = {**dict.fromkeys(current.states, "state"), **dict.fromkeys(current.inputs, "input")}
    spans = [(a, min(b, a + JOINT_SAMPLES)) for a, b in _bounds(segments, len(columns[current.states[0]]))]
    records = [Trajectory.from_arrays(dt * np.arange(b - a), {k: np.asarray(columns[k][a:b], dtype=float)
                                                              for k in kinds}, roles=kinds) for a, b in spans]
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            fitted = SINDYc(library="linear", include_constant="1" in current.terms, threshold=0.0,
                            kinematics=dict(roles.velocity_of) or "none", refine="output_error",
                            allow_unstable=True, prefer_stable=True, decimate=1, terms=list(terms)).fit(
                records, states=list(current.states), inputs=list(current.inputs)).model_
    except (CosimError, np.linalg.LinAlgError, FloatingPointError, ValueError):
        return None
    return _start_of(current, cand, fitted, terms, roles)


def _start_of(current: IdentifiedModel, cand: EffectCandidate, fitted: IdentifiedModel, terms: Sequence[str],
              roles: Roles) -> tuple[IdentifiedModel, EffectCandidate]:
    """The base part of an identification with `terms` beside the base's (the current model's structure), from
    the fit's own initial states, and `cand` with the fit's coefficients on `terms` in every dynamic row."""
    coef = np.array([[fitted.coef[fitted.states.index(s), fitted.terms.index(t)] if t in fitted.terms else 0.0
                      for t in current.terms] for s in current.states])
    coef[current.coef == 0.0] = 0.0  # the current model's structure
    rows = roles.dynamic_rows
    weights = tuple(float(fitted.coef[fitted.states.index(r), fitted.terms.index(t)]) if t in fitted.terms else 0.0
                    for r in rows for t in terms)
    # from the fit's own initial states too (the base's, with these coefficients, start the free run elsewhere)
    start = replace(current, coef=coef, meta={**current.meta, "x0": fitted.meta["x0"]})
    return start, replace(cand, terms=tuple(terms), rows=rows, coefficients=weights)


def joint_start(current: IdentifiedModel, cand: EffectCandidate, columns: Mapping[str, np.ndarray], dt: float,
                segments: list[int] | None) -> tuple[IdentifiedModel, EffectCandidate] | None:
    """The base part and the candidate (its coefficients in every dynamic row) of a linear model identified on
    the records with `cand`'s terms as extra inputs; None when the effect has no such terms or the fit fails.

    The identification is the default one (linear library, output-error multi-start, here from its starts
    without the continuation prior), with the current model's constant and kinematic rows; coefficients the
    current model holds at zero stay zero. For an effect on states, the equation-error start
    (:func:`state_start`). None too when the current model is not linear (module notes).
    """
    if not set(current.terms) <= {"1", *current.states, *current.inputs}:
        return None  # from a linear base only (module notes)
    if has_state_start(cand.name):
        return state_start(current, cand, columns, dt, segments)
    effect = EFFECTS[cand.name]
    new = effect.columns(cand.placement, cand.nuisance, columns)
    terms = cand.terms  # the screening's (a delay's one tap; the trial fit adds the next one)
    if not has_joint_start(cand.name) or not terms or not all(t in new for t in terms):
        return None
    roles = Roles.of(current)
    inputs = [*current.inputs, *terms]
    signals = {**{s: columns[s] for s in current.states}, **{u: columns[u] for u in current.inputs}, **new}
    kinds = {**dict.fromkeys(current.states, "state"), **dict.fromkeys(inputs, "input")}
    spans = [(a, min(b, a + JOINT_SAMPLES)) for a, b in _bounds(segments, len(signals[current.states[0]]))]
    records = [Trajectory.from_arrays(dt * np.arange(b - a), {k: signals[k][a:b] for k in kinds}, roles=kinds)
               for a, b in spans]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fitted = SINDYc(library="linear", include_constant="1" in current.terms, threshold=0.0,
                            kinematics=dict(roles.velocity_of) or "none", refine="output_error",
                            refine_options={"prior": 0.0}, allow_unstable=True,
                            decimate=1).fit(records, states=list(current.states), inputs=inputs).model_
    except (CosimError, np.linalg.LinAlgError, FloatingPointError):
        return None
    return _start_of(current, cand, fitted, terms, roles)
