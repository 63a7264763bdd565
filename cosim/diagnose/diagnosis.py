"""Diagnosis: trace the residual of a model to the physical effect it lacks, add it, report before and after.

``diagnose(model, data)`` does, round after round:

1. **Screen** every catalogued effect (:mod:`cosim.diagnose.effects`) at every place it can attach (found from the
   model's equations) and over its nuisance grid, on the **output error**: a Gauss-Newton score test along
   the model's free run (:mod:`cosim.diagnose.screening`), with every present coefficient and the initial state
   re-estimated alongside, so a candidate that only repeats a present term explains nothing. The equation
   error cannot do this on noisy positions: a stiff coupling turns their noise into equation error larger
   than a friction force. A candidate enters one dynamic row, or several when that pays by more than the BIC
   margin.
2. **Rank** the candidates by their change of BIC, refine the leading ones' nuisance parameters by a bounded
   scalar search, then **fit the leading candidates for real** (Gauss-Newton output error with the nuisance
   parameter) and judge them on the actual drop of the output error: the first-order score misleads when
   the model error is large. A candidate is **significant** when its likelihood-ratio p-value is below
   `alpha`, it lowers BIC by more than `bic_margin`, *and* its correction moves at least `min_size` of the
   data's spread: the first two are strict because the search tries a few hundred candidates (data without
   an effect must give "no effect found"), the third because on long or noise-free records a negligible
   mismatch (discretisation, say) is significant without being physical.
3. **Add** the best significant one (dropping rows where its coefficient is not clearly non-zero), and go
   to the next round while a significant effect remains (at most `max_effects`).
4. **Refit** after each accepted effect by output error (Gauss-Newton on the same sensitivities; unbiased
   under measurement noise), and **report** the free-run error before and after (R², NRMSE fit %, maximum deviation,
   residual whiteness), each effect's physical parameters with their standard errors (from the output-error
   Jacobian, through the row's input gain), and plots of the evidence.

This module holds the search, round after round. A round's screening and ranking are in ``_ranking``, the
trial fits (steps 2 to 4) in ``_trials``, the candidates in :mod:`~cosim.diagnose.candidates` and the report
in :mod:`~cosim.diagnose.diagnosis_report`.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> from cosim.data.trajectory import Trajectory
>>> dt, n = 1e-3, 6000
>>> t = np.arange(n + 1) * dt
>>> u = 3.0 * np.sin(2 * np.pi * 1.3 * t) + 1.5 * np.sign(np.sin(2 * np.pi * 0.7 * t))
>>> x, v = np.zeros(n + 1), np.zeros(n + 1)
>>> for k in range(n):    # a mass with viscous and Coulomb friction, Fc = 1 N (Euler, 10 substeps)
...     xs, vs = x[k], v[k]
...     for _ in range(10):
...         xs, vs = xs + 1e-4 * vs, vs + 1e-4 * (u[k] - 2.0 * vs - 1.0 * np.tanh(vs / 1e-3))
...     x[k + 1], v[k + 1] = xs, vs
>>> data = Trajectory.from_arrays(t, {"x": x, "v": v, "u": u}, roles={"x": "state", "v": "state", "u": "input"})
>>> linear = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u"),
...                          coef=np.array([[1.0, 0.0], [-2.0, 1.0]]))
>>> report = diagnose(linear, data)
>>> [e.name for e in report.effects], round(report.effects[0].parameters["Fc"], 1)
(['coulomb_friction'], 1.0)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from ..data.trajectory import Trajectory
from ..errors import DataError, InvalidSettingError
from ..identify.model import IdentifiedModel
from ._ranking import _round
from ._trials import _drop_redundant, _final_parameters, _fit_with, _FitOptions
from .candidates import EffectCandidate
from .diagnosis_report import DiagnosisReport, _figures
from .effects import effect_names
from .residuals import residuals
from .screening import Nuisance, OutputErrorScreen, output_error_fit

__all__ = ["diagnose"]


#: Default significance level of one candidate (strict: a few hundred candidates are tried).
ALPHA = 1e-6
#: Default least BIC decrease of a significant candidate.
BIC_MARGIN = 30.0
#: Default least size of a significant effect: its share of the row's motion (RMS over the windows).
MIN_SIZE = 0.005
#: How many of a round's leading candidates are fitted for real before one is accepted.
VERIFY_TOP = 6
#: Gauss-Newton iterations of a trial fit (the winner is then fitted to convergence).
TRIAL_ITERATIONS = 4


# ---------------------------------------------------------------------------------------------- the data, checked
def _columns(model: IdentifiedModel, data: Trajectory) -> dict[str, np.ndarray]:
    missing = [n for n in (*model.states, *model.inputs) if n not in data.names]
    if missing:
        from ..errors import UnknownVariableError

        raise UnknownVariableError(f"the data have no column {missing[0]!r} that the model needs; "
                                   f"columns are {list(data.names)}")
    return {name: np.asarray(data[name], dtype=float) for name in data.names}


def _initial_state(model: IdentifiedModel, data: Trajectory, x0: str | Sequence[float]) -> np.ndarray | None:
    """The held initial state of `diagnose`'s `x0` (None: estimated)."""
    if isinstance(x0, str):
        if x0 not in ("estimate", "measured"):
            raise InvalidSettingError(f'x0 must be "estimate", "measured" or {len(model.states)} values, got {x0!r}')
        return None if x0 == "estimate" else np.array([data[name][0] for name in model.states], dtype=float)
    values = np.asarray(x0, dtype=float).ravel()
    if values.shape != (len(model.states),) or not np.all(np.isfinite(values)):
        raise InvalidSettingError(f"x0 must hold {len(model.states)} finite values ({', '.join(model.states)}), "
                                  f"got {list(x0)}")
    return values


