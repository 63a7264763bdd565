"""Candidate effects: one effect at one place, with its evidence and its physical parameters.

* :class:`EffectCandidate` - one catalogued effect at one place with one nuisance value, as the screening
  scores it and the trial fits judge it: change of BIC, p-value, size, physical parameters with their
  standard errors;
* ``_uncertainty`` - those standard errors, by the delta method from the covariance of the effect's
  coefficients.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InvalidSettingError
from .effects import EFFECTS, Attachment, Effect, Roles, effect_names

__all__ = ["EffectCandidate"]


@dataclass(frozen=True)
class EffectCandidate:
    """One effect at one place with one nuisance value, as scored on the output error (free run) and judged by
    its trial fit.

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
    explained : dict
        What it explains: ``size``, the share of the data's spread its fit removes (from the score test while
        screening; from the trial fit afterwards, which adds ``plausible``, whether its parameters are
        physically possible, and ``correlation_factor``, by which a coloured residual thins the samples).
    significant : bool
    parameters : dict of str to float
        Physical parameters from the coefficients (see :mod:`cosim.diagnose.effects`).
    uncertainty : dict of str to float
        Standard errors of the parameters where known.
    meaning : str
        The effect's physical meaning.
    coefficients : tuple of float
        The effect's coefficients in its rows' equations, row by row (the score test's estimate).
    nuisance_se : float or None
        Standard error of the nuisance parameter when the trial fit estimated it.
    fixed : bool
        The nuisance value was given in the effect selection (``"deadzone:width=0.2"``): tried at that value
        only, never refitted.
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
    fixed: bool = False

    @property
    def placement(self) -> Attachment:
        """Where the candidate acts, as its effect's :class:`~cosim.diagnose.effects.Attachment`."""
        signals = tuple(self.attached_to.split("-")) if self.attached_to != "constant" else ()
        return Attachment(self.attached_to, signals, self.rows)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "attached_to": self.attached_to, "rows": list(self.rows),
                "nuisance": self.nuisance, "terms": list(self.terms), "delta_bic": self.delta_bic,
                "p_value": self.p_value, "explained": dict(self.explained), "significant": self.significant,
                "parameters": dict(self.parameters), "uncertainty": dict(self.uncertainty), "meaning": self.meaning}


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


@contextmanager
def registered(candidates: Sequence[Effect], effects: Any) -> Iterator[Any]:
    """The effects a user brings (`candidates`, :func:`~cosim.diagnose.user_candidates.candidate`) in the catalogue
    for the duration of one diagnosis (the search looks effects up by name), in its own thread or task only, and
    the selection `effects` with their names added."""
    for c in candidates:  # an Effect of its own name (given twice, or already registered, is the same one)
        if not isinstance(c, Effect) or EFFECTS.get(c.name, c) is not c:
            raise InvalidSettingError(f"candidate {getattr(c, 'name', c)!r} is not an Effect with a new name; "
                                      "build it with cosim.diagnose.candidate(...)")
    extra = {c.name: c for c in candidates if c.name not in EFFECTS}
    if extra:
        effects = [*effect_names(effects), *extra]
    with EFFECTS.brought(extra):  # (this diagnosis' thread or task only)
        yield effects
