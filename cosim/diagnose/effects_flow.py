"""Catalogue effects of levels and bounds: square-root outflow of a tank, and a hard stop or overflow.

Registered with the catalogue (:data:`~cosim.diagnose.effects.EFFECTS`) when the package is imported (its
``__init__`` imports this module, so any import of :mod:`cosim.diagnose.effects` registers them; importing it from
``effects`` itself would be a cycle).

* ``sqrt_outflow`` - a tank's outflow through an orifice, ``h' = ... - a*sqrt(h)`` (Torricelli), written
  ``sqrt(abs(h))``. It attaches to each **level**: a state whose own equation is dynamic but which is not a
  velocity, i.e. neither the position nor the velocity of a kinematic pair ``p' = v`` (:func:`level_states`; a
  tank level has no velocity state, and :class:`~cosim.diagnose.effects.Roles` is unchanged: the rule reads its
  ``dynamic_rows`` and ``velocity_of``). Only a level that stays non-negative over the record is tried (a share
  :data:`NEGATIVE_SHARE` of the samples below zero at most). Parameters: ``a``, minus the coefficient in the
  level's own row (positive: the tank drains); ``a_input``, the same over that row's input gain, where it has one
  (for a tank fed by an inflow ``u``, ``h' = u/A - ...``: the orifice's coefficient in the inflow's units); and
  ``inflow_ROW``, the coefficient in any other row chosen (the tank below, fed by this outflow).
* ``hard_stop`` (selection alias ``overflow``) - a state that cannot pass a bound ``B``: a one-sided stiff term,
  a ramp past the bound, ``0.5*(x-B)+0.5*abs(x-B)`` (= ``max(x-B, 0)``) above an upper bound, or
  ``0.5*(B-x)+0.5*abs(B-x)`` below a lower one; a tank's overflow is the upper one on its level. It attaches to
  every state that is not a velocity (a position, whose stop pushes in its velocity's row, or a level), on each
  side; the search chooses the row(s). The nuisance ``bound`` is gridded, linearly, inside the range the
  record's free run reaches near that side (between its median and its :data:`BOUND_QUANTILE` quantile, so that
  the state spends time beyond the bound), refined and fitted. A nuisance is fitted on a log scale, so it is
  positive: a bound below zero is tried at its own places (labels ``"x (upper, below 0)"``), with the bound's
  size as the nuisance. Parameters: ``bound`` (signed), ``stiffness`` (the rate the term pushes back per unit
  past the bound in the state's own row for a level, in its velocity's row for a position, else in the first
  row chosen: positive for a stop) and ``stiffness_input``, the same over that row's input gain (a force per
  unit past the stop), where it has one.

Examples
--------
>>> from cosim.diagnose.effects import EFFECTS, Attachment
>>> EFFECTS["sqrt_outflow"].terms(Attachment("h1", ("h1",), ("h1",)), None)
('sqrt(abs(h1))',)
>>> EFFECTS["hard_stop"].terms(Attachment("h2 (upper)", ("h2",), ("h2",)), 0.5)
('0.5*(h2-0.5)+0.5*abs(h2-0.5)',)
>>> EFFECTS["hard_stop"].terms(Attachment("x (lower, below 0)", ("x",), ("v",)), 0.2)
('0.5*(-0.2-x)+0.5*abs(-0.2-x)',)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ._record_band import RecordBand
from .effects import Attachment, Effect, Roles, _num, register_effect

__all__ = ["BOUND_QUANTILE", "NEGATIVE_SHARE", "level_states"]

#: Most share of a level's samples below zero (noise, a sensor's offset) for the square-root outflow to be tried.
NEGATIVE_SHARE = 0.01
#: The quantile of the free run past which a bound is not tried (at least 1 - this share lies beyond it), and
#: the median the other end of the bound's grid.
BOUND_QUANTILE = 0.97
#: Values of a bound's grid.
BOUND_POINTS = 6
_SIDES = ("upper", "lower")
_BELOW = ", below 0"


def level_states(roles: Roles) -> tuple[str, ...]:
    """The states whose own rows are dynamic and which are not velocities (a tank's level), in the model's order.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> tank = IdentifiedModel(states=("h1", "h2"), inputs=("u",), terms=("h1", "h2", "u"),
    ...                        coef=np.array([[-0.1, 0.0, 1.0], [0.1, -0.1, 0.0]]))
    >>> level_states(Roles.of(tank))
    ('h1', 'h2')
    """
    return tuple(s for s in roles.dynamic_rows if s not in roles.velocities)


def _place(label: str) -> tuple[str, str, bool]:
    """(state, side, bound below zero) of a hard stop's attachment label ``"x (upper)"``, ``"x (lower, below 0)"``."""
    state, _, rest = label.rpartition(" (")
    below = rest.endswith(_BELOW + ")")
    return state, rest.removesuffix(")").removesuffix(_BELOW), below


@dataclass(frozen=True)
class _LevelEffect(Effect):
    """An effect on levels (:func:`level_states`)."""

    def attachments(self, roles: Roles) -> list[Attachment]:
        return [Attachment(s, (s,), roles.dynamic_rows) for s in level_states(roles)]


@dataclass(frozen=True)
class _BoundEffect(Effect):
    """An effect beyond a bound of a state that is not a velocity: one place per state, side and sign of the bound."""

    def attachments(self, roles: Roles) -> list[Attachment]:
        states = [*roles.positions, *level_states(roles)]
        return [Attachment(f"{s} ({side}{below})", (s,), roles.dynamic_rows)
                for s in states for side in _SIDES for below in ("", _BELOW)]

    def signal(self, attachment: Attachment, data: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.asarray(data[_place(attachment.label)[0]], dtype=float)


# ---------------------------------------------------------------------------------------------- square-root outflow
def _outflow_span(level: np.ndarray, band: RecordBand, label: str) -> tuple[float, float] | None:
    """Everywhere, on a level that stays non-negative: the measured one where the band has it (a linear base's
    free run undershoots where the plant's level never went below zero: 8 % of the samples on a two-tank
    record, whose outflows were then never tried), else the free run."""
    below = band.below_zero.get(label)
    if below is None:
        below = float(np.mean(level < 0.0)) if level.size else 1.0
    return (0.0, math.inf) if level.size and below <= NEGATIVE_SHARE else None


def _outflow_params(coef: dict[str, np.ndarray], value: float | None, roles: Roles,
                    attachment: Attachment) -> dict[str, float]:
    level = attachment.signals[0] if attachment.signals else attachment.label
    out = {"a": -float(coef[level][0]) if level in coef else math.nan}
    if level in coef and roles.gain(level):
        out["a_input"] = out["a"] / roles.gain(level)
    out.update({f"inflow_{row}": float(values[0]) for row, values in coef.items() if row != level})
    return out


# ---------------------------------------------------------------------------------------------- hard stop
def _stop_terms(attachment: Attachment, value: float | None) -> tuple[str, ...]:
    state, side, below = _place(attachment.label)
    bound = -float(value) if below else float(value)
    past = (f"{state}-{_num(bound)}" if bound >= 0 else f"{state}+{_num(-bound)}") if side == "upper" \
        else f"{_num(bound)}-{state}"
    return (f"0.5*({past})+0.5*abs({past})",)


#: The least share of the samples a measured state must spend at its extreme for a hard stop to be tried there
#: (a level held at the tank's top, an axis against its stop); a state that only turns there is not held.
LINGER = 0.03


def _stop_span(x: np.ndarray, band: RecordBand, label: str) -> tuple[float, float] | None:
    """The bound's size between the free run's median and its BOUND_QUANTILE quantile on the label's side, or the
    measured state's extreme there (smoothed) where that lies further out, where its sign is the label's; None
    where the state does not move or the range holds no bound of that sign.

    The measured extreme: a state held at a bound for a few % of the record sits there, not beyond it, and a
    base model's free run may reach it even less (a tank at its overflow for 3.3 % of a record: the bound, 1.037,
    lay above the free run's 97 % quantile, the fit stopped at that edge and was refused as standing in for
    another effect)."""
    state, side, below = _place(label)
    if x.size < 2 or not np.ptp(x) > 0:
        return None
    if state in band.lingers and band.lingers[state][side == "upper"] < LINGER:
        return None  # the measured state never sits at that end: nothing holds it there
    q = BOUND_QUANTILE if side == "upper" else 1.0 - BOUND_QUANTILE
    end = float(np.quantile(x, q))
    if state in band.extremes:
        end = max(end, band.extremes[state][1]) if side == "upper" else min(end, band.extremes[state][0])
    lo, hi = sorted((float(np.median(x)), end))
    if below:
        lo, hi = -hi, -lo
    if hi <= 0.0:
        return None
    return max(lo, hi / BOUND_POINTS), hi


def _stop_grid(lo: float, hi: float, x: np.ndarray) -> list[float]:
    return [float(v) for v in np.linspace(lo, hi, BOUND_POINTS)]


def _stop_params(coef: dict[str, np.ndarray], value: float | None, roles: Roles,
                 attachment: Attachment) -> dict[str, float]:
    state, side, below = _place(attachment.label)
    own = roles.velocity_of.get(state, state)
    row = own if own in coef else next(iter(coef))
    stiffness = (-1.0 if side == "upper" else 1.0) * float(coef[row][0])
    out = {"bound": (-1.0 if below else 1.0) * float(value) if value is not None else math.nan,
           "stiffness": stiffness}
    if roles.gain(row):
        out["stiffness_input"] = stiffness / roles.gain(row)
    return out


register_effect(_LevelEffect(
    "sqrt_outflow", "square-root outflow of a level: a tank draining through an orifice, h' = ... - a*sqrt(h)",
    "level", None, "", lambda a, v: (f"sqrt(abs({a.signals[0]}))",), _outflow_params,
    plausible=lambda p: not p["a"] <= 0.0, span=_outflow_span))
register_effect(_BoundEffect(
    "hard_stop", "a hard stop or overflow: a state that cannot pass a bound (a stiff push back beyond it)",
    "state", "bound", "position", _stop_terms, _stop_params, plausible=lambda p: not p["stiffness"] <= 0.0,
    span=_stop_span, make_grid=_stop_grid))
