"""Robustness: Monte Carlo validation of a controller over the plant's parameters and undeclared effects.

Each sample draws the plant's physical parameters uniformly within ``±spread`` of their nominal values (the
values the run sets, ``parameters=``, else the FMU's start values) and each effect's parameter uniformly in its
range (``effects={"Fc": (0, 200)}``), runs :func:`cosim.loop.validation.validate` on the FMU with them, and
records pass or fail with the figures. The parameters varied by default (:func:`robustness_plan`): the bundled
two-mass servo's inertias, stiffness and damping (:data:`DEFAULT_UNCERTAIN`) where the FMU has them all, else
every real parameter of the FMU (each element of an array parameter, ``A[1,2]``) whose value is not zero; a
name that is not a real parameter is refused in one line listing the FMU's parameters. The samples run through
the sweep engine (:func:`cosim.study.sweep.run_sweep`): local processes or a Dask cluster. A sample that
raises counts as a failure.

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
from ..loop.validation import Scenario, Spec, parse_scenario, parse_spec, validate
from ..loop.validation_defaults import default_checks, fmu_parameters
from ..plant._variables import array_value, element_name, expand_signals, shape_of
from ..plant.model_description import open_model_description
from .sweep import SweepResult, run_sweep

__all__ = ["DEFAULT_UNCERTAIN", "RobustnessPlan", "RobustnessResult", "robustness", "robustness_plan"]

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
    # the drawn plant wins over a scenario's own parameters (a drawn array over the scenario's elements of it); the
    # scenario keeps its name (the table's columns)
    runs = [replace(Scenario.from_dict(s), name=s["name"], parameters={
        **{k: v for k, v in s.get("parameters", {}).items() if k.partition("[")[0] not in parameters},
        **parameters}) for s in scenarios]
    verdict = validate(fmu, ctrl, runs, specs, model=None, progress=False, kind=kind)
    metrics: dict[str, Any] = {}
    for check in verdict.checks:
        prefix = f"{check['scenario']}|" if len(runs) > 1 else ""
        metrics[prefix + check["metric"]] = check["value"]
    score = max((_ratio(parse_spec(c["spec"]).op, c["value"], c["limit"]) for c in verdict.checks
                 if c["passed"] is not None), default=0.0)
    return {"passed": verdict.passed, "reasons": list(verdict.reasons), "metrics": metrics,
            "score": score if math.isfinite(score) else None}


@dataclass(frozen=True)
class RobustnessPlan:
    """What a Monte Carlo varies: ``nominal`` values of the spread parameters and ``ranges`` of the effects, by
    scalar or array-element name, and the whole arrays they belong to (``arrays``, row-major values and shape),
    so that a draw sets each array whole."""

    nominal: dict[str, float]
    ranges: dict[str, tuple[float, float]]
    arrays: dict[str, tuple[list[float], tuple[int, ...]]]

    def fmu_values(self, draw: Mapping[str, float]) -> dict[str, Any]:
        """A draw (by scalar or element name) as the FMU's parameters: scalars, and each touched array whole."""
        out: dict[str, Any] = {}
        for name, value in draw.items():
            base = name.partition("[")[0]
            if base in self.arrays and "[" in name:
                flat, shape = self.arrays[base]
                current = out.get(base)
                values = list(flat) if current is None else current
                index = tuple(int(i) - 1 for i in name[len(base) + 1:-1].split(","))
                values[int(np.ravel_multi_index(index, shape))] = float(value)
                out[base] = values
            else:
                out[name] = float(value)
        for base, values in list(out.items()):
            if base in self.arrays and isinstance(values, list):
                out[base] = np.reshape(values, self.arrays[base][1]).tolist()
        return out


