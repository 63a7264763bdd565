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
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize, stats
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from ..data.trajectory import Trajectory
from ..errors import DataError, InvalidSettingError
from ..identify.metrics import max_deviation_pct, nrmse_fit_pct, r2
from ..identify.model import IdentifiedModel
from ..report import Report
from .effects import EFFECTS, Attachment, Effect, Roles, effect_names
from .residuals import ResidualAnalysis, residuals
from .screening import (
    Nuisance,
    OutputErrorScreen,
    correlation_factor,
    effect_specs,
    free_run_cost,
    free_run_residual,
    output_error_fit,
)

__all__ = ["DiagnosisReport", "EffectCandidate", "diagnose"]

#: Default significance level of one candidate (strict: a few hundred candidates are tried).
ALPHA = 1e-6
#: Default least BIC decrease of a significant candidate.
BIC_MARGIN = 30.0
#: Default least size of a significant effect: its share of the row's motion (RMS over the windows).
MIN_SIZE = 0.005


@dataclass(frozen=True)
class EffectCandidate:
    """One effect at one place with one nuisance value, scored on the integral equation error.

    Attributes
    ----------
    name : str
        Catalogue name.
    attached_to : str
        The signal (or pair ``"a-b"``, or ``"constant"``) it acts on.
    rows : tuple of str
        The states' equations it enters.
    nuisance : float or None
        The nuisance parameter (smoothing velocity, width, periods, delay in samples).
    terms : tuple of str
        The term expressions it adds.
    delta_bic : float
        Change of BIC when added (negative: better).
    p_value : float
        Likelihood-ratio test against the model without it.
    explained : dict of str to float
        Per row, the fraction of the row's residual sum of squares it removes.
    significant : bool
    parameters : dict of str to float
        Physical parameters from the coefficients (see :mod:`cosim.diagnose.effects`).
    uncertainty : dict of str to float
        Standard errors of the parameters where known.
    meaning : str
        The effect's physical meaning.
    """

    name: str
    attached_to: str
    rows: tuple[str, ...]
    nuisance: float | None
    terms: tuple[str, ...]
    delta_bic: float
    p_value: float
    explained: dict[str, float]
    significant: bool
    parameters: dict[str, float] = field(default_factory=dict)
    uncertainty: dict[str, float] = field(default_factory=dict)
    meaning: str = ""
    coefficients: tuple[float, ...] = ()
    nuisance_se: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "attached_to": self.attached_to, "rows": list(self.rows),
                "nuisance": self.nuisance, "terms": list(self.terms), "delta_bic": self.delta_bic,
                "p_value": self.p_value, "explained": dict(self.explained), "significant": self.significant,
                "parameters": dict(self.parameters), "uncertainty": dict(self.uncertainty), "meaning": self.meaning}


# ---------------------------------------------------------------------------------------------- the screening
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


def _uncertainty(effect: Effect, coef: dict, cov: np.ndarray, value: float | None, roles: Roles,
                 attachment: Attachment) -> dict[str, float]:
    """Standard error of each physical parameter, by name, by the delta method: the gradient of the parameter
    in the effect's coefficients (by differences) and their covariance ``cov`` (rows in ``coef``'s order, terms
    within). The covariance matters: a delay's two taps are each loose but their centroid is not."""
    flat = np.concatenate([np.asarray(c, dtype=float) for c in coef.values()])
    if cov is None or np.shape(cov) != (flat.size, flat.size):
        return {}
    base = effect.parameters(coef, value, roles, attachment)
    grads = {name: np.zeros(flat.size) for name in base}
    steps = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * 1e-3
    for k, h in enumerate(steps):
        if not h > 0.0:
            continue
        moved_flat = flat.copy()
        moved_flat[k] += h
        moved, at = {}, 0
        for row, c in coef.items():
            moved[row] = moved_flat[at:at + len(c)]
            at += len(c)
        for name, v in effect.parameters(moved, value, roles, attachment).items():
            if name in grads and np.isfinite(v) and np.isfinite(base[name]):
                grads[name][k] = (v - base[name]) / h
    out = {}
    for name, g in grads.items():
        var = float(g @ cov @ g)
        if var > 0.0:
            out[name] = math.sqrt(var)
    return out


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


