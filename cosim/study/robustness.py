"""Robustness: Monte Carlo validation of a controller over the plant's parameters and undeclared effects.

Each sample draws the plant's physical parameters uniformly within ``±spread`` of their nominal values (the
FMU's start values; by default the two-mass servo's inertias, stiffness and damping) and each effect's
parameter uniformly in its range (``effects={"Fc": (0, 200)}``), runs :func:`cosim.loop.validation.validate` on
the FMU with them, and records pass or fail with the figures. The samples run through the sweep engine
(:func:`cosim.study.sweep.run_sweep`): local processes or a Dask cluster. A sample that raises counts as a failure.

The **worst case** is the sample that comes closest to (or goes furthest beyond) a spec limit: for each
``metric <= limit`` spec, the ratio ``value / limit`` (for ``>=``, ``limit / value``); the sample with the
largest ratio over all specs; a failed sample beats every passing one.

Examples
--------
>>> from cosim import build_fmu
>>> from controllers.pid import PID
>>> pid = PID(kp=1.5e4, ki=1.3e4, kd=6.4e3, tf=0.022, b=0.33, dt=1e-3, inputs="Tm", outputs="theta_L",
...           u_min=-5000, u_max=5000)
>>> rob = robustness(build_fmu(), pid, "step:amp=0.01,duration=2", ["overshoot<=60%"], samples=3, workers=1,
...                  progress=False)
>>> rob.samples, 0.0 <= rob.pass_rate <= 1.0, sorted(rob.worst["parameters"])
(3, True, ['BL', 'Bm', 'JL', 'Jm', 'KL'])
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..errors import InvalidSettingError, UnknownVariableError
from ..loop.validation import TELESCOPE_SPECS, Scenario, Spec, parse_scenario, parse_spec, validate
from ..plant.model_description import open_model_description
from .sweep import SweepResult, run_sweep

__all__ = ["DEFAULT_UNCERTAIN", "RobustnessResult", "robustness"]

#: Parameters of the bundled plant varied by default: inertias, stiffness and damping.
DEFAULT_UNCERTAIN = ("Jm", "JL", "KL", "Bm", "BL")


@dataclass(frozen=True)
class RobustnessResult:
    """The outcome of :func:`robustness`.

    Attributes
    ----------
    samples : int
    pass_rate : float
        Fraction of the samples that met every spec.
    worst : dict
        The worst sample: ``parameters``, ``passed``, ``reasons``, ``metrics``, ``score`` (largest spec ratio).
    table : pandas.DataFrame
        One row per sample: the drawn parameters, ``passed``, ``score``, the spec metrics, ``error``.
    sweep : SweepResult
        The raw sweep (where each sample ran, durations, errors).
    nominal : dict
        Nominal parameter values the spread applies to.
    """

    samples: int
    pass_rate: float
    worst: dict[str, Any]
    table: pd.DataFrame
    sweep: SweepResult
    nominal: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "pass_rate": self.pass_rate, "worst": self.worst, "nominal": self.nominal,
                "wall_time": self.sweep.wall_time, "scheduler": self.sweep.scheduler,
                "failed_to_run": self.sweep.n_failed}

    def _repr_html_(self) -> str:
        """Jupyter's view: the pass rate, and the nominal plant beside the worst one (with why it failed)."""
        from ..report import html_table

        worst = self.worst
        score = "n/a" if worst["score"] is None else float(f"{worst['score']:.3g}")
        rows = [{"plant": "nominal", **{k: float(f"{v:.4g}") for k, v in self.nominal.items()}},
                {"plant": "worst", **{k: float(f"{v:.4g}") for k, v in worst["parameters"].items()},
                 "passed": worst["passed"], "score": score}]
        why = "; ".join(worst["reasons"][:3])
        caption = (f"robustness: {self.samples} plants, pass rate {self.pass_rate:.1%}; the worst case "
                   + (f"fails: {why}" if why else "passes") + " (score: its largest value / limit over the specs)")
        return html_table(rows, caption=caption, highlight={(1, "passed"): bool(worst["passed"])})

    def save_table(self, path: str | os.PathLike) -> Path:
        """Write the per-sample table as CSV, atomically."""
        from ..files import atomic_output

        with atomic_output(path) as tmp:
            self.table.to_csv(tmp, index=False)
        return Path(path)


def _ratio(op: str, value: float | None, limit: float) -> float:
    """How close `value` comes to `limit` (1 = on the limit, above 1 = beyond it)."""
    if value is None or not math.isfinite(value):
        return math.inf
    if op in ("<=", "<"):
        return value / limit if limit > 0 else (math.inf if value > limit else 0.0)
    return limit / value if value > 0 else math.inf


def robustness_case(fmu: str, controller: dict[str, Any], scenarios: list[dict[str, Any]], specs: list[str],
                    parameters: dict[str, float], kind: str | None = None) -> dict[str, Any]:
    """One Monte Carlo sample (runs in a worker): validate with `parameters`, return pass, reasons, figures."""
    from controllers.base import controller_from_json

    ctrl = controller_from_json(controller)
    # the drawn plant wins over a scenario's own parameters; the scenario keeps its name (the table's columns)
    runs = [replace(Scenario.from_dict(s), parameters={**s.get("parameters", {}), **parameters}, name=s["name"])
            for s in scenarios]
    verdict = validate(fmu, ctrl, runs, specs, model=None, progress=False, kind=kind)
    metrics: dict[str, Any] = {}
    for check in verdict.checks:
        prefix = f"{check['scenario']}|" if len(runs) > 1 else ""
        metrics[prefix + check["metric"]] = check["value"]
    score = max((_ratio(parse_spec(c["spec"]).op, c["value"], c["limit"]) for c in verdict.checks
                 if c["passed"] is not None), default=0.0)
    return {"passed": verdict.passed, "reasons": list(verdict.reasons), "metrics": metrics,
            "score": score if math.isfinite(score) else None}


