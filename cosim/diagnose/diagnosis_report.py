"""The diagnosis report: what :func:`~cosim.diagnose.diagnosis.diagnose` found, as tables, figures, HTML and JSON.

* :class:`DiagnosisReport` - the accepted effects, every round's candidates and trial fits, the model before
  and after with their free-run errors and residuals; as JSON (:meth:`~DiagnosisReport.to_dict`), one HTML
  file (:meth:`~DiagnosisReport.write_report`, or sections of another report) and the evidence plot;
* ``_figures`` - a model's free-run error against data (R², NRMSE, maximum deviation, whiteness): the
  report's ``before`` and ``after``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..data.trajectory import Trajectory
from ..identify.metrics import max_deviation_pct, nrmse_fit_pct, r2
from ..identify.model import IdentifiedModel
from ..report import Report, html_table, step_text
from ._holdout import HELD_OUT_T
from .candidates import EffectCandidate
from .residuals import ResidualAnalysis

if TYPE_CHECKING:
    import matplotlib.figure

    from .ambiguity import Ambiguity

__all__ = ["DiagnosisReport"]


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
    data : Trajectory or None
        The (first) record, with any column an effect added.
    rejected : tuple of EffectCandidate
        Candidates that were significant on the data they were fitted to but did not lower the free-run error on
        held-out data: not findings; their ``explained`` holds ``held_out_t`` and the held-out NRMSE without and
        with them.
    dropped_terms : tuple of str
        Terms of the model before (``"row: term"``) dropped once an effect made them redundant (a spring standing
        in for friction).
    analysis : dict
        The step the search ran at: ``decimation`` (the factor the records were decimated by; 1: none), ``dt``
        and ``record_dt`` in s. `rounds`, `trials`, `steps` and `rejected` are of that step; `effects`,
        `model_after` and the figures of the records' own.
    ambiguous : tuple of Ambiguity
        Readings these data cannot tell apart (gravity or a spring to ground over small swings), each with the
        experiment that would (:mod:`~cosim.diagnose.ambiguity`).
    rivals : tuple of (EffectCandidate, EffectCandidate)
        Each accepted effect and another effect whose fit, to convergence as the accepted one's, came within
        the BIC margin of it in that round (the source of the rival sets in `ambiguous`).
    rival_models : tuple of (IdentifiedModel, IdentifiedModel)
        For each of `rivals`, the model with the accepted effect and the model with its rival, as fitted in that
        round (what the experiment between them is computed on).
    experiments : tuple of dict
        Experiments run on a plant (``plant=``) to settle an ambiguity: ``effects``, ``input_scale``,
        ``signal``, ``swing`` (half its range in the run), ``samples``; their records were diagnosed beside the
        data's.
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
    rejected: tuple[EffectCandidate, ...] = ()
    dropped_terms: tuple[str, ...] = ()
    analysis: dict[str, Any] = field(default_factory=dict)
    ambiguous: tuple[Ambiguity, ...] = ()
    rivals: tuple[tuple[EffectCandidate, EffectCandidate], ...] = ()
    rival_models: tuple[tuple[IdentifiedModel, IdentifiedModel], ...] = field(default=(), repr=False, compare=False)
    experiments: tuple[dict[str, Any], ...] = ()

    @property
    def found(self) -> bool:
        return bool(self.effects)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: ``effects`` (accepted, in the order found; empty when none), ``before``/``after`` with
        ``nrmse_pct`` and ``r2``, ``rejected`` (candidates that failed on held-out data), ``dropped_terms``, and
        ``model_before``, the model diagnosed as a model file holds it
        (:meth:`~cosim.identify.model.IdentifiedModel.from_dict` reads it back: the base that ``cosim diagnose``
        identified, when it was given none)."""
        return {"effects": [e.to_dict() for e in self.effects], "before": self.before, "after": self.after,
                "ranking": [e.to_dict() for e in self.ranking[:12]], "message": self.message,
                "trials": [[{"name": c.name, "attached_to": c.attached_to, "delta_bic": c.delta_bic,
                             "significant": c.significant, "parameters": dict(c.parameters)} for c in round_]
                           for round_ in self.trials],
                "rejected": [e.to_dict() for e in self.rejected], "dropped_terms": list(self.dropped_terms),
                "analysis": dict(self.analysis), "ambiguous": [a.to_dict() for a in self.ambiguous],
                "to_separate": [{"effects": list(a.effects), **a.to_separate} for a in self.ambiguous],
                "experiments": [dict(e) for e in self.experiments],
                "equations_after": self.model_after.equations(), "model_before": self.model_before.to_dict()}

    def plot_evidence(self, path: str | os.PathLike | None = None, *, bins: int = 30) -> matplotlib.figure.Figure:
        """For each accepted effect (or the top candidate), the residuals of its row against the signal it
        attaches to, before and after, averaged in bins: friction shows as a step at zero speed (or, once a
        linear model has taken part of it up as damping, a slope) that disappears.

        Two panels per effect: the equation residual (what the right-hand side misses; on noisy data the
        derivative's noise can bury it) and the free-run residual (what the simulation misses). Each bin of the
        signal is a point at the mean residual with an error bar of ± one standard deviation (the spread).

        Parameters
        ----------
        path : path-like, optional
            Write the figure there as PNG too.
        bins : int
            Number of equal bins over the range of the signal.

        Returns
        -------
        matplotlib.figure.Figure
        """
        from ..figures import FONT_SIZE, finish, new_figure

        shown = list(self.effects) or list(self.ranking[:1])
        fig = new_figure(figsize=(12, 4.0 * max(len(shown), 1) + 0.4), layout="constrained")
        axes = fig.subplots(max(len(shown), 1), 2, squeeze=False)
        for (eq_ax, run_ax), cand in zip(axes, shown, strict=False):
            row = cand.rows[0] if cand.rows else self.model_before.states[-1]
            i = self.model_before.states.index(row)
            signal = cand.attached_to.split("-")[0] if cand.attached_to != "constant" else None
            if self.data is not None and signal in self.data.names:
                x, x_label = self.data[signal], _label(self.data, signal)
            else:
                x, x_label = self.residuals_before.time, "time [s]"
            unit = _unit(self.data, row)
            panels = ((eq_ax, "equation", x[:-1], f"equation residual of {row}'", _per_second(unit)),
                      (run_ax, "free_run", x, f"free-run residual of {row}", unit))
            for ax, kind, where, what, what_unit in panels:
                for j, (key, res) in enumerate((("before", self.residuals_before), ("after", self.residuals_after))):
                    _binned(ax, where, getattr(res, kind)[:, i], bins, key, shift=(j - 0.5) * 0.25)
                ax.axhline(0.0, color="k", lw=0.6)
                ax.set_xlabel(x_label, fontsize=FONT_SIZE + 1)
                ax.set_ylabel(f"{what} [{what_unit}]" if what_unit else what, fontsize=FONT_SIZE)
                ax.set_title(f"{cand.name} on {cand.attached_to}: {what}", fontsize=FONT_SIZE + 1)
                ax.grid(alpha=0.3)
                ax.legend(fontsize=FONT_SIZE)
        return finish(fig, path)

    def plot_free_run(self, path: str | os.PathLike | None = None) -> matplotlib.figure.Figure | None:
        """The data and the free runs of the model before and after, with their errors under each state.

        Parameters
        ----------
        path : path-like, optional
            Write the figure there as PNG too.

        Returns
        -------
        matplotlib.figure.Figure or None
            None without data (a report read back from JSON).
        """
        from ..data.plots import plot_trajectory
        from ..figures import COLOURS

        if self.data is None:
            return None
        sims = []
        for label, model in (("before", self.model_before), ("after", self.model_after)):
            sim = _free_run(model, self.data)
            if sim is not None:
                sims.append((f"model {label}", sim, COLOURS[label]))
        return plot_trajectory(self.data.select(list(self.model_before.states)), path, label="data", others=sims,
                               errors=True, title="Free run of the model before and after, against the data")

    def _repr_html_(self) -> str:
        """Jupyter's view: the effects found and the error before and after, as two small tables."""
        effects = [{"effect": e.name, "attached to": e.attached_to,
                    **{k: f"{v:.5g}" + (f" ± {e.uncertainty[k]:.2g}" if k in e.uncertainty else "")
                       for k, v in e.parameters.items()}} for e in self.effects] or [{"effect": "none found"}]
        errors = [{"": label, "NRMSE %": _number(figures.get("nrmse_pct")), "R²": _number(figures.get("r2"), 6),
                   "max dev %": _number(figures.get("max_dev_pct")), "white": figures.get("white")}
                  for label, figures in (("before", self.before), ("after", self.after))]
        marks = {(k, "white"): bool(row["white"]) for k, row in enumerate(errors)}
        return (f"<div>{html_table(effects, caption='Diagnosis: ' + self.message)}"
                f"{html_table(errors, caption='free-run error against the data', highlight=marks)}</div>")

    def write_report(self, path: str | os.PathLike, *, title: str = "Diagnosis", seconds: float | None = None,
                     records: Sequence[Trajectory] | None = None, model_from: str = "",
                     against: str = "the data") -> Path:
        """One HTML file: the summary box (:meth:`summary`), the effects, the ranking, the parameters,
        before/after figures and the plots.

        Parameters
        ----------
        path : path-like
            The HTML file (PNG plots beside it, named after it).
        title : str
        seconds, records, model_from, against
            For the summary box: see :meth:`summary`.

        Returns
        -------
        Path
        """
        path = Path(path)
        report = Report(title, subtitle=self.message)
        report.add_summary(**self.summary(records, seconds=seconds, model_from=model_from, against=against))
        self.add_to_report(report, path.with_suffix(""))
        return report.write(path)

    def summary(self, records: Sequence[Trajectory] | None = None, *, seconds: float | None = None,
                model_from: str = "", against: str = "the data") -> dict[str, Any]:
        """The facts a report opens with (keyword arguments of :func:`cosim.report.summary_box`): the plant and
        the data (from the records' files and metadata), the model diagnosed, the effects found with their
        parameters ± standard error (or why none), the free-run NRMSE before and after per state, the time.

        Parameters
        ----------
        records : sequence of Trajectory, optional
            The records diagnosed, as read (their ``meta`` names the file, the FMU that made them, the noise
            added); default: :attr:`data`.
        seconds : float, optional
            How long the diagnosis took, measured where it ran.
        model_from : str
            Where the model diagnosed came from (a file, "identified from the data"...).
        against : str
            What the free-run errors are measured against.

        Returns
        -------
        dict
        """
        records = list(records) if records is not None else [self.data] if self.data is not None else []
        plant, data = _plant_and_data(records, self.model_before, self.analysis)
        model = self.model_before
        context = [("Model", (f"{model_from}: " if model_from else "")
                    + f"{len(model.states)} states ({', '.join(model.states)}), inputs {', '.join(model.inputs)}, "
                    f"{int(np.count_nonzero(model.coef))} terms")]
        mean = "mean of the measured" if _measured_of(self.after) else "mean"
        errors = {label: {**{k: v["nrmse_pct"] for k, v in figures.get("per_state", {}).items()},
                          mean: figures.get("nrmse_pct")} for label, figures in (("before", self.before),
                                                                                 ("after", self.after))}
        more = []
        if self.rejected:
            more.append(("Not claimed", "; ".join(f"{c.name} on {c.attached_to}" for c in self.rejected)
                         + ": better on the data fitted to, not on held-out data"))
        more += [("Cannot tell apart", a.sentence()) for a in self.ambiguous]
        more += [("Experiment run", f"{', '.join(e['effects'])}: the record's input x{e['input_scale']:g} on the "
                  f"plant, {e['signal']} swinging ±{e['swing']:.3g}") for e in self.experiments]
        return {"plant": plant, "data": data, "context": context, "effects": [e.to_dict() for e in self.effects],
                "no_effect": self.message.removeprefix("no effect found: "), "errors": errors,
                "error_label": f"free-run NRMSE, % of each state's spread, against {against} (lower is better)",
                "more": more, "seconds": seconds}

    def _states_note(self) -> str:
        """Which states the summary figures are means over: the measured ones (not a derived velocity)."""
        states = _measured_of(self.after)
        return f"measured states ({', '.join(states)})" if states else "states"

    def _rate_note(self) -> str:
        """A caption's note of the step the search ran at, when it is not the record's ("" otherwise)."""
        factor = self.analysis.get("decimation", 1)
        if factor == 1:
            return ""
        return (f"; the search ran on the record decimated by {factor} ({1.0 / self.analysis['dt']:.4g} Hz), the "
                f"effects were then refitted at its own {1.0 / self.analysis['record_dt']:.4g} Hz")

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
        from ..figures import COLOURS, save_figure

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
            caption="free-run simulation against the data; means over the " + self._states_note() + self._rate_note())
        if self.rejected:
            report.add_table("Rejected: better in-sample, not on held-out data (or refitted out of range)", [
                {"effect": c.name, "attached to": c.attached_to,
                 "plausible": bool(c.explained.get("plausible", True)),
                 "held-out NRMSE without [%]": float(f"{c.explained.get('held_out_nrmse_without_pct', np.nan):.4g}"),
                 "held-out NRMSE with [%]": float(f"{c.explained.get('held_out_nrmse_with_pct', np.nan):.4g}"),
                 "held-out t": float(f"{c.explained.get('held_out_t', np.nan):.3g}"),
                 **{k: float(f"{v:.5g}") for k, v in c.parameters.items()}} for c in self.rejected],
                caption="each model fitted on one half of every record and simulated on the other half; an effect "
                        "is accepted only if it lowers that error by more than noise explains")
        if self.dropped_terms:
            report.add_text("Terms dropped", "No longer needed once the effects were in: " +
                            ", ".join(self.dropped_terms))
        report.add_table("Candidates (first round)", [
            {"effect": c.name, "attached to": c.attached_to, "nuisance": c.nuisance, "delta BIC": round(c.delta_bic, 1),
             "p-value": float(f"{c.p_value:.3g}"), "significant": c.significant} for c in self.ranking])
        figures = [("Evidence", "evidence", self.plot_evidence(),
                    "binned means ± one standard deviation of the residuals of the effect's row, against the "
                    "signal it attaches to"),
                   ("Residuals before", "residuals_before", self.residuals_before.plot(colour=COLOURS["before"]), ""),
                   ("Residuals after", "residuals_after", self.residuals_after.plot(colour=COLOURS["after"]), ""),
                   ("Free run against the data", "free_run", self.plot_free_run(),
                    "error: the data minus each model's free run")]
        for heading, name, fig, caption in figures:
            if fig is not None:
                pngs.append(save_figure(fig, f"{stem}_{name}.png", close=False))
                report.add_figure(heading, pngs[-1], caption=caption)
        report.add_text("Equations after", "\n\n".join(self.model_after.equations()))
        return pngs