def _real_values(fmu: str, given: Mapping[str, Any], kind: str | None) -> tuple[dict[str, float], dict[str, Any],
                                                                             list[str]]:
    """Every real parameter's value by scalar or element name (the `given` one, else the start value), the
    array parameters' flat values and shapes, and the FMU's parameter names (all types)."""
    md = open_model_description(fmu, kind)
    names = fmu_parameters(md)
    variables = {v.name: v for v in md.modelVariables}
    starts = {v.name: v.start for v in md.modelVariables}
    values: dict[str, float] = {}
    arrays: dict[str, tuple[list[float], tuple[int, ...]]] = {}
    for name in names:
        var = variables[name]
        if var.type not in ("Real", "Float64", "Float32"):
            continue
        if getattr(var, "dimensions", None):
            shape = shape_of(var, {**starts, **given})
            size = int(np.prod(shape))
            if name in given:
                flat = [float(v) for v in array_value(expand_signals([var, *[d.variable for d in var.dimensions
                                                                              if d.variable is not None]])[name],
                                                      given[name])]
            else:
                text = str(var.start or "").split()
                flat = [float(v) for v in text] if len(text) == size else [0.0] * size
            for offset, index in enumerate(np.ndindex(*shape)):
                element = element_name(name, index)
                flat[offset] = float(given.get(element, flat[offset]))
                values[element] = flat[offset]
            arrays[name] = (flat, tuple(shape))
        else:
            try:
                values[name] = float(given.get(name, var.start))
            except (TypeError, ValueError):
                continue
    return values, arrays, names


def robustness_plan(fmu: str | os.PathLike, *, spread: float = 0.2, uncertain: Sequence[str] | None = None,
                    effects: Mapping[str, tuple[float, float]] | None = None,
                    parameters: Mapping[str, Any] | None = None, kind: str | None = None) -> RobustnessPlan:
    """The parameters a Monte Carlo spreads and their nominal values, the effects' ranges; bad names refused.

    Parameters
    ----------
    fmu : path-like
    spread : float
        Relative half-width of the draws, in [0, 1).
    uncertain : sequence of str, optional
        Real parameters to spread (an array's name stands for its elements); default :data:`DEFAULT_UNCERTAIN`
        where the FMU has them all, else every real parameter (array elements too) whose value is not zero.
    effects : mapping of name to (low, high), optional
    parameters : mapping, optional
        Values the runs set (``--set``): the nominal values of the spread parameters where given.
    kind : {"cs", "me"}, optional

    Returns
    -------
    RobustnessPlan

    Examples
    --------
    >>> from cosim import build_fmu
    >>> plan = robustness_plan(build_fmu(), parameters={"Jm": 300.0})
    >>> plan.nominal
    {'Jm': 300.0, 'JL': 1000.0, 'KL': 2500000.0, 'Bm': 50.0, 'BL': 500.0}
    """
    if not (isinstance(spread, (int, float)) and 0 <= spread < 1):
        raise InvalidSettingError(f"spread is a fraction in [0, 1), got {spread!r}")
    fmu = str(Path(fmu))
    label = Path(fmu).name
    values, arrays, names = _real_values(fmu, dict(parameters or {}), kind)
    real = [n for n in names if n in values or n in arrays]

    def pick(name: str, role: str) -> list[str]:
        if name in values:
            return [name]
        if name in arrays:
            return [e for e in values if e.partition("[")[0] == name]
        import difflib

        near = difflib.get_close_matches(name, real, n=1)
        listed = ", ".join(real[:40]) + (" ..." if len(real) > 40 else "") if real else "none"
        hint = f"; did you mean {near[0]}?" if near else ""
        raise UnknownVariableError(f"{label} has no real parameter {name!r} to {role}{hint} (its real parameters: "
                                   f"{listed})")

    if uncertain is None:
        chosen = (list(DEFAULT_UNCERTAIN) if all(n in values for n in DEFAULT_UNCERTAIN)
                  else [n for n, v in values.items() if v != 0.0 and math.isfinite(v)])
        if not chosen and not real:
            raise InvalidSettingError(f"{label} declares no real parameter, so a Monte Carlo has nothing to vary (an "
                                      "exported model keeps its coefficients as constants); validate without "
                                      "--robustness, or on an FMU with parameters")
        if not chosen:
            raise InvalidSettingError(f"{label} has no real parameter with a non-zero value to spread around (its "
                                      f"real parameters: {', '.join(real[:40])}); name them with --vary NAME,... "
                                      "and give their values with --set")
    else:
        chosen = [e for name in uncertain for e in pick(str(name), "vary")]
    ranges: dict[str, tuple[float, float]] = {}
    for name, bounds in dict(effects or {}).items():
        for element in pick(str(name), "vary as an effect"):
            if len(bounds) != 2 or not bounds[0] <= bounds[1]:
                raise InvalidSettingError(f"effect range for {name!r} must be (low, high) with low <= high, "
                                          f"got {bounds}")
            ranges[element] = (float(bounds[0]), float(bounds[1]))
    nominal = {name: values[name] for name in chosen if name not in ranges}
    return RobustnessPlan(nominal=nominal, ranges=ranges, arrays=arrays)