# ---------------------------------------------------------------------------------------------- the report
@dataclass(frozen=True)
class DiagnosisReport:
    """What :func:`diagnose` found.

    Attributes
    ----------
    effects : tuple of EffectCandidate
        The accepted effects, in the order found (empty: no effect found), with parameters from the final
        refit.
    ranking : tuple of EffectCandidate
        The first round's best candidate of every effect, best first.
    rounds : tuple of tuple of EffectCandidate
        Each round's ranking (by the score test).
    trials : tuple of tuple of EffectCandidate
        Each round's leading candidates fitted for real, judged on the actual drop of the output error (the
        best significant one is accepted).
    steps : tuple of (tuple of str, IdentifiedModel)
        After each round, the effects the model holds and the model refitted with them (the last is
        `model_after`). An effect found earlier is dropped when the one found later makes it redundant.
    model_before, model_after : IdentifiedModel
    before, after : dict
        ``r2``, ``nrmse_pct``, ``max_dev_pct`` (means over the states, and per state under ``per_state``), and
        ``white`` (the free-run residual passes the whiteness test for every state).
    residuals_before, residuals_after : ResidualAnalysis
    message : str
        One sentence: what was found, or "no effect found" and whether the residual is white.
    """

    effects: tuple[EffectCandidate, ...]
    ranking: tuple[EffectCandidate, ...]
    rounds: tuple[tuple[EffectCandidate, ...], ...]
    trials: tuple[tuple[EffectCandidate, ...], ...]
    steps: tuple[tuple[tuple[str, ...], IdentifiedModel], ...]
    model_before: IdentifiedModel
    model_after: IdentifiedModel
    before: dict[str, Any]
    after: dict[str, Any]
    residuals_before: ResidualAnalysis
    residuals_after: ResidualAnalysis
    message: str
    data: Trajectory | None = None

    @property
    def found(self) -> bool:
        return bool(self.effects)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: ``effects`` (ranked, empty when none), ``before``/``after`` with ``nrmse_pct`` and ``r2``."""
        return {"effects": [e.to_dict() for e in self.effects], "before": self.before, "after": self.after,
                "ranking": [e.to_dict() for e in self.ranking[:12]], "message": self.message,
                "trials": [[{"name": c.name, "attached_to": c.attached_to, "delta_bic": c.delta_bic,
                             "significant": c.significant, "parameters": dict(c.parameters)} for c in round_]
                           for round_ in self.trials],
                "equations_after": self.model_after.equations()}

    def plot_evidence(self, path: str | os.PathLike) -> Path:
        """PNG: for each accepted effect (or the top candidate), the equation residual of its row against the
        signal it attaches to, before and after: friction shows as a step at zero speed that disappears."""
        from ..figures import pyplot, save_figure

        plt = pyplot()

        shown = list(self.effects) or list(self.ranking[:1])
        fig, axes = plt.subplots(1, max(len(shown), 1), figsize=(5.5 * max(len(shown), 1), 4.2), squeeze=False)
        for ax, cand in zip(axes[0], shown, strict=False):
            row = cand.rows[0] if cand.rows else self.model_before.states[-1]
            i = self.model_before.states.index(row)
            signal_name = cand.attached_to.split("-")[0] if cand.attached_to != "constant" else None
            x_data = self.data[signal_name][:-1] if self.data is not None and signal_name in self.data.names else \
                self.residuals_before.time[1:]
            step = max(1, len(x_data) // 6000)
            ax.plot(x_data[::step], self.residuals_before.equation[::step, i], ".", ms=1.5, alpha=0.5,
                    label="before (model without it)")
            ax.plot(x_data[::step], self.residuals_after.equation[::step, i], ".", ms=1.5, alpha=0.5,
                    label="after (model with it)")
            ax.set_xlabel(signal_name or "time [s]")
            ax.set_ylabel(f"equation residual of {row}'")
            ax.set_title(f"{cand.name} on {cand.attached_to}", fontsize=9)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8, markerscale=5)
        fig.tight_layout()
        return save_figure(fig, path)

    def write_report(self, path: str | os.PathLike, *, title: str = "Diagnosis") -> Path:
        """One HTML file: the verdict, the ranking, the parameters, before/after figures and the plots."""
        path = Path(path)
        report = Report(title, subtitle=self.message)
        self.add_to_report(report, path.with_suffix(""))
        return report.write(path)

    def add_to_report(self, report: Report, stem: str | os.PathLike) -> list[Path]:
        """Add the diagnosis sections to `report`: the effects with their parameters (± standard error), the
        error before and after, the first round's candidates, the evidence, the residuals before and after,
        the free run against the data, and the equations after.

        Parameters
        ----------
        report : cosim.report.Report
            The report to extend (one job's report can hold the diagnosis with its other stages).
        stem : path-like
            Path prefix of the PNG files written: ``<stem>_evidence.png``, ``<stem>_residuals_before.png``,
            ``<stem>_residuals_after.png``, ``<stem>_free_run.png``.

        Returns
        -------
        list of Path
            The PNG files written.
        """
        from ..data.plots import plot_trajectory

        stem = Path(stem)
        pngs: list[Path] = []
        report.add_table("Effects found", [{"rank": i + 1, "effect": e.name, "attached to": e.attached_to,
                                            "rows": ", ".join(e.rows), "meaning": e.meaning,
                                            **{k: float(f"{v:.5g}") for k, v in e.parameters.items()},
                                            **{f"±{k}": float(f"{v:.3g}") for k, v in e.uncertainty.items()}}
                                           for i, e in enumerate(self.effects)] or [{"result": "no effect found"}])
        report.add_table("Error before and after", [
            {"": "before", **{k: self.before[k] for k in ("r2", "nrmse_pct", "max_dev_pct", "white")}},
            {"": "after", **{k: self.after[k] for k in ("r2", "nrmse_pct", "max_dev_pct", "white")}}],
            caption="free-run simulation against the data; means over the states")
        report.add_table("Candidates (first round)", [
            {"effect": c.name, "attached to": c.attached_to, "nuisance": c.nuisance, "delta BIC": round(c.delta_bic, 1),
             "p-value": float(f"{c.p_value:.3g}"), "significant": c.significant} for c in self.ranking])
        pngs.append(Path(self.plot_evidence(f"{stem}_evidence.png")))
        report.add_figure("Evidence", pngs[-1])
        pngs.append(Path(self.residuals_before.plot(f"{stem}_residuals_before.png")))
        report.add_figure("Residuals before", pngs[-1])
        pngs.append(Path(self.residuals_after.plot(f"{stem}_residuals_after.png")))
        report.add_figure("Residuals after", pngs[-1])
        if self.data is not None:
            sims = []
            for label, model in (("before", self.model_before), ("after", self.model_after)):
                sim = _free_run(model, self.data)
                if sim is not None:
                    sims.append((f"model {label}", sim))
            pngs.append(Path(plot_trajectory(self.data.select(list(self.model_before.states)), f"{stem}_free_run.png",
                                             label="data", others=sims)))
            report.add_figure("Free run against the data", pngs[-1])
        report.add_text("Equations after", "\n\n".join(self.model_after.equations()))
        return pngs


# ---------------------------------------------------------------------------------------------- helpers
def _columns(model: IdentifiedModel, data: Trajectory) -> dict[str, np.ndarray]:
    missing = [n for n in (*model.states, *model.inputs) if n not in data.names]
    if missing:
        from ..errors import UnknownVariableError

        raise UnknownVariableError(f"the data have no column {missing[0]!r} that the model needs; "
                                   f"columns are {list(data.names)}")
    return {name: np.asarray(data[name], dtype=float) for name in data.names}


def _x0(model: IdentifiedModel, data: Trajectory) -> np.ndarray:
    meta_x0 = model.meta.get("x0") if isinstance(model.meta, Mapping) else None
    if meta_x0:
        return np.asarray(meta_x0[0], dtype=float)
    return np.array([data[name][0] for name in model.states])


@dataclass(frozen=True)
class _FitOptions:
    """How every output-error fit of one diagnosis treats the initial state and the noise levels."""

    estimate_x0: bool
    noise: Mapping[str, float] | None

    @property
    def kw(self) -> dict[str, Any]:
        return {"estimate_x0": self.estimate_x0, "noise": self.noise}


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


def _free_run(model: IdentifiedModel, data: Trajectory) -> Trajectory | None:
    u = np.column_stack([data[n] for n in model.inputs]) if model.inputs else np.zeros((len(data), 0))
    sim = model.simulate(_x0(model, data), u[:-1], dt=data.dt, t0=float(data.time[0]))
    return sim.to_trajectory() if sim.ok else None


def _figures(model: IdentifiedModel, data: Trajectory, res: ResidualAnalysis,
             x0: np.ndarray | None = None) -> dict[str, Any]:
    truth = np.column_stack([data[name] for name in model.states])
    u = np.column_stack([data[n] for n in model.inputs]) if model.inputs else np.zeros((len(data), 0))
    sim = model.simulate(_x0(model, data) if x0 is None else x0, u[:-1], dt=data.dt)
    if not sim.ok:
        return {"r2": None, "nrmse_pct": None, "max_dev_pct": None, "white": False, "status": sim.status,
                "per_state": {}}
    fit = np.atleast_1d(nrmse_fit_pct(truth, sim.states))
    rr = np.atleast_1d(r2(truth, sim.states))
    dev = np.atleast_1d(max_deviation_pct(truth, sim.states))
    per_state = {name: {"r2": float(rr[i]), "nrmse_pct": float(100.0 - fit[i]), "fit_pct": float(fit[i]),
                        "max_dev_pct": float(dev[i])} for i, name in enumerate(model.states)}
    return {"r2": float(np.mean(rr)), "nrmse_pct": float(np.mean(100.0 - fit)), "max_dev_pct": float(np.mean(dev)),
            "white": bool(res.white), "status": sim.status, "per_state": per_state}


def _with_columns(traj: Trajectory, columns: Mapping[str, np.ndarray]) -> Trajectory:
    """`traj` plus the derived columns (a delayed input) that it lacks."""
    extra = {k: v for k, v in columns.items() if k not in traj.names}
    if not extra:
        return traj
    return Trajectory.from_arrays(traj.time, {**{n: traj[n] for n in traj.names}, **extra},
                                  roles={**dict(zip(traj.names, traj.roles, strict=True)),
                                         **dict.fromkeys(extra, "input")})


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


def _with_effect(model: IdentifiedModel, cand: EffectCandidate, new_inputs: list[str]) -> IdentifiedModel:
    """The model with the candidate's terms in its rows, at the coefficients the screening estimated."""
    terms = list(model.terms) + [t for t in cand.terms if t not in model.terms]
    coef = np.zeros((len(model.states), len(terms)))
    coef[:, :len(model.terms)] = model.coef
    q = len(cand.terms)
    for r_i, row in enumerate(cand.rows):
        i = model.states.index(row)
        for t_i, term in enumerate(cand.terms):
            value = cand.coefficients[r_i * q + t_i] if cand.coefficients else 0.0
            coef[i, terms.index(term)] = value if value != 0.0 else 1e-12
    meta = {"x0": model.meta["x0"]} if isinstance(model.meta, Mapping) and "x0" in model.meta else {}
    return IdentifiedModel(states=model.states, inputs=tuple(model.inputs) + tuple(new_inputs), terms=tuple(terms),
                           coef=coef, dt=model.dt, meta=meta)


def _write_back(accepted: list[EffectCandidate], owners: Sequence[int], nuisances: Sequence[Nuisance]) -> None:
    """Put the fitted nuisance values (and the terms written with them) on the accepted effects."""
    for j, nu in zip(owners, nuisances, strict=True):
        accepted[j] = replace(accepted[j], nuisance=nu.value, terms=nu.terms, nuisance_se=nu.std_error)


#: How many of a round's leading candidates are fitted for real before one is accepted.
VERIFY_TOP = 6
#: Gauss-Newton iterations of a trial fit (the winner is then fitted to convergence).
TRIAL_ITERATIONS = 4


@dataclass
class _Trial:
    candidate: EffectCandidate
    model: IdentifiedModel
    nuisances: list[Nuisance]
    nuisance: Nuisance | None
    new_columns: dict[str, np.ndarray]


def _fit_with(current: IdentifiedModel, cand: EffectCandidate, columns: dict[str, np.ndarray], dt: float,
              nuisances: list[Nuisance], screen: OutputErrorScreen, alpha: float, bic_margin: float,
              min_size: float, fit: _FitOptions, iterations: int = 15) -> _Trial | None:
    """The model refitted with `cand` added (its nuisance parameter too), scored on the actual output error."""
    effect = EFFECTS[cand.name]
    signals = tuple(cand.attached_to.split("-")) if cand.attached_to != "constant" else ()
    placed = Attachment(cand.attached_to, signals, cand.rows)
    new_cols = effect.columns(placed, cand.nuisance, columns)
    cols = {**columns, **new_cols}
    fit_terms = effect.fit_terms(placed, cand.nuisance)
    if fit_terms != cand.terms:  # more terms than the screening's: they start at zero
        start = dict(zip(cand.terms, np.reshape(cand.coefficients, (len(cand.rows), -1)).T, strict=True)) \
            if cand.coefficients else {}
        coefficients = np.column_stack([start.get(t, np.zeros(len(cand.rows))) for t in fit_terms]).reshape(-1)
        cand = replace(cand, terms=fit_terms, coefficients=tuple(float(c) for c in coefficients))
    trial = _with_effect(current, cand, list(new_cols))
    if free_run_cost(trial, cols, dt, screen.x0, screen.sigma) > float(screen.residual @ screen.residual):
        # the score's one linear step overshoots (a drifting free run): start the effect from zero instead
        trial = _with_effect(current, replace(cand, coefficients=()), list(new_cols))
    nuis = list(nuisances)
    own = None
    if effect.nuisance is not None and not effect.integer and effect.fit_nuisance:
        own = Nuisance(lambda v, e=effect, a=placed: e.terms(a, v), float(cand.nuisance))
        nuis.append(own)
    try:
        model, se, nuis = output_error_fit(trial, cols, dt, nuisances=nuis, iterations=iterations, **fit.kw)
        if own is not None:
            cand = replace(cand, nuisance=nuis[-1].value, terms=nuis[-1].terms, nuisance_se=nuis[-1].std_error)
        if effect.physical is not None:
            model, se, nuis, cand = _physical_nuisance(model, cand, effect, placed, cols, dt, nuis, iterations, fit)
        pruned = _prune_rows(model, se, cand)
        if pruned is not None:
            model, cand = pruned
            model, se, nuis = output_error_fit(model, cols, dt, nuisances=nuis, **fit.kw)
            if own is not None:
                cand = replace(cand, nuisance=nuis[-1].value, terms=nuis[-1].terms, nuisance_se=nuis[-1].std_error)
    except (DataError, np.linalg.LinAlgError, FloatingPointError):
        return None
    cost0 = float(screen.residual @ screen.residual)
    cost1 = float(model.meta["refinement"]["cost"])
    q = len(cand.terms) * len(cand.rows) + (1 if own is not None else 0)
    if cost1 >= cost0:
        return None
    delta_bic, p_value, size, factor = _evidence(screen, model, cols, dt, cost0, cost1, q)
    plausible = effect.is_plausible(_final_parameters(cand, model).parameters)
    cand = replace(cand, delta_bic=delta_bic, p_value=p_value,
                   explained={"size": size, "plausible": plausible, "correlation_factor": factor},
                   significant=bool(p_value < alpha and delta_bic < -bic_margin and size >= min_size and plausible))
    return _Trial(cand, model, nuis, own, new_cols)


def _evidence(screen: OutputErrorScreen, fuller: IdentifiedModel, cols: Mapping[str, np.ndarray], dt: float,
              cost0: float, cost1: float, q: int) -> tuple[float, float, float, float]:
    """What `q` more parameters bought, from cost `cost0` (the model of `screen`) to `cost1` (`fuller`): the BIC
    change, the likelihood-ratio p-value, the size (share of the data's spread) and the residual's correlation
    factor. A residual the fuller model leaves coloured holds fewer independent samples than it has
    (:func:`~cosim.diagnose.screening.correlation_factor`): both tests count samples by it."""
    after = free_run_residual(fuller, cols, dt, fuller.meta["x0"][0], screen.sigma)
    factor = correlation_factor(after) if after is not None else 1.0
    n_eff = screen.n_obs / factor
    delta_bic = n_eff * math.log(cost1 / cost0) + q * math.log(n_eff)
    variance = factor * cost1 / max(screen.n_obs - screen.base.shape[1] - q, 1)
    p_value = float(stats.chi2.sf((cost0 - cost1) / variance, q))
    size = math.sqrt(cost0 - cost1) / max(screen.scale_y, 1e-300)
    return delta_bic, p_value, size, factor


def _physical_nuisance(model: IdentifiedModel, cand: EffectCandidate, effect: Effect, placed: Attachment,
                       cols: dict[str, np.ndarray], dt: float, nuis: list[Nuisance], iterations: int,
                       fit: _FitOptions):
    """Move a nuisance the data pin only through a product (a backlash's width) to its physical value.

    The term is rewritten at the value :attr:`Effect.physical` gives, its coefficients scaled to keep the
    product, and the model refitted; twice, since the part of the record inside the band changes with it.
    """
    se = np.zeros_like(model.coef)
    for _ in range(2):
        coef = {row: model.coef[model.states.index(row), [model.terms.index(t) for t in cand.terms]]
                for row in cand.rows if all(t in model.terms for t in cand.terms)}
        value = effect.physical(coef, float(cand.nuisance), Roles.of(model), placed) if coef else None
        if value is None or abs(math.log(value / cand.nuisance)) < 0.01:
            break
        terms, matrix = list(model.terms), model.coef.copy()
        new_terms = effect.terms(placed, value)
        for old, new in zip(cand.terms, new_terms, strict=True):
            k = terms.index(old)
            terms[k] = new
            matrix[:, k] *= cand.nuisance / value
        moved = IdentifiedModel(states=model.states, inputs=model.inputs, terms=tuple(terms), coef=matrix,
                                dt=model.dt, meta=model.meta)
        model, se, nuis = output_error_fit(moved, cols, dt, nuisances=nuis, iterations=iterations, **fit.kw)
        cand = replace(cand, nuisance=value, terms=new_terms)
    return model, se, nuis, cand


def _drop_redundant(current: IdentifiedModel, accepted: list[EffectCandidate], owners: list[int],
                    nuisances: list[Nuisance], columns: dict[str, np.ndarray], dt: float, alpha: float,
                    bic_margin: float, min_size: float, fit: _FitOptions):
    """Backward check: each earlier effect is removed and the model refitted; if the removal does not cost a
    significant rise of the output error (the same test as for adding it), the effect goes."""
    for j in range(len(accepted) - 2, -1, -1):
        cand = accepted[j]
        keep = [k for k in range(len(current.terms)) if current.terms[k] not in cand.terms]
        own = owners.index(j) if j in owners else None
        rest = [nu for k, nu in enumerate(nuisances) if k != own]
        reduced = IdentifiedModel(states=current.states, inputs=current.inputs,
                                  terms=tuple(current.terms[k] for k in keep), coef=current.coef[:, keep],
                                  dt=current.dt, meta=current.meta)
        try:
            reduced, _, rest = output_error_fit(reduced, columns, dt, nuisances=rest, iterations=40, **fit.kw)
        except (DataError, np.linalg.LinAlgError, FloatingPointError):
            continue
        cost_full = float(current.meta["refinement"]["cost"])
        cost_reduced = float(reduced.meta["refinement"]["cost"])
        if cost_reduced <= cost_full:
            pays = False
        else:
            q = len(cand.terms) * len(cand.rows) + (1 if own is not None else 0)
            delta_bic, p_value, size, _ = _evidence(OutputErrorScreen(reduced, columns, dt, **fit.kw), current,
                                                    columns, dt, cost_reduced, cost_full, q)
            pays = p_value < alpha and delta_bic < -bic_margin and size >= min_size
        if not pays:
            current, nuisances = reduced, rest
            accepted = accepted[:j] + accepted[j + 1:]
            owners = [k - (k > j) for k in owners if k != j]
    return current, accepted, owners, nuisances


#: A row keeps an effect's terms only if one of them stands this many standard errors from zero.
ROW_T_MIN = 10.0


def _prune_rows(model: IdentifiedModel, se: np.ndarray, cand: EffectCandidate):
    """Drop the rows where the effect's coefficients are not clearly non-zero after the fit (None: keep all)."""
    if len(cand.rows) < 2:
        return None
    keep = []
    for row in cand.rows:
        i = model.states.index(row)
        t = [abs(model.coef[i, model.terms.index(term)]) / max(se[i, model.terms.index(term)], 1e-300)
             for term in cand.terms if term in model.terms]
        if t and max(t) >= ROW_T_MIN:
            keep.append(row)
    if len(keep) == len(cand.rows) or not keep:
        return None
    coef = model.coef.copy()
    for row in cand.rows:
        if row not in keep:
            for term in cand.terms:
                if term in model.terms:
                    coef[model.states.index(row), model.terms.index(term)] = 0.0
    pruned = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=coef, dt=model.dt,
                             meta=model.meta)
    return pruned, replace(cand, rows=tuple(keep))