# ---------------------------------------------------------------------------------------------- summary
def _plant_and_data(records: Sequence[Trajectory], model: IdentifiedModel,
                    analysis: Mapping[str, Any]) -> tuple[str | None, str | None]:
    """The summary's plant (the FMU that made the data, or the measured data's file) and data (files, samples,
    duration, step, noise: as added when the record says so, else estimated per state)."""
    from ._free_run import noise_level

    if not records:
        return None, None
    meta = records[0].meta or {}
    files = [Path(str((r.meta or {}).get("data_file", {}).get("file", ""))).name for r in records]
    if meta.get("source") == "fmu" and meta.get("fmu"):
        kind = {"cs": "co-simulation", "me": "Model Exchange"}.get(meta.get("kind"), meta.get("kind"))
        version = f"FMI {meta['fmi_version']}" if meta.get("fmi_version") else None
        what = ", ".join(str(x) for x in (meta.get("model"), version, kind) if x)
        plant = f"{meta['fmu']} ({what}), simulated by cosim"
    else:
        plant = "measured data" + (f": {', '.join(f for f in files if f)}" if any(files) else "") + \
            " (no plant model: the diagnosis reads the data alone)"
    parts = []
    for name, r in zip(files, records, strict=True):
        span = float(r.time[-1] - r.time[0])
        parts.append(f"{name + ': ' if name else ''}{len(r)} samples, {span:.4g} s at {step_text(r.dt)}")
    if len(parts) > 3:
        parts = [*parts[:2], f"... {len(parts)} records, {sum(len(r) for r in records)} samples in all"]
    noise = meta.get("noise") if isinstance(meta.get("noise"), Mapping) else None
    if noise and "level" in noise:
        parts.append(f"noise {noise['level'] * 100:.3g} % of each signal's std, added (seed {noise.get('seed')})")
    else:
        first = records[0]
        levels = {s: noise_level(first[s]) / np.std(first[s]) * 100 for s in model.states
                  if s in first.names and np.std(first[s]) > 0}
        parts.append("noise, estimated from second differences, % of each state's std: "
                     + ", ".join(f"{s} {v:.2g}" for s, v in levels.items()))
    if analysis.get("decimation", 1) > 1:
        parts.append(f"searched at {1.0 / analysis['dt']:.4g} Hz (decimated by {analysis['decimation']})")
    return plant, "; ".join(parts)


