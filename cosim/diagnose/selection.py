"""Effects chosen together: a joint sparse selection on the output error, and how stable it is under resampling.

Every catalogued effect at every place it can attach (its best nuisance value and rows by its own score, see
:func:`library`) enters one linear problem: the model's free-run residual regressed on the sensitivities of its
own coefficients and initial state (always in) and of every candidate's coefficients (the Gauss-Newton
linearisation of the output error, :class:`~cosim.diagnose.screening.OutputErrorScreen`). A forward group
selection by BIC picks the candidates **together**: each is judged with those already in and the base
re-estimated, so an effect that only repeats another explains nothing (:func:`forward_select`).

**Stability selection** (Meinshausen & Buehlmann 2010; complementary pairs, Shah & Samworth 2013): the same
selection on many half-samples of the record (half of its time blocks, each pair of halves complementary) gives
each candidate a selection probability. A candidate chosen on fewer than :data:`PI_CLAIM` of them is not
claimed, whatever it scores on the whole record: with ``q`` candidates chosen per half-sample among ``p``, the
expected number of false claims is at most ``q**2 / ((2 PI_CLAIM - 1) p)`` (stated in the report).

**One answer on every machine.** Every choice between numbers compares them with a tolerance far above
rounding (:data:`TIE`, relative) and breaks ties by the catalogue's order, and the half-samples are drawn from a
fixed seed: a matrix product that ends in other last bits under another BLAS kernel cannot change a choice.

**Readings the data cannot tell apart.** A claimed candidate and another effect's candidate whose swap changes
BIC by less than :data:`EVIDENCE_MARGIN` are reported together (:func:`equivalents`), in the catalogue's order,
and neither is preferred for its last digits.

Examples
--------
>>> import numpy as np
>>> G = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.9], [0.0, 0.9, 1.0]])   # base, then two candidates
>>> g = np.array([0.0, 3.0, 2.7])
>>> forward_select(G, g, 20.0, 1000, base=[0], groups=[[1], [2]])
[0]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ._record_band import RecordBand
from .effects import EFFECTS, Attachment, Effect, EffectSelection
from .screening import OutputErrorScreen, effect_specs

__all__ = ["EVIDENCE_MARGIN", "PI_CLAIM", "Option", "Stability", "equivalents", "forward_select", "library",
           "stability"]

#: Relative tolerance of every comparison between two scores (far above a BLAS kernel's rounding, 1e-13).
TIE = 1e-7
#: BIC units within which two readings are equivalent on the data (Kass & Raftery's "very strong" is above 10).
EVIDENCE_MARGIN = 10.0
#: The least selection probability over the half-samples of a claimed effect.
PI_CLAIM = 0.6
#: Complementary pairs of half-samples.
PAIRS = 16
#: Time blocks a record is cut into for the half-samples.
BLOCKS = 16
#: Ridge on the normalised Gram's diagonal: keeps near-collinear columns solvable, far below any decision.
_RIDGE = 1e-10


@dataclass(frozen=True)
class Option:
    """One candidate of the joint selection: an effect at a place, with its nuisance value and rows."""

    effect: Effect
    attachment: Attachment
    value: float | None
    rows: tuple[str, ...]
    terms: tuple[str, ...]
    delta_bic: float  # its own score against the base alone
    coefficients: tuple[float, ...]

    @property
    def key(self) -> tuple[str, str]:
        return (self.effect.name, self.attachment.label)


def _better(a: float, b: float) -> bool:
    """`a` lower than `b` by more than the tolerance (ties are not better)."""
    return a < b - TIE * max(abs(a), abs(b), 1.0)


def library(screen: OutputErrorScreen, selection: EffectSelection, band: RecordBand,
            taken: Sequence[tuple[str, str]] = ()) -> list[Option]:
    """Every selected effect at every place it attaches (but those `taken`), each with the nuisance value and rows
    its own score prefers (ties: the first in the grid's order, then fewer rows), in the catalogue's order."""
    data = screen.free_run
    places: list[tuple[Effect, Attachment, float | None, tuple[str, ...], tuple[str, ...]]] = []
    for name in selection.names:
        effect = EFFECTS[name]
        fixed = selection.fixed.get(name)
        for attachment in effect.attachments(screen.roles):
            if (name, attachment.label) in taken:
                continue
            if name == "offset" and "1" in screen.model.terms:
                rows = [r for r in attachment.rows if screen.model.coef[screen.model.states.index(r),
                                                                          screen.model.terms.index("1")] == 0.0]
                attachment = Attachment(attachment.label, attachment.signals, tuple(rows))
            if fixed is not None:
                values = [fixed] if effect.admits(fixed, attachment, data, band) else []
            else:
                values = effect.grid(attachment, data, band)
            for value in values:
                for terms, rows in effect_specs(effect, attachment, value, screen):
                    places.append((effect, attachment, value, terms, rows))
    scores = screen.test_specs([(terms, rows) for _, _, _, terms, rows in places])
    best: dict[tuple[str, str], Option] = {}
    for (effect, attachment, value, terms, rows), score in zip(places, scores, strict=True):
        if score["coef"] is None:
            continue
        option = Option(effect, attachment, value, rows, terms, float(score["delta_bic"]),
                        tuple(float(c) for c in score["coef"]))
        key = option.key
        if key not in best or _better(option.delta_bic, best[key].delta_bic):
            best[key] = option
    return list(best.values())


class Gram:
    """The normalised Gram matrix of [base | candidates] and its cross product with the residual, per time block
    (sums of blocks are the half-samples')."""

    def __init__(self, screen: OutputErrorScreen, options: Sequence[Option]) -> None:
        sens = screen.candidate_sensitivities([(o.terms, o.rows) for o in options])
        self.groups: list[list[int]] = []
        first = screen.base.shape[1]
        for s in sens:
            self.groups.append(list(range(first, first + s.shape[1])))
            first += s.shape[1]
        a = np.column_stack([screen.base, *sens])
        norms = np.linalg.norm(a, axis=0)
        norms[~(norms > 0)] = 1.0
        a = a / norms
        self.a = a
        y = screen.residual
        self.base = list(range(screen.base.shape[1]))
        n_states = len(screen.model.states)
        samples = y.size // n_states
        edges = np.linspace(0, samples, BLOCKS + 1).round().astype(int) * n_states
        self.blocks = [(a[lo:hi].T @ a[lo:hi], a[lo:hi].T @ y[lo:hi], float(y[lo:hi] @ y[lo:hi]))
                       for lo, hi in zip(edges[:-1], edges[1:], strict=True)]
        self.n_obs = screen.n_obs
        self.whole = self.of(range(BLOCKS))

    def fitted(self, cols: Sequence[int]) -> np.ndarray:
        """The whole record's least-squares fit of the residual on columns `cols`."""
        G, g, _ = self.whole
        sub = G[np.ix_(cols, cols)]
        sub = sub + _RIDGE * np.diag(np.diag(sub) + 1e-300)
        return self.a[:, cols] @ np.linalg.solve(sub, g[cols])

    def of(self, blocks: Sequence[int]) -> tuple[np.ndarray, np.ndarray, float]:
        """The Gram, cross product and residual sum of squares of the given blocks."""
        G = sum(self.blocks[b][0] for b in blocks)
        g = sum(self.blocks[b][1] for b in blocks)
        return G, g, sum(self.blocks[b][2] for b in blocks)


def _rss(G: np.ndarray, g: np.ndarray, yy: float, cols: Sequence[int]) -> float:
    """The residual sum of squares of the least-squares fit on columns `cols`."""
    if not cols:
        return yy
    sub = G[np.ix_(cols, cols)]
    sub = sub + _RIDGE * np.diag(np.diag(sub) + 1e-300)
    try:
        c = np.linalg.cholesky(sub)
    except np.linalg.LinAlgError:
        return yy
    z = np.linalg.solve(c, g[cols])
    return max(yy - float(z @ z), 1e-300 * max(yy, 1.0))


def forward_select(G: np.ndarray, g: np.ndarray, yy: float, n_eff: float, *, base: Sequence[int],
                   groups: Sequence[Sequence[int]], max_groups: int = 3) -> list[int]:
    """Forward group selection by BIC: the groups (indices into `groups`) that enter, in order.

    Each step adds the group that lowers BIC most with the base and the groups already in re-estimated, while
    that lowers it at all (by more than the tolerance); ties go to the earlier group.
    """
    chosen: list[int] = []
    cols = list(base)
    rss = _rss(G, g, yy, cols)
    log_n = math.log(max(n_eff, 2.0))
    while len(chosen) < max_groups:
        best, best_bic = None, 0.0
        for k, group in enumerate(groups):
            if k in chosen:
                continue
            rss_k = _rss(G, g, yy, cols + list(group))
            bic = n_eff * math.log(rss_k / rss) + len(group) * log_n
            if _better(bic, best_bic):
                best, best_bic = k, bic
        if best is None:
            break
        chosen.append(best)
        cols += list(groups[best])
        rss = _rss(G, g, yy, cols)
    return chosen


@dataclass(frozen=True)
class Stability:
    """The joint selection on the whole record and how often each candidate is chosen on half-samples."""

    chosen: tuple[int, ...]  # on the whole record, in order
    probability: tuple[float, ...]  # per option
    n_eff: float
    per_half: float  # mean number chosen per half-sample

    def bound(self, options: int) -> float:
        """Meinshausen & Buehlmann's bound on the expected number of false claims."""
        return self.per_half ** 2 / ((2 * PI_CLAIM - 1) * max(options, 1))


def stability(gram: Gram, n_eff: float, max_groups: int) -> Stability:
    """The whole record's selection and each option's selection probability over :data:`PAIRS` complementary
    pairs of half-samples (drawn from a fixed seed)."""
    G, g, yy = gram.whole
    chosen = forward_select(G, g, yy, n_eff, base=gram.base, groups=gram.groups, max_groups=max_groups)
    rng = np.random.default_rng(20261128)
    counts = np.zeros(len(gram.groups))
    sizes = []
    for _ in range(PAIRS):
        perm = rng.permutation(BLOCKS)
        for half in (perm[:BLOCKS // 2], perm[BLOCKS // 2:]):
            Gh, gh, yh = gram.of(sorted(half.tolist()))
            picked = forward_select(Gh, gh, yh, n_eff / 2, base=gram.base, groups=gram.groups,
                                    max_groups=max_groups)
            counts[picked] += 1
            sizes.append(len(picked))
    return Stability(tuple(chosen), tuple((counts / (2 * PAIRS)).tolist()), n_eff, float(np.mean(sizes)))


def equivalents(gram: Gram, options: Sequence[Option], chosen: Sequence[int], n_eff: float,
                margin: float = EVIDENCE_MARGIN) -> dict[int, int]:
    """For each chosen option, the other effect's option that would do as well in its place (its swap changes
    BIC by less than `margin`), the closest one; options without an equivalent are left out."""
    G, g, yy = gram.whole
    log_n = math.log(max(n_eff, 2.0))
    out: dict[int, int] = {}
    for c in chosen:
        rest = [k for k in chosen if k != c]
        cols = list(gram.base) + [i for k in rest for i in gram.groups[k]]
        rss_c = _rss(G, g, yy, cols + gram.groups[c])
        best, best_gap = None, margin
        for k, option in enumerate(options):
            if k in chosen or option.effect.name == options[c].effect.name:
                continue
            rss_k = _rss(G, g, yy, cols + gram.groups[k])
            gap = n_eff * math.log(rss_k / rss_c) + (len(gram.groups[k]) - len(gram.groups[c])) * log_n
            if _better(gap, best_gap):
                best, best_gap = k, gap
        if best is not None:
            out[c] = best
    return out


def names_of(options: Sequence[Option], picked: Sequence[int]) -> list[str]:
    """The picked options as ``name on place`` (for messages)."""
    return [f"{options[k].effect.name} on {options[k].attachment.label}" for k in picked]


def by_key(options: Sequence[Option]) -> Mapping[tuple[str, str], int]:
    """Each option's index by its (effect, place) key."""
    return {o.key: k for k, o in enumerate(options)}