def _noise(model: IdentifiedModel, noise: Mapping[str, float] | None) -> dict[str, float] | None:
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


def _with_columns(traj: Trajectory, columns: Mapping[str, np.ndarray]) -> Trajectory:
    """`traj` plus the derived columns (a delayed input) that it lacks."""
    extra = {k: v for k, v in columns.items() if k not in traj.names}
    if not extra:
        return traj
    return Trajectory.from_arrays(traj.time, {**{n: traj[n] for n in traj.names}, **extra},
                                  roles={**dict(zip(traj.names, traj.roles, strict=True)),
                                         **dict.fromkeys(extra, "input")})


# ---------------------------------------------------------------------------------------------- the search
def diagnose(model: IdentifiedModel, data: Trajectory, *, effects: str | Sequence[str] = "all",
             max_effects: int = 3, alpha: float = ALPHA, bic_margin: float = BIC_MARGIN,
             min_size: float = MIN_SIZE, reference: Trajectory | None = None,
             x0: str | Sequence[float] = "estimate", noise: Mapping[str, float] | None = None,
             progress: bool | None = None) -> DiagnosisReport:
    """Find the effects `model` lacks in `data`, add them, and report the error before and after.

    Parameters
    ----------
    model : IdentifiedModel
        The model to diagnose (typically linear, from :class:`~cosim.identify.sindyc.SINDYc`).
    data : Trajectory
        Measured data holding the model's states and inputs, at a uniform step.
    effects : "all", comma-separated names, or a list
        Which catalogued effects to try.
    max_effects : int
        Most effects added.
    alpha, bic_margin : float
        A candidate is significant when its p-value is below `alpha` and it lowers BIC by more than
        `bic_margin`.
    min_size : float
        Least size of a significant effect: how much of the data's spread its free-run correction moves.
    reference : Trajectory, optional
        Noise-free truth on the same time grid (a simulation): the before/after figures are then computed
        against it, as the reference study does, instead of against the noisy data (whose noise is a floor).
    x0 : "estimate", "measured", or a sequence of float
        The free runs' initial state: estimated with the parameters in every fit (MATLAB's
        ``InitialState='estimate'``; right for noisy states), the data's first sample, or given values. Hold
        it (``"measured"``) when the states are measured far more precisely than the model can follow them,
        on a long record of a drifting (integrating) plant: there an estimated initial state absorbs the
        model's error (on EMPS it lands 3 mm from an encoder reading good to 5 um).
    noise : dict, optional
        A state's noise level (the scale of its residual in every fit), e.g. a sensor's resolution, instead
        of the estimate from the data's second differences (:func:`~cosim.diagnose.screening.noise_level`), which
        is far too small on a filtered or interpolated signal.
    progress : bool or None
        A progress bar on stderr, one step per screening round and trial fit (None: only on a terminal).

    Returns
    -------
    DiagnosisReport
    """
    # the work is tall, thin least squares and small matrix products: threaded BLAS only adds overhead
    # (3x slower on 2 cores)
    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(model, data, effects=effects, max_effects=max_effects, alpha=alpha, bic_margin=bic_margin,
                         min_size=min_size, reference=reference, x0=x0, noise=noise, progress=progress)