def _final_parameters(cand: EffectCandidate, model: IdentifiedModel) -> EffectCandidate:
    """The candidate with parameters (and standard errors) from the final model's coefficients."""
    effect = EFFECTS[cand.name]
    roles = Roles.of(model)
    refinement = model.meta.get("refinement", {}) if isinstance(model.meta, Mapping) else {}
    order = {(int(i), str(t)): k for k, (i, t) in enumerate(refinement.get("parameters", []))}
    full = np.asarray(refinement["covariance"]) if "covariance" in refinement else None
    coef, index = {}, []
    for row in cand.rows:
        i = model.states.index(row)
        terms = [t for t in cand.terms if t in model.terms]
        if not terms:
            continue
        coef[row] = model.coef[i, [model.terms.index(t) for t in terms]]
        index += [order.get((i, t), -1) for t in terms]
    if not coef:
        return cand
    attachment = Attachment(cand.attached_to, tuple(cand.attached_to.split("-")), cand.rows)
    params = effect.parameters(coef, cand.nuisance, roles, attachment)
    if "delay_samples" in params and model.dt:
        params["delay_s"] = params["delay_samples"] * float(model.dt)
    unc = dict(cand.uncertainty)
    if full is not None and index and min(index) >= 0:
        unc = _uncertainty(effect, coef, full[np.ix_(index, index)], cand.nuisance, roles, attachment)
    if "delay_samples" in unc and model.dt:
        unc["delay_s"] = unc["delay_samples"] * float(model.dt)
    if cand.nuisance_se and effect.nuisance in params:
        unc[effect.nuisance] = float(cand.nuisance_se)
    return replace(cand, parameters=params, uncertainty=unc)