# ---------------------------------------------------------------------------------------------- figures
def _unit(data: Trajectory | None, name: str) -> str:
    return data.units[data.names.index(name)] if data is not None and name in data.names else ""


def _label(data: Trajectory, name: str) -> str:
    from ..figures import axis_label

    return axis_label(name, _unit(data, name))


def _per_second(unit: str) -> str:
    """The unit of a derivative: ``rad/s`` -> ``rad/s²``, ``rad`` -> ``rad/s``."""
    if not unit:
        return ""
    return unit[:-2] + "/s²" if unit.endswith("/s") else f"{unit}/s"


def _number(value: Any, digits: int = 4) -> Any:
    return "n/a" if value is None else float(f"{value:.{digits}g}")


def _binned(ax: Any, x: np.ndarray, y: np.ndarray, bins: int, key: str, *, shift: float = 0.0) -> None:
    """`y` against `x` as binned means ± one standard deviation, in the colour of `key` (before, after)."""
    from ..figures import COLOURS, binned_mean

    centre, mean, std, _ = binned_mean(x, y, bins)
    width = float(np.min(np.diff(centre))) if len(centre) > 1 else 0.0
    label = {"before": "before (model without it)", "after": "after (model with it)"}[key]
    ax.errorbar(centre + shift * width, mean, yerr=std, fmt="o", ms=4, lw=0.9, capsize=2, color=COLOURS[key],
                label=label)


