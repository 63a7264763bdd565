"""Removing a delay from a model takes its taps out of the model's inputs (_trials._remove_effect)."""
from __future__ import annotations

import numpy as np

from cosim.diagnose._trials import _FitOptions, _remove_effect
from cosim.diagnose.candidates import EffectCandidate
from cosim.diagnose.effects import EFFECTS, delayed_name
from cosim.identify.model import IdentifiedModel


def test_a_removed_delay_takes_its_taps_out_of_the_inputs():
    """x' = -x + u(t - 3 dt) fitted with the delay's two taps as inputs; removed, the model keeps u alone (its
    taps left behind were named twice when a later trial added them again: record 64 of the generalisation
    benchmark)."""
    rng = np.random.default_rng(0)
    dt, n = 0.01, 2000
    u = np.repeat(rng.standard_normal(n // 20), 20)
    d = 3
    lagged = np.concatenate([np.full(d, u[0]), u[:-d]])
    x = np.zeros(n)
    for k in range(n - 1):  # (Euler at a fine enough step for the test: the fit only has to run)
        x[k + 1] = x[k] + dt * (-x[k] + lagged[k])
    columns = {"x": x, "u": u}
    cand = EffectCandidate("delay", "u", ("x",), float(d), (delayed_name("u", d), delayed_name("u", d + 1)),
                           -100.0, 0.0, {}, True)
    columns.update(EFFECTS["delay"].columns(cand.placement, cand.nuisance, columns))
    model = IdentifiedModel(states=("x",), inputs=("u", *cand.terms), terms=("x", "u", *cand.terms),
                            coef=np.array([[-1.0, 0.01, 0.99, 0.0]]), dt=dt, meta={"x0": [[0.0]]})
    removed = _remove_effect(model, cand, None, [], columns, dt, _FitOptions(estimate_x0=True, noise=None))
    assert removed is not None
    reduced = removed[0]
    assert reduced.inputs == ("u",) and reduced.terms == ("x", "u")
    assert reduced.coef[0, 1] > 0.5  # the input's own gain took the taps' weight