def _diagnose(model: IdentifiedModel, data: Trajectory, *, effects: str | Sequence[str], max_effects: int,
              alpha: float, bic_margin: float, min_size: float, reference: Trajectory | None,
              x0: str | Sequence[float], noise: Mapping[str, float] | None,
              progress: bool | None) -> DiagnosisReport:
    names = effect_names(effects)
    if len(data) < 200:
        raise DataError(f"diagnosis needs at least 200 samples, got {len(data)}")
    if not np.allclose(np.diff(data.time), data.dt, rtol=1e-6, atol=0.0):
        raise DataError("the data's time step is not uniform; resample it onto a uniform grid first")
    columns = _columns(model, data)
    for name in model.inputs:
        if np.ptp(columns[name]) == 0.0:
            raise DataError(f"input {name!r} is constant: nothing to diagnose from; excite the plant")
    start = _initial_state(model, data, x0)
    fit = _FitOptions(estimate_x0=start is None, noise=_noise(model, noise))
    res_before = residuals(model, data, x0="estimate" if start is None else start)
    truth = reference if reference is not None else data
    before = _figures(model, truth, res_before, start)
    # the base at its own output-error optimum, so that a candidate's trial fit gains only what it adds
    current = output_error_fit(model, columns, data.dt, x0=start, **fit.kw)[0]
    accepted, rounds, fitted, steps = [], [], [], []
    nuisances: list[Nuisance] = []
    owners: list[int] = []
    bar = tqdm(total=max_effects, unit="round", desc="diagnose", leave=False,
               disable=None if progress is None else not progress)
    for _ in range(max_effects):
        bar.set_postfix_str("screening")
        try:
            screen = OutputErrorScreen(current, dict(columns), data.dt, **fit.kw)
        except DataError:
            if not accepted:
                raise
            break  # the model with the effects found so far is too unstable to screen further: report them
        ranking = _round(screen, names, alpha, bic_margin, min_size,
                         taken=[(c.name, c.attached_to) for c in accepted])
        rounds.append(tuple(ranking))
        bar.set_postfix_str("fitting " + ", ".join(c.name for c in ranking[:VERIFY_TOP] if c.significant))
        bar.update(1)
        # the score test is a first-order guide; the leading candidates are fitted for real and judged on
        # the actual drop of the output error (a large model error makes the first order unreliable)
        trials = [_fit_with(current, c, columns, data.dt, nuisances, screen, alpha, bic_margin, min_size, fit,
                            iterations=TRIAL_ITERATIONS) for c in ranking[:VERIFY_TOP] if c.significant]
        fitted.append(tuple(t.candidate for t in trials if t is not None))
        trials = [t for t in trials if t is not None and t.candidate.significant]
        if not trials:
            break
        best = min(trials, key=lambda t: t.candidate.delta_bic)
        best = _fit_with(current, best.candidate, columns, data.dt, nuisances, screen, alpha, bic_margin,
                         min_size, fit) or best  # the winner, fitted to convergence
        accepted.append(best.candidate)
        if best.nuisance is not None:
            owners.append(len(accepted) - 1)
        current, nuisances = best.model, best.nuisances
        columns.update(best.new_columns)  # a delay's delayed input
        _write_back(accepted, owners, nuisances)
        # an effect found earlier may have stood in for the one found now: keep it only if it still pays
        current, accepted, owners, nuisances = _drop_redundant(current, accepted, owners, nuisances, columns,
                                                              data.dt, alpha, bic_margin, min_size, fit)
        _write_back(accepted, owners, nuisances)
        steps.append((tuple(c.name for c in accepted), current))
    bar.close()
    work = _with_columns(data, columns)  # the data plus the columns an effect added
    final = current
    final_x0 = final.meta.get("x0") if isinstance(final.meta, Mapping) else None
    res_after = residuals(final, work, x0=final_x0[0] if final_x0 else "estimate") if accepted else res_before
    after = _figures(final, _with_columns(truth, columns), res_after) if accepted else before
    found = tuple(_final_parameters(c, final) for c in accepted)
    if found:
        message = "found " + ", then ".join(f"{e.name} on {e.attached_to}" for e in found) + \
                  f": free-run NRMSE {before['nrmse_pct']:.3g} % -> {after['nrmse_pct']:.3g} %"
    elif res_before.white:
        message = "no effect found: the residual is white, the model explains the data"
    else:
        message = ("no effect found: the residual is not white, but no catalogued effect explains it "
                   "(the model lacks something the catalogue does not cover)")
    return DiagnosisReport(effects=found, ranking=rounds[0] if rounds else (), rounds=tuple(rounds),
                           trials=tuple(fitted), steps=tuple(steps),
                           model_before=model, model_after=final, before=before, after=after,
                           residuals_before=res_before, residuals_after=res_after, message=message, data=work)


def _write_back(accepted: list[EffectCandidate], owners: Sequence[int], nuisances: Sequence[Nuisance]) -> None:
    """Put the fitted nuisance values (and the terms written with them) on the accepted effects."""
    for j, nu in zip(owners, nuisances, strict=True):
        accepted[j] = replace(accepted[j], nuisance=nu.value, terms=nu.terms, nuisance_se=nu.std_error)