def _x0(model: IdentifiedModel, data: Trajectory) -> np.ndarray:
    meta_x0 = model.meta.get("x0") if isinstance(model.meta, Mapping) else None
    if meta_x0:
        return np.asarray(meta_x0[0], dtype=float)
    return np.array([data[name][0] for name in model.states])


def _free_run(model: IdentifiedModel, data: Trajectory) -> Trajectory | None:
    u = np.column_stack([data[n] for n in model.inputs]) if model.inputs else np.zeros((len(data), 0))
    sim = model.simulate(_x0(model, data), u[:-1], dt=data.dt, t0=float(data.time[0]))
    return sim.to_trajectory() if sim.ok else None


def _figures(model: IdentifiedModel, data: Trajectory, res: ResidualAnalysis,
             x0: np.ndarray | None = None, measured: Sequence[str] | None = None) -> dict[str, Any]:
    """The free-run figures of `model` on `data`: per state, and their means over the `measured` states (None:
    all), the ones the diagnosis fitted: a velocity derived from a measured position is reported per state but
    is no measurement (a model that follows the positions better may follow their smoothed derivative worse)."""
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
    counted = [i for i, name in enumerate(model.states) if measured is None or name in measured] or \
        list(range(len(model.states)))
    return {"r2": float(np.mean(rr[counted])), "nrmse_pct": float(np.mean(100.0 - fit[counted])),
            "max_dev_pct": float(np.mean(dev[counted])), "white": bool(res.white), "status": sim.status,
            "per_state": per_state, "states": [model.states[i] for i in counted]}


