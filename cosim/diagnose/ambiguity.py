"""Readings the data cannot tell apart, and the experiment that would.

Two effects whose features are nearly the same on a record (:func:`~cosim.diagnose.selection.equivalents`:
swapping one for the other changes BIC by less than the evidence margin) are reported together, in the
catalogue's order, with the input that would separate them: what the record lacks that makes their features
differ (slow motion for Coulomb and Stribeck friction, a larger swing for gravity and a spring, a wider speed or
amplitude range, another frequency band). :class:`Ambiguity` holds the set, the sentence and the experiment as
numbers (``to_dict`` is the JSON's ``ambiguous`` entry).

Examples
--------
>>> a = Ambiguity(("coulomb_friction", "stribeck"), ("v", "v"), "speed", "v", 0.002, "below")
>>> a.sentence
'coulomb_friction or stribeck: these data cannot tell them apart'
>>> a.to_separate
'to separate them, record v moving slower than 0.002 (the record never does)'
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._record_band import RecordBand
from .effects import EFFECTS
from .screening import OutputErrorScreen

__all__ = ["Ambiguity", "ambiguity_of"]


@dataclass(frozen=True)
class Ambiguity:
    """Two readings of the same data, and the experiment that would tell them apart.

    Attributes
    ----------
    effects : tuple of str
        The effects, in the catalogue's order.
    attached_to : tuple of str
        Where each acts.
    quantity : str
        What the experiment must reach: ``"speed"``, ``"amplitude"`` or ``"range"``.
    signal : str
        The signal it concerns.
    level : float
        The level to reach (in the signal's units).
    direction : str
        ``"below"`` (move slower than `level`) or ``"beyond"`` (swing past it).
    """

    effects: tuple[str, ...]
    attached_to: tuple[str, ...]
    quantity: str
    signal: str
    level: float
    direction: str

    @property
    def sentence(self) -> str:
        return f"{' or '.join(self.effects)}: these data cannot tell them apart"

    @property
    def to_separate(self) -> str:
        if self.direction == "below":
            return (f"to separate them, record {self.signal} moving slower than {self.level:.3g} "
                    "(the record never does)")
        return f"to separate them, drive {self.signal} to a {self.quantity} beyond {self.level:.3g}"

    def to_dict(self) -> dict[str, Any]:
        return {"effects": list(self.effects), "attached_to": list(self.attached_to), "reason": self.sentence,
                "to_separate": self.to_separate, "experiment": {"quantity": self.quantity, "signal": self.signal,
                                                                "level": self.level, "direction": self.direction}}


def ambiguity_of(a: Any, b: Any, screen: OutputErrorScreen, band: RecordBand) -> Ambiguity:
    """The ambiguity of two :class:`~cosim.diagnose.selection.Option` readings on `screen`'s record."""
    order = list(EFFECTS)
    first, second = sorted((a, b), key=lambda o: (order.index(o.effect.name) if o.effect.name in order
                                                  else len(order), o.attachment.label))
    names = {first.effect.name, second.effect.name}
    data = screen.free_run
    signal = (first.attachment.signals or second.attachment.signals or (screen.model.states[0],))[0]
    values = np.abs(np.asarray(data.get(signal, np.zeros(1)), dtype=float))
    if names & {"stribeck"} and names & {"coulomb_friction", "viscous_asymmetry"}:
        vs = next(o.value for o in (first, second) if o.effect.name == "stribeck")
        return Ambiguity((first.effect.name, second.effect.name), (first.attachment.label, second.attachment.label),
                         "speed", signal, float(vs or np.percentile(values, 5)), "below")
    quantity = "amplitude" if any(o.effect.attaches_to in ("position", "position_or_pair", "pair")
                                  for o in (first, second)) else "range"
    return Ambiguity((first.effect.name, second.effect.name), (first.attachment.label, second.attachment.label),
                     quantity, signal, float(2.0 * np.max(values)) if values.size else 0.0, "beyond")
