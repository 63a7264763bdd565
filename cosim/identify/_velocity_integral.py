"""An equation-error start that takes positions from their velocities (``refine="output_error"``, pinned
kinematics).

Equation error regresses each velocity's derivative on the library evaluated on the measured states. With
noisy positions that is biased towards zero for every direction whose signal is below its noise: the twist of
a stiff shaft (record of ``benchmarks/bench_diagnosis.py``: twist RMS 0.0018 rad under 0.04 rad of position
noise) carries the whole torsional mode, and both the plain and the noise-compensated fits lose it (the
compensation divides by the little that is left and diverges). Output error started there finds a model
that locks the two masses with a damper instead of a spring.

With a kinematic row ``p' = v`` pinned, the position need not be read from its sensor: over a block of the
record starting at ``t0``, ``p(t) = p(t0) + integral of v``. Integrating a dynamic row over the block,

    x_i(t) - x_i(t0) = sum_j a_ij * integral of term_j,

a position term becomes ``p(t0) (t - t0)`` plus the double integral of its velocity, so after removing from
every column its straight line over the block (the unknown ``x_i(t0)`` and ``p(t0)`` terms, and the
constant's ``t - t0``) only integrals of measured velocities and inputs remain as regressors: their noise is a
random walk far below the signal, and the target's own noise is white and unbiased. Blocks are short, so that
what the linear library lacks (friction) does not accumulate. The coefficients come from least squares on all
blocks; each row's constant from the record's mean slope. This is the integral (or "modulating function")
approach of continuous-time identification (Garnier & Young's CONTSID toolbox builds on it), specialised to
what the pinned kinematics give for free; written here because no maintained Python library fits continuous
models with pinned kinematic rows this way (pysindy's weak form integrates the measured library terms,
positions included).

:func:`velocity_integral_start` fits one block length; the refinement
(:func:`cosim.identify._refinement._velocity_start`) tries each of :data:`BLOCK_SAMPLES` and keeps the fit
whose free run follows the data best. On the record above the best block is 96 samples and the start holds
the torsional mode (73.8 rad/s after output error, the plant's 75.4) that the other starts lose; there the
model that locks the masses still wins the multi-start (output-error cost 0.119 against 0.133: the linear
library lacks the friction either way).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .model import IdentifiedModel

#: Block lengths tried, in samples (longer blocks let what the linear library lacks accumulate, shorter ones
#: leave the springs little curvature to show).
BLOCK_SAMPLES = (24, 48, 96, 192, 384)


def _cumulative(v: np.ndarray, dt: float, held: bool) -> np.ndarray:
    """Running integral from the block's first sample: exact for a held input, trapezoids otherwise."""
    steps = dt * v[:-1] if held else 0.5 * dt * (v[1:] + v[:-1])
    return np.concatenate([np.zeros((1,) + v.shape[1:]), np.cumsum(steps, axis=0)])


def _block_columns(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, dt: float, kin: Mapping[str, str],
                   free: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """One block's regressors (samples x terms, the constant's column zero) and targets (samples x free rows),
    each less its straight line over the block."""
    theta = model.features(x, u)
    cols = np.empty_like(theta)
    for j, term in enumerate(model.terms):
        if term == "1":
            cols[:, j] = 0.0
        elif term in kin:
            velocity = x[:, model.states.index(kin[term])]
            cols[:, j] = _cumulative(_cumulative(velocity, dt, False), dt, False)
        else:
            cols[:, j] = _cumulative(theta[:, j], dt, term in model.inputs)
    target = x[:, free] - x[0, free]
    line = np.column_stack([np.ones(len(x)), np.arange(len(x), dtype=float)])
    q, _ = np.linalg.qr(line)
    return cols - q @ (q.T @ cols), target - q @ (q.T @ target)


def velocity_integral_start(model: IdentifiedModel, runs: Sequence[tuple[np.ndarray, np.ndarray]], dt: float,
                            kin: Mapping[str, str], block: int) -> IdentifiedModel | None:
    """The model's free rows fitted on integrals of the measured velocities and inputs over blocks of `block`
    samples (module docstring); None without pinned kinematics, or with records shorter than three blocks.

    `runs` are the records as (states, inputs) arrays of equal length (inputs held over each step), `kin` maps
    each pinned position to its velocity; the kinematic rows of `model` are kept.
    """
    if not kin or sum(len(x) // block for x, _ in runs) < 3:
        return None
    free = [i for i, s in enumerate(model.states) if s not in kin]
    blocks = [_block_columns(model, x[s:s + block], u[s:s + block], dt, kin, free)
              for x, u in runs for s in range(0, len(x) - block + 1, block)]
    a = np.vstack([b[0] for b in blocks])
    y = np.vstack([b[1] for b in blocks])
    coef = model.coef.copy()
    k_const = model.terms.index("1") if "1" in model.terms else None
    mean_terms = np.mean(np.vstack([model.features(x, u) for x, u in runs]), axis=0) if k_const is not None else None
    for r, i in enumerate(free):
        support = [j for j in range(len(model.terms)) if model.coef[i, j] != 0.0 and j != k_const]
        if not support:
            continue
        scale = np.sqrt(np.mean(a[:, support] ** 2, axis=0))
        if not np.all(scale > 0):
            return None
        sol = np.linalg.lstsq(a[:, support] / scale, y[:, r], rcond=None)[0] / scale
        coef[i, support] = sol
        if k_const is not None and model.coef[i, k_const] != 0.0:
            # the constant from the mean slope of the row's state over every record
            slope = sum(x[-1, i] - x[0, i] for x, _ in runs) / (dt * sum(len(x) - 1 for x, _ in runs))
            coef[i, k_const] = slope - float(mean_terms[support] @ sol)
    if not np.all(np.isfinite(coef)):
        return None
    return IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=coef, dt=model.dt)