def _measured_of(figures: Mapping[str, Any]) -> list[str] | None:
    """The states `figures`' means are over (:func:`_figures`' ``states``) where they leave some out (a velocity
    derived from a measured position); None where they are over every state."""
    states = figures.get("states")
    return list(states) if states and len(states) < len(figures.get("per_state") or states) else None


def _message(found: Sequence[EffectCandidate], before: Mapping[str, Any], after: Mapping[str, Any],
             res_before: ResidualAnalysis, rejected: Sequence[EffectCandidate]) -> str:
    """The report's one sentence."""
    if found:
        states = _measured_of(after)
        of = f" of the measured states ({', '.join(states)})" if states else ""
        return "found " + ", then ".join(f"{e.name} on {e.attached_to}" for e in found) + \
            f": free-run NRMSE{of} {before['nrmse_pct']:.3g} % -> {after['nrmse_pct']:.3g} %"
    odd = [c for c in rejected if c.explained.get("plausible", True) is False]
    # (an effect that beat noise on held-out data, with a model that still predicts them no better than their mean)
    poor = [c for c in rejected if c not in odd and c.explained.get("held_out_t", -math.inf) >= HELD_OUT_T
            and c.explained.get("held_out_predictive", True) is False]
    held = [c for c in rejected if c not in odd and c not in poor]
    tried = ("; " + ", ".join(f"{c.name} on {c.attached_to}" for c in held) +
             " lowered the error on the data it was fitted to but not on held-out data") if held else ""
    tried += "".join(f"; {c.name} on {c.attached_to} lowered the held-out error, but the model with it still "
                     f"predicts held-out data no better than their mean (NRMSE "
                     f"{c.explained['held_out_nrmse_with_pct']:.3g} %): identify a better base model first"
                     for c in poor)
    tried += ("; " + ", ".join(f"{c.name} on {c.attached_to}" for c in odd) +
              " was accepted, then refitted to parameters the plant cannot have, and dropped") if odd else ""
    if res_before.white:
        return "no effect found: the residual is white, the model explains the data" + tried
    return ("no effect found: the residual is not white, but no catalogued effect explains it "
            "(the model lacks something the catalogue does not cover)" + tried)
