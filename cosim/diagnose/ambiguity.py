"""Readings the data cannot tell apart, and the experiment that would: a diagnosis's ``ambiguous`` sets.

A catalogued effect whose linearisation is a few of the base model's terms (:attr:`Effect.absorbs`: gravity's
``sin x`` over a small swing is a spring to ground ``x`` and a constant) is, on a record that stays where the
linearisation holds, another reading of the same data: the linear model with a spring to ground and the model
with gravity in its place fit alike. The search then names nothing, and that is right as far as it goes; but
"no effect" hides a question these data cannot answer. :func:`linearisation_ambiguities` asks it:

0. could the search try the effect on this record at all? (its span rule on the model's free run: gravity wants
   half a radian of range; where it could, the search judged, and there is no set);
1. does the record show the restoring force at all? (the model without the spring to ground, refitted, is
   worse by more than the margin; a coupling to another position, ``c_q q + c_p p``, is kept as the twist
   ``c_q (q - p)``, and only ``(c_q + c_p) p`` goes to ground);
2. the effect's reading: the spring and the constant replaced by the effect's terms (their least-squares match
   on the record), refitted by output error;
3. if the two readings' BIC are within the margin the diagnosis needs for any claim, they form a set
   (:class:`Ambiguity`), and :func:`separating_experiment` finds the input that tells them apart: the record's
   own input scaled up (1.5x to 20x) until the two readings' free runs differ by at least the noise level
   (RMS, in some state) and the search could try the effect on it (its span rule), and the swing that input
   reaches. Readings alike under every scale tried are left out: one model for every use the data serve.

:func:`rival_ambiguities` adds the other kind: a named effect whose round had another effect's fit within the
margin (:func:`converged_rival`: the trial fits' near one fitted to convergence as the accepted one is; a sine
and its cubic over a swing of a third of a radian); the record that would separate them is a wider range of the
signal they act on.

:func:`run_experiment` runs that input on an FMU of the plant (``cosim diagnose --plant``) and returns the record
a second diagnosis takes beside the first, with measurement noise at the level the first record shows
(seeded: the same answer on every run); :func:`settled` goes on with the next larger scale while a set of
amplitude remains, up to :data:`MAX_EXPERIMENTS` runs. Written here because no library of the field reports equivalent
readings of a record or designs the experiment between two of them.

Examples
--------
>>> from cosim.diagnose.ambiguity import Ambiguity
>>> a = Ambiguity(("gravity", "spring"), "theta", ("gravity on theta", "a spring to ground on theta and a "
...               "constant"), 3.0, 30.0, {"quantity": "amplitude", "signal": "theta", "at_least": 0.62,
...               "now": 0.15, "input_scale": 5.0})
>>> a.sentence()[:60]
'gravity on theta or a spring to ground on theta and a consta'
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from itertools import zip_longest
from typing import Any

import numpy as np

from ..data.trajectory import Trajectory
from ..errors import DataError
from ..identify.model import IdentifiedModel
from ._free_run import noise_level
from ._record_band import RecordBand
from .diagnosis_report import DiagnosisReport
from .effects import EFFECTS, Effect, Roles
from .screening import output_error_fit

__all__ = ["Ambiguity", "check_plant", "linearisation_ambiguities", "rival_ambiguities", "run_experiment",
           "separating_experiment", "settled"]

#: How far apart (RMS over the record, in noise levels of some state) two readings' free runs must be for an
#: experiment to separate them: a difference the size of the noise on every sample, which the other errors of
#: a model do not hide.
SEPARATION = 1.0
#: The scales of the record's input tried, smallest first.
INPUT_SCALES = (1.5, 2.0, 3.0, 5.0, 8.0, 13.0, 20.0)
#: Gauss-Newton iterations of the readings' fits.
ITERATIONS = 15
#: Seed of the measurement noise added to an experiment run on an FMU.
EXPERIMENT_SEED = 0


@dataclass(frozen=True)
class Ambiguity:
    """Two readings of the data within the evidence margin of each other, and the experiment between them.

    Attributes
    ----------
    effects : tuple of str
        The readings' names: the effect and what stands for it in the model (``("gravity", "spring")``).
    attached_to : str
        The signal the effect acts on in the reading reported: the first of `places`.
    readings : tuple of str
        Each reading in words.
    delta_bic : float
        The effect's reading's BIC minus the model's (negative: the effect fits a little better).
    margin : float
        The BIC change the diagnosis needs for a claim; the two readings are closer than it.
    to_separate : dict
        The experiment: ``quantity`` ("amplitude"), ``signal``, ``at_least`` (the swing, half the range, it
        reaches), ``now`` (the record's), ``input_scale`` (the record's input times it); ``at_least`` is None
        when no scale up to the largest tried separates them.
    models : tuple of IdentifiedModel
        The two readings, fitted (the model's first).
    places : tuple of str
        Every place where the effect's reading is within the margin of the best (``attached_to`` among them).
    """

    effects: tuple[str, ...]
    attached_to: str
    readings: tuple[str, ...]
    delta_bic: float
    margin: float
    to_separate: dict[str, Any]
    models: tuple[IdentifiedModel, ...] = field(default=(), repr=False, compare=False)
    places: tuple[str, ...] = ()

    def sentence(self) -> str:
        """What the data cannot tell, and what would."""
        s = self.to_separate
        if self.delta_bic < -self.margin:  # a rival never named: its physical parameter at the record's edge
            said = (f"{' or '.join(self.readings)}: the second fits these data better (BIC {-self.delta_bic:.3g} "
                    f"lower), but at the edge of what the record shows, so neither is claimed over the other")
        else:
            said = (f"{' or '.join(self.readings)}: these data cannot tell them apart (BIC "
                    f"{abs(self.delta_bic):.3g} apart, a claim needs {self.margin:g})")
        if s.get("at_least") is None:
            return said + f"; a record over a wider {s['quantity']} of {s['signal']} would separate them"
        return (said + f"; swings of at least ±{s['at_least']:.3g} on {s['signal']} (the record's input "
                f"x{s['input_scale']:g}; it swings ±{s['now']:.3g} now) would separate them")

    def to_dict(self) -> dict[str, Any]:
        return {"effects": list(self.effects), "attached_to": self.attached_to,
                "places": list(self.places or (self.attached_to,)), "readings": list(self.readings),
                "delta_bic": self.delta_bic, "margin": self.margin, "to_separate": dict(self.to_separate),
                "sentence": self.sentence()}


def _columns(model: IdentifiedModel, record: Trajectory) -> dict[str, np.ndarray]:
    return {n: np.asarray(record[n], dtype=float) for n in (*model.states, *model.inputs)}


def _bic(fitted: IdentifiedModel, n_obs: int) -> float:
    """BIC up to a constant: the output-error cost and the model's coefficients."""
    return n_obs * math.log(float(fitted.meta["refinement"]["cost"])) + np.count_nonzero(fitted.coef) * math.log(n_obs)


def _fit(model: IdentifiedModel, cols: dict[str, np.ndarray], dt: float, noise: Mapping[str, float],
         measured: Sequence[str] | None) -> tuple[IdentifiedModel, np.ndarray] | None:
    try:
        return output_error_fit(model, cols, dt, iterations=ITERATIONS, noise=noise, measured=measured)[:2]
    except (DataError, np.linalg.LinAlgError, FloatingPointError):
        return None  # (a reading whose free run diverges on the record is no reading of it)


def _reading(model: IdentifiedModel, roles: Roles, position: str, rows: Sequence[int], terms: tuple[str, ...] | None,
             cols: Mapping[str, np.ndarray]) -> IdentifiedModel:
    """`model` with its spring to ground on `position` in `rows` taken out: a coupled position's coefficient
    moved onto the twist ``(q-position)`` (``c_q q + c_p p = c_q (q - p) + (c_q + c_p) p``), the rest, the spring
    to ground, dropped (``terms=None``) or, with the row's constant, replaced by the effect's `terms` (their
    least-squares match on the record)."""
    coupled = sorted({b if a == position else a for a, b in roles.pairs if position in (a, b)} & set(model.terms))
    twists = [f"({q}-{position})" for q in coupled]
    names = list(model.terms) + [t for t in (*twists, *(terms or ())) if t not in model.terms]
    coef = np.zeros((len(model.states), len(names)))
    coef[:, :len(model.terms)] = model.coef
    wide = replace(model, terms=tuple(names), coef=coef)
    X = np.column_stack([cols[s] for s in model.states])
    U = np.column_stack([cols[u] for u in model.inputs]) if model.inputs else np.zeros((len(X), 0))
    F = wide.features(X, U)
    k_p = names.index(position)
    for i in rows:
        for q, twist in zip(coupled, twists, strict=True):
            coef[i, names.index(twist)] = coef[i, names.index(q)]
            coef[i, k_p] += coef[i, names.index(q)]
            coef[i, names.index(q)] = 0.0
        if terms is None:
            coef[i, k_p] = 0.0
            continue
        k_e = [names.index(t) for t in terms]
        moved = [k_p] + ([names.index("1")] if "1" in names else [])
        coef[i, k_e] = np.linalg.lstsq(F[:, k_e], F[:, moved] @ coef[i, moved], rcond=None)[0]
        coef[i, moved] = 0.0
    keep = [k for k in range(len(names)) if np.any(coef[:, k])]
    return replace(wide, terms=tuple(names[k] for k in keep), coef=coef[:, keep],
                   meta={k: v for k, v in model.meta.items() if k == "x0"})


def linearisation_ambiguities(model: IdentifiedModel, record: Trajectory, names: Sequence[str], *,
                              found: Sequence[tuple[str, str]] = (), margin: float = 30.0,
                              noise: Mapping[str, float] | None = None,
                              measured: Sequence[str] | None = None) -> list[Ambiguity]:
    """The effects among `names` that are another reading of `model`'s spring to ground and constant on
    `record` (see the module notes): one :class:`Ambiguity` per effect, at its best place.

    Parameters
    ----------
    model : IdentifiedModel
        The diagnosed model (its effects added).
    record : Trajectory
        The record it was diagnosed on (the first, with any column an effect added).
    names : sequence of str
        The effects searched.
    found : sequence of (name, attached_to)
        The effects named: not asked again.
    margin : float
        The BIC change a claim needs.
    noise, measured
        As in :func:`~cosim.diagnose.diagnosis.diagnose`.
    """
    roles = Roles.of(model)
    cols = _columns(model, record)
    dt = float(record.dt)
    levels = {s: float(noise[s]) if noise and s in noise else noise_level(cols[s]) for s in model.states}
    n_obs = len(record) * len(measured if measured is not None else model.states)
    fitted = run = None
    out = []
    for name in names:
        effect = EFFECTS.get(name)
        if effect is None or effect.absorbs is None or name in {f for f, _ in found}:
            continue  # (named: where it sits was the search's to judge)
        readings = []
        for a in effect.attachments(roles):
            position = a.signals[0]
            if position not in model.terms or any(position in at.split("-") for _, at in found):
                continue  # (an effect named on the position accounts for its bend: gravity's would need both)
            if effect.span is not None:
                if run is None:  # (the model's own free run, once: what the search's span rules read)
                    run = _simulated(model, np.column_stack([cols[u] for u in model.inputs]), dt, cols)
                    run = {} if run is None else dict(zip(model.states, run.T, strict=True))
                if not run or _searchable(effect, a.label, position, run, dt, levels):
                    continue  # (the search could try it here, and judged: the data told them apart)
            fitted = fitted or _fit(model, cols, dt, levels, measured)
            if fitted is None:
                return out
            base = fitted[0]
            rows = [model.states.index(r) for r in a.rows if base.coef[model.states.index(r),
                                                                       base.terms.index(position)] != 0.0]
            free = _fit(_reading(base, roles, position, rows, None, cols), cols, dt, levels, measured)
            if not rows or (free is not None and _bic(free[0], n_obs) - _bic(base, n_obs) < margin):
                continue  # the record shows no spring to ground: nothing the effect could stand for
            read = _fit(_reading(base, roles, position, rows, effect.make_terms(a, None), cols), cols, dt, levels,
                        measured)
            if read is None:
                continue
            other = read[0]
            delta = _bic(other, n_obs) - _bic(base, n_obs)
            if abs(delta) <= margin:
                readings.append((delta, a.label, position, other))
        if not readings:
            continue
        # the best reading's place, and every place within the margin of it (on a stiff coupling the data
        # cannot tell the two ends apart either: listed in the model's order, not picked by rounding)
        best = min(r[0] for r in readings)
        near = [r for r in readings if r[0] - best <= margin]
        delta, label, position, other = near[0]  # (the first of them: not the one rounding favours)
        places = [r[1] for r in near]
        experiment = separating_experiment(fitted[0], other, cols, dt, levels, position,
                                           partial(_searchable, effect, label, position, dt=dt, noise=levels))
        if experiment["input_scale"] is None:
            continue  # (alike under every input up to 20x the record's: one model for every use the data serve)
        out.append(Ambiguity((name, "spring"), label, (f"{name} on {' or '.join(places)}",
                             f"a spring to ground on {' or '.join(places)} and a constant"), float(delta),
                             float(margin), experiment, (fitted[0], other), tuple(places)))
    return out


def _searchable(effect: Effect, label: str, position: str, run: Mapping[str, np.ndarray], dt: float,
                noise: Mapping[str, float]) -> bool:
    """Whether the search could try `effect` at `position` on a record like `run` (its span rule; an effect
    without one: always)."""
    return effect.span is None or effect.span(run[position], RecordBand.of(run, dt, noise), label) is not None


def _simulated(model: IdentifiedModel, U: np.ndarray, dt: float,
              cols: Mapping[str, np.ndarray] | None = None) -> np.ndarray | None:
    """The model's free run from its fitted initial state (else the record's first sample, from `cols`)."""
    meta = model.meta if isinstance(model.meta, Mapping) else {}
    x0 = (np.asarray(meta["x0"], dtype=float).reshape(-1, len(model.states))[0] if "x0" in meta
          else np.array([cols[s][0] for s in model.states]))
    sim = model.simulate(x0, U[:-1], dt=dt)
    return sim.states if sim.ok else None


def separating_experiment(first: IdentifiedModel, second: IdentifiedModel, cols: Mapping[str, np.ndarray],
                          dt: float, noise: Mapping[str, float], signal: str,
                          searchable: Callable[[dict[str, np.ndarray]], bool] | None = None) -> dict[str, Any]:
    """The least scale of the record's input (:data:`INPUT_SCALES`) under which the two readings' free runs
    differ by :data:`SEPARATION` noise levels (RMS) in some state, and where the search can try the effect on
    the second's run (`searchable`, from its signals: gravity's span wants half a radian of range), and the
    swing of `signal` it reaches."""
    U = np.column_stack([cols[u] for u in first.inputs]) if first.inputs else np.zeros((len(cols[signal]), 0))
    k = first.states.index(signal)
    sigma = np.array([noise[s] for s in first.states])
    now = float(np.ptp(cols[signal])) / 2
    for scale in INPUT_SCALES:
        a, b = _simulated(first, U * scale, dt), _simulated(second, U * scale, dt)
        if a is None or b is None:
            break  # (a reading diverging is no experiment to run on a plant)
        apart = float(np.max(np.sqrt(np.mean((a - b) ** 2, axis=0)) / sigma)) >= SEPARATION
        if apart and (searchable is None or searchable(dict(zip(second.states, b.T, strict=True)))):
            return {"quantity": "amplitude", "signal": signal, "at_least": float(np.ptp(b[:, k])) / 2, "now": now,
                    "input_scale": scale}
    return {"quantity": "amplitude", "signal": signal, "at_least": None, "now": now, "input_scale": None}


def run_experiment(plant: str | os.PathLike, record: Trajectory, model: IdentifiedModel, scale: float, *,
                   parameters: Mapping[str, float] | None = None, noise: Mapping[str, float] | None = None,
                   ) -> Trajectory:
    """The record's input times `scale` run on the FMU `plant` (its `parameters` set), `model`'s states and
    inputs recorded, each state with Gaussian noise at the record's level (`noise`, else estimated from it;
    seed :data:`EXPERIMENT_SEED`).

    Raises
    ------
    DataError
        When the FMU lacks one of the model's signals.
    """
    from ..data.simulation import simulate

    check_plant(plant, (*model.states, *model.inputs))
    dt, n = float(record.dt), len(record)
    inputs = {u: np.asarray(record[u], dtype=float) * scale for u in model.inputs}
    run = simulate(plant, inputs, duration=dt * (n - 1), dt=dt, parameters=dict(parameters or {}),
                   outputs=list(model.states), progress=False)
    rng = np.random.default_rng(EXPERIMENT_SEED)
    cols = {u: np.asarray(run[u], dtype=float) for u in model.inputs}
    for s in model.states:
        level = float(noise[s]) if noise and s in noise else noise_level(np.asarray(record[s], dtype=float))
        cols[s] = np.asarray(run[s], dtype=float) + rng.normal(0.0, level, len(run))
    return Trajectory.from_arrays(np.asarray(run.time), cols, roles={**dict.fromkeys(model.states, "state"),
                                                                     **dict.fromkeys(model.inputs, "input")})


def check_plant(plant: str | os.PathLike, signals: Sequence[str]) -> None:
    """Refuse, in one line, an FMU that lacks one of the data's `signals` (a model's states and inputs), before
    any work."""
    from ..plant.model_description import open_model_description

    known = {v.name for v in open_model_description(plant).modelVariables}
    missing = [s for s in signals if s not in known]
    if missing:
        raise DataError(f"the plant {os.fspath(plant)!r} has no variable {', '.join(map(repr, missing))} of the "
                        f"data; give the FMU of the plant that recorded them (--plant)")


#: What a wider range of the signal an effect attaches to means, by the kind of signal.
QUANTITY = {"position": "amplitude", "pair": "amplitude", "position_or_pair": "amplitude", "velocity": "speed range",
            "input": "input amplitude", "none": "amplitude"}


def converged_rival(best: Any, trials: Sequence[Any], margin: float,
                    fit_with: Callable[[Any], Any]) -> Any | None:
    """The best-scoring other effect among a round's trial fits (`trials`, a few iterations each) that came
    within `margin` of the accepted one's, fitted to convergence as the accepted `best` was (`fit_with`), if it
    is significant and still within the margin of it, or significant but for a nuisance at its span's edge and
    not worse than `best` by more than the margin: its trial (``candidate``, ``model``); else None."""
    mine = next((t for t in trials if (t.candidate.name, t.candidate.attached_to) ==
                 (best.candidate.name, best.candidate.attached_to)), best)
    near = [t for t in trials if t.candidate.name != best.candidate.name and _fits_as_reading(t.candidate)
            and t.candidate.delta_bic - min(mine.candidate.delta_bic, best.candidate.delta_bic) <= margin]
    if not near:
        return None
    rival = fit_with(min(near, key=lambda t: (t.candidate.delta_bic, t.candidate.name)))
    if rival is None or not _fits_as_reading(rival.candidate):
        return None
    gap = rival.candidate.delta_bic - best.candidate.delta_bic
    # a reading whose physical parameter ends at the edge of what the record shows is never named, so one that
    # fits better by any amount is a rival too: the data do not establish the named effect against it
    edge = not rival.candidate.significant
    return rival if (gap <= margin if edge else abs(gap) <= margin) else None


def _fits_as_reading(cand: Any) -> bool:
    """Whether a trial's candidate is a reading of the data: significant, or so but for its physical nuisance
    at the edge of its span (a Stribeck velocity above the speeds that would show its decay)."""
    return bool(cand.significant or (cand.explained or {}).get("rival_only"))


def rival_ambiguities(report: DiagnosisReport, margin: float,
                      noise: Mapping[str, float] | None = None) -> list[Ambiguity]:
    """Each named effect with a rival (:attr:`DiagnosisReport.rivals`: another effect whose converged fit came
    within `margin` of its own): the two readings, and the record that would separate them: a wider range of the
    signal it attaches to, with the least scale of the record's input that does (:func:`separating_experiment`
    on the two readings' models, :attr:`DiagnosisReport.rival_models`) where both simulate the record."""
    out = []
    named = {(e.name, e.attached_to): e for e in report.effects}
    for (first, r), pair in zip_longest(report.rivals, report.rival_models, fillvalue=()):
        e = named.get((first.name, first.attached_to))
        if e is None:
            continue  # (dropped in a later round)
        signal = e.attached_to.split("-")[0]
        now = (float(np.ptp(report.data[signal])) / 2 if report.data is not None and signal in report.data.names
               else None)
        kind = QUANTITY.get(EFFECTS[e.name].attaches_to, "amplitude") if e.name in EFFECTS else "amplitude"
        experiment = _rival_experiment(pair, report.data, signal, noise) if pair else None
        out.append(Ambiguity((e.name, r.name), e.attached_to, (f"{e.name} on {e.attached_to}",
                             f"{r.name} on {r.attached_to}"), float(r.delta_bic - first.delta_bic), float(margin),
                             {"quantity": kind, "signal": signal, "at_least": None, "now": now, "input_scale": None,
                              **(experiment or {})},
                             tuple(pair), tuple(dict.fromkeys((e.attached_to, r.attached_to)))))
    return out


def _rival_experiment(pair: Sequence[IdentifiedModel], record: Trajectory | None, signal: str,
                      noise: Mapping[str, float] | None) -> dict[str, Any] | None:
    """:func:`separating_experiment` between a named effect's model and its rival's on the record (None where
    they differ in their signals or the record lacks one: a delay's delayed input)."""
    first, second = pair
    names = (*first.states, *first.inputs)
    if record is None or (first.states, first.inputs) != (second.states, second.inputs) or \
            not all(n in record.names for n in names):
        return None
    cols = _columns(first, record)
    levels = {s: float(noise[s]) if noise and s in noise else noise_level(cols[s]) for s in first.states}
    found = separating_experiment(first, second, cols, float(record.dt), levels,
                                  signal if signal in first.states else first.states[0])
    if signal not in first.states:  # an input's effect: the swing of the input itself
        scale = found["input_scale"]
        found = {**found, "signal": signal, "now": float(np.ptp(cols[signal])) / 2 if signal in cols else None,
                 "at_least": None if scale is None or signal not in cols else scale * float(np.ptp(cols[signal])) / 2}
    return {k: v for k, v in found.items() if k != "quantity"}


#: Most experiments run on a plant to settle the sets (each the next larger input scale when a set remains).
MAX_EXPERIMENTS = 3


def _said(message: str, sets: Sequence[Ambiguity]) -> str:
    return "; ".join([message, *(a.sentence() for a in sets)])


def settled(report: DiagnosisReport, records: Sequence[Trajectory], names: Sequence[str], *, margin: float,
            noise: Mapping[str, float] | None, measured: Sequence[str] | None,
            plant: str | os.PathLike | None = None, parameters: Mapping[str, float] | None = None,
            rediagnose: Callable[[list[Trajectory]], DiagnosisReport] | None = None) -> DiagnosisReport:
    """`report` with the readings its data cannot tell apart (:func:`linearisation_ambiguities`); with a
    `plant`, each set's experiment run on it (:func:`run_experiment`) and the `records` diagnosed again beside
    those runs (`rediagnose`), the answer of both."""
    def sets_of(rep: DiagnosisReport) -> list[Ambiguity]:
        if rep.data is None:
            return rival_ambiguities(rep, margin, noise)
        return rival_ambiguities(rep, margin, noise) + linearisation_ambiguities(
            rep.model_after, rep.data, names, margin=margin, noise=noise, measured=measured,
            found=[(e.name, e.attached_to) for e in rep.effects])

    sets = sets_of(report)
    runs: list[Trajectory] = []
    experiments: list[dict[str, Any]] = []
    while plant is not None and rediagnose is not None and sets and len(runs) < MAX_EXPERIMENTS:
        # an amplitude set's scale: its own, else the next above every scale run so far (a wider swing tells a
        # sine from its cubic, too); a set of another kind (a speed range) is not run
        last = max((e["input_scale"] for e in experiments), default=1.0)
        todo = [(a, a.to_separate["input_scale"] or next((s for s in INPUT_SCALES if s > last), None))
                for a in sets if a.to_separate["quantity"] == "amplitude"]
        todo = [(a, scale) for a, scale in todo if scale is not None and scale > last]
        if not todo:
            break
        a, scale = todo[0]
        run = run_experiment(plant, records[0], report.model_before, scale, parameters=parameters, noise=noise)
        runs.append(run)
        experiments.append({"effects": list(a.effects), "input_scale": scale, "signal": a.to_separate["signal"],
                            "swing": float(np.ptp(run[a.to_separate["signal"]])) / 2, "samples": len(run)})
        report = rediagnose([*records, *runs])
        sets = sets_of(report)
    return replace(report, ambiguous=tuple(sets), experiments=tuple(experiments), message=_said(report.message, sets))