def robustness(fmu: str | os.PathLike, controller: Any,
               scenarios: Scenario | str | Iterable[Scenario | str] | None = None,
               specs: Iterable[Spec | str] | None = None, *, samples: int = 50, spread: float = 0.2,
               uncertain: Sequence[str] | None = None, effects: Mapping[str, tuple[float, float]] | None = None,
               parameters: Mapping[str, Any] | None = None, seed: int = 0, scheduler: Any = None,
               workers: int | None = None, progress: bool | None = None, kind: str | None = None) -> RobustnessResult:
    """Validate `controller` on `samples` plants drawn around the nominal one; pass rate and worst case.

    Parameters
    ----------
    fmu : path-like
        The plant FMU file.
    controller : controllers.base.Controller
        Sent to the workers as JSON and rebuilt there.
    scenarios, specs
        As for :func:`cosim.loop.validation.validate` (default: the plant's and design's).
    samples : int
        Number of Monte Carlo samples.
    spread : float
        Relative half-width of the uniform draw of each `uncertain` parameter (0.2 = ±20 %).
    uncertain : sequence of str, optional
        FMU parameters drawn around their nominal values (an array's name: its elements); default: see
        :func:`robustness_plan`.
    effects : mapping of name to (low, high), optional
        Effect parameters drawn uniformly in a range, e.g. ``{"Fc": (0.0, 200.0)}``.
    parameters : mapping, optional
        FMU parameters every run sets (``--set``; a scenario's own still apply): the nominal values of the
        spread parameters where given.
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
    plan = robustness_plan(fmu, spread=spread, uncertain=uncertain, effects=effects, parameters=parameters,
                           kind=kind)
    fmu = str(Path(fmu))
    if scenarios is None or specs is None:
        defaults = default_checks(fmu, controller, kind=kind)
        scenarios = defaults.scenario if scenarios is None else scenarios
        specs = defaults.specs if specs is None else specs
    scenario_list = [s if isinstance(s, Scenario) else parse_scenario(s)
                     for s in ([scenarios] if isinstance(scenarios, (Scenario, str)) else scenarios)]
    if parameters:
        scenario_list = [s.with_effects(**{k: v for k, v in parameters.items() if k not in s.parameters})
                         for s in scenario_list]
    spec_texts = [parse_spec(s).text or f"{parse_spec(s).metric}{parse_spec(s).op}{parse_spec(s).limit!r}"
                  for s in specs]
    nominal, ranges = plan.nominal, plan.ranges
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(samples):
        params = {name: value * (1.0 + rng.uniform(-spread, spread)) for name, value in nominal.items()}
        params.update({name: float(rng.uniform(lo, hi)) for name, (lo, hi) in ranges.items()})
        draws.append(params)
    payload = controller.to_dict()
    cases = [{"fmu": fmu, "controller": payload, "scenarios": [s.to_dict() for s in scenario_list],
              "specs": spec_texts, "parameters": plan.fmu_values(params), **({"kind": kind} if kind else {})}
             for params in draws]
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
