"""A trial's second start for an effect on an input: the base re-identified with the effect's input beside it.

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
Effects on states (a friction, a cogging) would need their terms simulated, not measured, which the linear
identification cannot do: started from a fit on the measured signals, a cogging's trial drifted (record 150:
60 times the base's cost).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from ..data.trajectory import Trajectory
from ..errors import CosimError
from ..identify.model import IdentifiedModel
from ..identify.sindyc import SINDYc
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


def joint_start(current: IdentifiedModel, cand: EffectCandidate, columns: Mapping[str, np.ndarray], dt: float,
                segments: list[int] | None) -> tuple[IdentifiedModel, EffectCandidate] | None:
    """The base part and the candidate (its coefficients in every dynamic row) of a linear model identified on
    the records with `cand`'s terms as extra inputs; None when the effect has no such terms or the fit fails.

    The identification is the default one (linear library, output-error multi-start, here from its starts
    without the continuation prior), with the current model's constant and kinematic rows; coefficients the
    current model holds at zero stay zero.
    """
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
    coef = np.array([[fitted.coef[fitted.states.index(s), fitted.terms.index(t)] if t in fitted.terms else 0.0
                      for t in current.terms] for s in current.states])
    coef[current.coef == 0.0] = 0.0  # the current model's structure
    rows = roles.dynamic_rows
    weights = tuple(float(fitted.coef[fitted.states.index(r), fitted.terms.index(t)]) if t in fitted.terms else 0.0
                    for r in rows for t in terms)
    # from the fit's own initial states too (the base's, with these coefficients, start the free run elsewhere)
    start = replace(current, coef=coef, meta={**current.meta, "x0": fitted.meta["x0"]})
    return start, replace(cand, terms=terms, rows=rows, coefficients=weights)
