"""SINDYc's default threshold on cubic libraries, on the independent simulator of
benchmarks/bench_sindy_threshold.py (its own equations; scipy's solve_ivp, or a forward-Euler loop as a
fixed-step co-simulation FMU records).

Samples of a continuous flow, noise-free or with up to 2 % of noise: the threshold of least BIC keeps the true
terms and no other. Forward-Euler samples: the equation error is formed by the left rectangle (the data choose
it, ``meta["equation_error"]["sampler"]``), so noise-free records give the exact structure and coefficients,
where the trapezoid's O(dt) inconsistency made BIC keep 8-16 spurious terms per system. With output-error
refinement (``cosim identify``'s default) a noise-free record is decided by equation error, and keeps its
structure through the refinement (before: 2-12 spurious terms, the dense start refined and never pruned).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # benchmarks/ is not a package
import bench_sindy_threshold as bench  # noqa: E402

from cosim.identify.sindyc import SINDYc  # noqa: E402

SYSTEMS = {s.name: s for s in bench.systems()}


def fit(system, sampler, noise, **kw):
    # the equation-error path (refinement off unless asked): what these tests judge is its threshold rule
    est = SINDYc(library="polynomial", degree=3, allow_unstable=True, **{"refine": None, **kw})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return est.fit(bench.record(system, sampler, noise), states=list(system.states),
                       inputs=list(system.inputs)).model_


@pytest.mark.parametrize("name", list(SYSTEMS))
@pytest.mark.parametrize("noise", [0.0, 0.01, 0.02])
def test_continuous_flow_gives_the_true_terms(name, noise):
    system = SYSTEMS[name]
    model = fit(system, "solve_ivp", noise)
    result = bench.score(system, model, "solve_ivp")
    assert not result["spurious"] and not result["missed"], result
    assert result["coef_error_pct"] < 2.0, result
    assert model.meta["equation_error"]["sampler"]["chosen"] == "trapezoid"


@pytest.mark.parametrize("name", list(SYSTEMS))
def test_forward_euler_samples_give_the_exact_equations(name):
    system = SYSTEMS[name]
    model = fit(system, "euler", 0.0)
    result = bench.score(system, model, "euler")
    assert not result["spurious"] and not result["missed"], result
    sampler = model.meta["equation_error"]["sampler"]["chosen"]
    if system.inputs or name == "msd c=0.4":  # linear: Euler's O(dt) error is linear too, the trapezoid fits it
        assert sampler in ("trapezoid", "forward_euler")
    else:
        assert sampler == "forward_euler"
        assert result["coef_error_pct"] < 1e-6, result


def test_the_threshold_rule_alone_is_unchanged_on_continuous_data():
    """The trapezoid's features and BIC's candidates are the same as without the sampler choice."""
    from cosim.identify._equation_error import _equations as trapezoid
    from cosim.identify._sampler import _equations
    from cosim.identify.terms import Term

    system = SYSTEMS["duffing"]
    x, u = bench.simulate(system, system.x0, "solve_ivp")
    parsed = [Term(t) for t in ("1", "x", "v", "x**3", "x**2*v")]
    args = ([(x, u)], parsed, list(system.states), [], system.dt, {"x": "v"})
    kw = {"method": "integral", "options": {}, "noise_compensation": True}
    ours, theirs = _equations(*args, **kw), trapezoid(*args, **kw)
    assert np.array_equal(ours[0], theirs[0]) and np.array_equal(ours[1], theirs[1])


@pytest.mark.parametrize("name, sampler", [("duffing", "solve_ivp"), ("msd c=0.1", "solve_ivp"),
                                           ("lotka", "euler"), ("vdp mu=5", "euler")])
def test_refined_noise_free_records_keep_the_structure(name, sampler):
    system = SYSTEMS[name]
    model = fit(system, sampler, 0.0, refine="output_error")
    result = bench.score(system, model, sampler)
    assert not result["spurious"] and not result["missed"], result
    assert model.meta["threshold"]["equation_error"]["decided_by_equation_error"] is True


def test_refined_noisy_records_start_from_the_dense_fit():
    """With noise the equation error cannot judge small terms: the refinement starts dense, as before."""
    system = SYSTEMS["msd c=0.1"]
    model = fit(system, "solve_ivp", 0.01, refine="output_error")
    ee = model.meta["threshold"]["equation_error"]
    assert ee["decided_by_equation_error"] is False and ee["value"] == 0.0
    result = bench.score(system, model, "solve_ivp")
    assert not result["spurious"] and not result["missed"], result
