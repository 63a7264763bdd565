"""A placed effect's nuisance parameter in the output-error fit (:func:`~cosim.diagnose.screening.output_error_fit`):
its value, its sensitivity columns, a coefficient tied to another, and a Gauss-Newton step applied to all.

Kept apart from :mod:`~cosim.diagnose.screening` (which re-exports :class:`Nuisance`) to keep that module short;
the functions take the fit's :class:`~cosim.diagnose.screening.OutputErrorScreen` and use its free run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..identify.model import IdentifiedModel

if TYPE_CHECKING:
    from .screening import OutputErrorScreen


@dataclass
class Nuisance:
    """A placed effect's nuisance parameter that the output-error fit estimates with the coefficients.

    `make_terms(value)` writes the effect's terms for a value; the model holds ``make_terms(value)``.
    """

    make_terms: Callable[[float], tuple[str, ...]]
    value: float
    std_error: float | None = None  # set by the fit (first order, from the log-scale sensitivity)
    #: ``(term, factor)``: in every row, the coefficient of this nuisance's (first) term is `factor` times that
    #: row's coefficient of `term`, so it adds no free coefficient. An input's saturation or dead zone as the
    #: plant sees it: ``b * clip(u) = b * u - b * (u - clip(u))``, the input's own gain, tied (factor -1).
    tied_to: tuple[str, float] | None = None
    #: The range the fit keeps the value in: what the record can show of it (the effect's span at its
    #: attachment). A smoothing velocity's cost falls on towards zero (a sharper switch always fits a little
    #: better): unbounded, where the fit stopped depended on the path, and the path on the last bits of the data.
    bounds: tuple[float, float] = (0.0, math.inf)

    def at_bound(self, direction: float) -> bool:
        """Whether the value sits at the bound a step in `direction` (its sign) would cross."""
        lo, hi = self.bounds
        return (direction < 0.0 and self.value <= lo * (1.0 + 1e-12)) or \
            (direction > 0.0 and self.value >= hi * (1.0 - 1e-12))

    @property
    def terms(self) -> tuple[str, ...]:
        return self.make_terms(self.value)


def _tie_map(screen: OutputErrorScreen, model: IdentifiedModel, nuis: Sequence[Nuisance], width: int) -> np.ndarray:
    """The map from the free parameters to all `width` columns of the fit's Jacobian: the identity, but for a
    tied nuisance term (:attr:`Nuisance.tied_to`), whose coefficient in a row follows that row's free term."""
    ties = np.eye(width)
    index = {(i, term): c for c, (i, term) in enumerate(screen.base_columns)}
    dropped = []
    for nu in nuis:
        if nu.tied_to is None:
            continue
        term, factor = nu.tied_to
        for i in range(len(model.states)):
            tied, free = index.get((i, nu.terms[0])), index.get((i, term))
            if tied is not None and free is not None:
                ties[tied, free] = factor
                dropped.append(tied)
    return np.delete(ties, dropped, axis=1) if dropped else ties


#: A nuisance's terms carry a force when it is above this share of their row's RMS force (see
#: :func:`_nuisance_columns`).
LIVE_FORCE = 1e-9


def _nuisance_columns(screen: OutputErrorScreen, model: IdentifiedModel, nuis: Sequence[Nuisance]) -> list:
    """Sensitivity of the free run to log(value) of each nuisance parameter (one integration for all).

    A nuisance whose terms carry no force yet (an effect started from zero coefficients: its force is below
    :data:`LIVE_FORCE` of its row's) has no sensitivity: its column is zero, so the step leaves it where it is
    until the coefficients have grown. Its finite-difference column would be round-off, and a least-squares
    step on it arbitrarily large."""
    if not nuis:
        return []
    h = 0.02
    n = len(model.states)
    forcing = np.zeros((len(screen.x_sim) - 1, n, len(nuis)))
    row_rms = None
    for j, nu in enumerate(nuis):
        present = nu.terms
        up, down = nu.make_terms(nu.value * math.exp(h)), nu.make_terms(nu.value * math.exp(-h))
        f_up, f_down = screen._term_values(up), screen._term_values(down)
        own = np.zeros((len(f_up), n))
        for t_i, term in enumerate(present):
            if term not in model.terms:
                continue
            k = model.terms.index(term)
            for i in range(n):
                if model.coef[i, k] != 0.0:
                    forcing[:, i, j] += model.coef[i, k] * (f_up[:, t_i] - f_down[:, t_i]) / (2 * h)
                    own[:, i] += model.coef[i, k] * (f_up[:, t_i] + f_down[:, t_i]) / 2
        if row_rms is None:
            row_rms = np.sqrt(np.mean((screen._term_values(model.terms) @ model.coef.T) ** 2, axis=0))
        live = np.sqrt(np.mean(own ** 2, axis=0)) > LIVE_FORCE * row_rms
        if not np.any(live & (row_rms > 0)):
            forcing[:, :, j] = 0.0
    sens = screen._flatten_owned(screen._integrate(forcing))
    return [sens[:, j] for j in range(len(nuis))]


def _apply(model: IdentifiedModel, screen: OutputErrorScreen, step: np.ndarray,
           nuis: Sequence[Nuisance]) -> tuple[IdentifiedModel, np.ndarray, list[Nuisance]]:
    coef = model.coef.copy()
    nb = len(screen.base_columns)
    for c, (i, term) in enumerate(screen.base_columns):
        coef[i, model.terms.index(term)] += step[c]
    n = screen.x0.size if screen.estimate_x0 else 0
    start = screen.x0 + step[nb:nb + n].reshape(screen.x0.shape) if n else screen.x0
    terms = list(model.terms)
    new_nuis = []
    for j, nu in enumerate(nuis):
        lo, hi = nu.bounds
        value = min(max(nu.value * math.exp(float(np.clip(step[nb + n + j], -1.0, 1.0))), lo), hi)
        for old, new in zip(nu.terms, nu.make_terms(value), strict=True):
            if old in terms:
                terms[terms.index(old)] = new
        new_nuis.append(replace(nu, value=value, std_error=None))
    return IdentifiedModel(states=model.states, inputs=model.inputs, terms=tuple(terms), coef=coef,
                           dt=model.dt), start, new_nuis