def _nominal(fmu: str, names: Iterable[str]) -> dict[str, float]:
    variables = {v.name: v for v in open_model_description(fmu).modelVariables}
    nominal = {}
    for name in names:
        if name not in variables:
            raise UnknownVariableError(f"{Path(fmu).name} has no parameter {name!r} to vary; "
                                       f"its parameters include {sorted(variables)[:12]}")
        start = variables[name].start
        try:
            nominal[name] = float(start)
        except (TypeError, ValueError):
            raise InvalidSettingError(f"parameter {name!r} has no numeric start value to vary around") from None
    return nominal


def robustness(fmu: str | os.PathLike, controller: Any, scenarios: Scenario | str | Iterable[Scenario | str],
               specs: Iterable[Spec | str] = TELESCOPE_SPECS, *, samples: int = 50, spread: float = 0.2,
               uncertain: Sequence[str] = DEFAULT_UNCERTAIN,
               effects: Mapping[str, tuple[float, float]] | None = None, seed: int = 0,
               scheduler: Any = None, workers: int | None = None, progress: bool | None = None,
               kind: str | None = None) -> RobustnessResult:
    """Validate `controller` on `samples` plants drawn around the nominal one; pass rate and worst case.

    Parameters
    ----------
    fmu : path-like
        The plant FMU file.
    controller : controllers.base.Controller
        Sent to the workers as JSON and rebuilt there.
    scenarios, specs
        As for :func:`cosim.loop.validation.validate`.
    samples : int
        Number of Monte Carlo samples.
    spread : float
        Relative half-width of the uniform draw of each `uncertain` parameter (0.2 = ±20 %).
    uncertain : sequence of str
        FMU parameters drawn around their start values.
    effects : mapping of name to (low, high), optional
        Effect parameters drawn uniformly in a range, e.g. ``{"Fc": (0.0, 200.0)}``.
    seed : int
        Seed of the draws (the same seed gives the same plants wherever the samples run).
    scheduler, workers
        As for :func:`cosim.study.sweep.run_sweep`.
    progress : bool or None, default None
        Progress bar on stderr, one step per sample: None shows it only when stderr is a terminal, True
        shows it anyway, False hides it.
    kind : {"cs", "me"}, optional
        The FMU's interface (see :class:`~cosim.plant.fmu_plant.FmuPlant`).

    Returns
    -------
    RobustnessResult
    """
    if not isinstance(samples, int) or samples < 1:
        raise InvalidSettingError(f"samples must be a positive whole number, got {samples!r}")
    if not (isinstance(spread, (int, float)) and 0 <= spread < 1):
        raise InvalidSettingError(f"spread is a fraction in [0, 1), got {spread!r}")
    fmu = str(Path(fmu))
    scenario_list = [s if isinstance(s, Scenario) else parse_scenario(s)
                     for s in ([scenarios] if isinstance(scenarios, (Scenario, str)) else scenarios)]
    spec_texts = [parse_spec(s).text or f"{parse_spec(s).metric}{parse_spec(s).op}{parse_spec(s).limit!r}"
                  for s in specs]
    nominal = _nominal(fmu, uncertain)
    ranges = dict(effects or {})
    _nominal(fmu, ranges)  # the effects must exist too
    for name, bounds in ranges.items():
        if len(bounds) != 2 or not bounds[0] <= bounds[1]:
            raise InvalidSettingError(f"effect range for {name!r} must be (low, high) with low <= high, got {bounds}")
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(samples):
        params = {name: value * (1.0 + rng.uniform(-spread, spread)) for name, value in nominal.items()}
        params.update({name: float(rng.uniform(lo, hi)) for name, (lo, hi) in ranges.items()})
        draws.append(params)
    payload = controller.to_dict()
    cases = [{"fmu": fmu, "controller": payload, "scenarios": [s.to_dict() for s in scenario_list],
              "specs": spec_texts, "parameters": params, **({"kind": kind} if kind else {})} for params in draws]
    sweep = run_sweep(robustness_case, cases, scheduler=scheduler, workers=workers, progress=progress,
                      desc="robustness")
    rows = []
    for params, result, error in zip(draws, sweep.results, sweep.errors, strict=True):
        row: dict[str, Any] = dict(params)
        if result is None:
            row.update(passed=False, score=math.inf, error=str(error), reasons=[str(error)])
        else:
            score = result["score"] if result["score"] is not None else math.inf
            row.update(passed=bool(result["passed"]), score=score, error="", reasons=result["reasons"])
            row.update(result["metrics"])
        rows.append(row)
    table = pd.DataFrame(rows)
    order = table.assign(_fail=~table["passed"]).sort_values(["_fail", "score"], ascending=False).index
    w = rows[int(order[0])]
    worst = {"parameters": {k: w[k] for k in draws[0]}, "passed": w["passed"], "reasons": w["reasons"],
             "score": None if not math.isfinite(w["score"]) else w["score"],
             "metrics": {k: v for k, v in w.items() if k not in draws[0] and k not in
                         ("passed", "score", "error", "reasons")}}
    table = table.drop(columns=["reasons"])
    return RobustnessResult(samples=samples, pass_rate=float(table["passed"].mean()), worst=worst, table=table,
                            sweep=sweep, nominal=nominal)
