"""The effect catalogue: physical effects a model may lack, each with the regressors it adds and its search.

Every effect is registered by name (:data:`EFFECTS`, :func:`register_effect`) with

* its **physical meaning** (one line, for reports);
* what it **attaches to**: a velocity state, a position state, a pair of coupled positions, an input, or
  nothing. :class:`Roles` finds the candidates from the model itself: a state ``p`` whose equation is
  ``p' = v`` is a position with velocity ``v``; two positions whose equations' rows share a term in both
  are coupled; the model's inputs are the inputs;
* the **nuisance parameter** it searches on its own (a smoothing velocity, a width, a period, a delay), with a
  grid built from the data (:meth:`Effect.grid`), refined afterwards by a bounded scalar search;
* the **terms** it adds, as cosim term expressions (:mod:`cosim.terms`: the augmented model simulates, saves
  and exports like any other). A delay cannot be written as a term: it adds a delayed copy of the input as
  a new data column (:meth:`Effect.columns`) and the model uses it in place of the input;
* how its **physical parameters** follow from the fitted coefficients: a force or torque is the coefficient
  divided by the row's input gain (``-c/b`` for a friction term, which opposes the motion).

The catalogue: ``coulomb_friction``, ``viscous_asymmetry``, ``stribeck``, ``backlash``, ``deadzone``,
``saturation``, ``cogging``, ``gravity``, ``offset``, ``delay``, ``cubic_stiffness``.

Examples
--------
>>> sorted(EFFECTS)[:4]
['backlash', 'cogging', 'coulomb_friction', 'cubic_stiffness']
>>> EFFECTS["coulomb_friction"].terms(Attachment("omega_m", ("omega_m",), ("omega_m",)), 0.01)
('tanh(omega_m/0.01)',)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .errors import InvalidSettingError, UnknownVariableError
from .model import IdentifiedModel

__all__ = ["EFFECTS", "Attachment", "Effect", "Roles", "register_effect"]


def _num(value: float) -> str:
    """A number as a term literal: short, exact enough (9 significant digits)."""
    return f"{value:.9g}"


def _clip(expr: str, width: float) -> str:
    """``clip(expr, -w, w)`` written with ``abs``: ``(abs(e + w) - abs(e - w)) / 2``."""
    w = _num(width)
    return f"0.5*abs({expr}+{w})-0.5*abs({expr}-{w})"


@dataclass(frozen=True)
class Attachment:
    """Where an effect acts: a label, the signals it reads, and the model rows (states' equations) it enters."""

    label: str
    signals: tuple[str, ...]
    rows: tuple[str, ...]


@dataclass(frozen=True)
class Roles:
    """The roles the model's signals play, found from its equations (see the module notes).

    Attributes
    ----------
    velocity_of : dict
        Position state -> its velocity state (rows ``p' = v``).
    dynamic_rows : tuple of str
        States whose equations are not kinematic: where forces act.
    pairs : tuple of (str, str)
        Coupled positions: both appear, with opposite signs, in a dynamic row.
    inputs : tuple of str
    input_gain : dict
        Per dynamic row, (input name, coefficient) of its largest input term, if any.
    """

    velocity_of: dict[str, str]
    dynamic_rows: tuple[str, ...]
    pairs: tuple[tuple[str, str], ...]
    inputs: tuple[str, ...]
    input_gain: dict[str, tuple[str, float]]

    @classmethod
    def of(cls, model: IdentifiedModel) -> Roles:
        terms = list(model.terms)
        velocity_of: dict[str, str] = {}
        for i, state in enumerate(model.states):
            row = model.coef[i]
            nonzero = [t for k, t in enumerate(terms) if row[k] != 0.0]
            if len(nonzero) == 1 and nonzero[0] in model.states and nonzero[0] != state \
                    and math.isclose(row[terms.index(nonzero[0])], 1.0, rel_tol=1e-9):
                velocity_of[state] = nonzero[0]
        dynamic = tuple(s for s in model.states if s not in velocity_of)
        positions = list(velocity_of)
        pairs = []
        for a_i, a in enumerate(positions):
            for b in positions[a_i + 1:]:
                for row_name in dynamic:
                    row = model.coef[model.states.index(row_name)]
                    ca = row[terms.index(a)] if a in terms else 0.0
                    cb = row[terms.index(b)] if b in terms else 0.0
                    if ca * cb < 0:
                        pairs.append((a, b))
                        break
        gains = {}
        for row_name in dynamic:
            row = model.coef[model.states.index(row_name)]
            best = [(abs(row[terms.index(u)]), u) for u in model.inputs if u in terms and row[terms.index(u)] != 0]
            if best:
                u = max(best)[1]
                gains[row_name] = (u, float(row[terms.index(u)]))
        return cls(velocity_of=velocity_of, dynamic_rows=dynamic, pairs=tuple(pairs), inputs=tuple(model.inputs),
                   input_gain=gains)

    @property
    def velocities(self) -> tuple[str, ...]:
        return tuple(self.velocity_of.values())

    @property
    def positions(self) -> tuple[str, ...]:
        return tuple(self.velocity_of)

    def rows_for_input(self, name: str) -> tuple[str, ...]:
        return tuple(row for row, (u, _) in self.input_gain.items() if u == name)


@dataclass(frozen=True)
class Effect:
    """One catalogued effect (see the module notes). Instances live in :data:`EFFECTS`."""

    name: str
    meaning: str
    attaches_to: str  # "velocity", "position", "pair", "input" or "none"
    nuisance: str | None
    unit: str  # of the nuisance: "velocity", "position", "twist", "input", "samples", "periods" or ""
    make_terms: Callable[[Attachment, float | None], tuple[str, ...]]
    params: Callable[[dict[str, np.ndarray], float | None, Roles, Attachment], dict[str, float]]
    grid_fractions: tuple[float, ...] = ()
    integer: bool = False

    def attachments(self, roles: Roles) -> list[Attachment]:
        """Every place the effect could act in a model with these `roles`."""
        dyn = roles.dynamic_rows
        if self.attaches_to == "velocity":
            return [Attachment(v, (v,), dyn) for v in roles.velocities]
        if self.attaches_to == "position":
            return [Attachment(p, (p,), dyn) for p in roles.positions]
        if self.attaches_to == "pair":
            out = []
            for a, b in roles.pairs:
                rows = tuple(r for r in dyn)
                out.append(Attachment(f"{a}-{b}", (a, b), rows))
            return out
        if self.attaches_to == "input":
            return [Attachment(u, (u,), roles.rows_for_input(u)) for u in roles.inputs if roles.rows_for_input(u)]
        return [Attachment("constant", (), dyn)]

    def grid(self, attachment: Attachment, data: Mapping[str, np.ndarray]) -> list[float | None]:
        """Candidate values of the nuisance parameter, scaled to the data."""
        if self.nuisance is None:
            return [None]
        if self.integer:
            return [float(v) for v in self.grid_fractions]
        signal = self.signal(attachment, data)
        scale = float(np.max(np.abs(signal))) if signal.size else 1.0
        scale = scale if scale > 0 else 1.0
        return [f * scale for f in self.grid_fractions]

    def signal(self, attachment: Attachment, data: Mapping[str, np.ndarray]) -> np.ndarray:
        """The signal the nuisance parameter is measured on (the twist for a pair)."""
        if len(attachment.signals) == 2:
            return np.asarray(data[attachment.signals[0]]) - np.asarray(data[attachment.signals[1]])
        if attachment.signals:
            return np.asarray(data[attachment.signals[0]])
        return np.zeros(0)

    def terms(self, attachment: Attachment, value: float | None) -> tuple[str, ...]:
        """The term expressions the effect adds at `attachment` with nuisance `value`."""
        return self.make_terms(attachment, value)

    def columns(self, attachment: Attachment, value: float | None, data: Mapping[str, np.ndarray]) -> dict:
        """Extra data columns the effect needs (a delayed input); empty for most effects."""
        if self.name != "delay":
            return {}
        u = np.asarray(data[attachment.signals[0]], dtype=float)
        d = int(round(value or 0))
        return {delayed_name(attachment.signals[0], d): np.concatenate([np.full(d, u[0]), u[:len(u) - d]])}

    def parameters(self, coef: dict[str, np.ndarray], value: float | None, roles: Roles,
                   attachment: Attachment) -> dict[str, float]:
        """Physical parameters from the coefficients of the effect's terms, per row (``coef[row]``)."""
        return self.params(coef, value, roles, attachment)


def delayed_name(name: str, samples: int) -> str:
    """Name of the column holding input `name` delayed by `samples` samples."""
    return f"{name}_delayed_{samples}"


EFFECTS: dict[str, Effect] = {}


def register_effect(effect: Effect) -> Effect:
    """Add an effect to the catalogue (a name may be registered once)."""
    if effect.name in EFFECTS:
        raise InvalidSettingError(f"effect {effect.name!r} is already registered")
    EFFECTS[effect.name] = effect
    return effect


def effect_names(selection: str | Sequence[str] = "all") -> list[str]:
    """Catalogue names from ``"all"``, a comma-separated string or a list; unknown names are refused."""
    if isinstance(selection, str):
        selection = list(EFFECTS) if selection.strip() == "all" else [s.strip() for s in selection.split(",")]
    unknown = [s for s in selection if s not in EFFECTS]
    if unknown:
        raise UnknownVariableError(f"no effect named {unknown[0]!r} in the catalogue; known: {', '.join(EFFECTS)}")
    return list(selection)


# ---------------------------------------------------------------------------------------------- parameter helpers
def _force(coef: dict[str, np.ndarray], roles: Roles, index: int = 0, sign: float = 1.0) -> dict[str, float]:
    """The coefficient as a force/torque at the input of each row that has one (``sign * c / b``)."""
    out = {}
    for row, values in coef.items():
        if row in roles.input_gain:
            u, b = roles.input_gain[row]
            out[f"{row}"] = sign * float(values[index]) / b
    return out


def _first(values: dict[str, float]) -> float:
    return next(iter(values.values())) if values else math.nan


def _friction_params(name: str) -> Callable:
    def params(coef, value, roles, attachment):
        forces = _force(coef, roles, sign=-1.0)
        out = {name: _first(forces)}
        if value is not None:
            out["smoothing_velocity"] = float(value)
        return out
    return params


def _stribeck_params(coef, value, roles, attachment):
    return {"Fs": _first(_force(coef, roles, sign=-1.0)), "vs": float(value)}


def _backlash_params(coef, value, roles, attachment):
    out = {"half_width": float(value)}
    for row, values in coef.items():
        out[f"coef_{row}"] = float(values[0])
    return out


def _input_level_params(name: str) -> Callable:
    def params(coef, value, roles, attachment):
        row = attachment.rows[0] if attachment.rows else None
        b = roles.input_gain.get(row, (None, math.nan))[1] if row else math.nan
        c = float(coef[row][0]) if row in coef else math.nan
        return {name: float(value), "gain_ratio": -c / b if b else math.nan}
    return params


def _periodic_params(name: str) -> Callable:
    def params(coef, value, roles, attachment):
        out = {}
        for row, values in coef.items():
            amp = float(math.hypot(values[0], values[1]))
            if row in roles.input_gain:
                amp /= abs(roles.input_gain[row][1])
                out[f"amplitude_{row}"] = amp
            else:
                out[f"amplitude_{row}_accel"] = amp
            out[f"phase_{row}"] = float(math.atan2(values[1], values[0]))
        if value is not None:
            out[name] = float(value)
        return out
    return params


def _offset_params(coef, value, roles, attachment):
    return {f"offset_{row}": v for row, v in _force(coef, roles).items()}


def _delay_params(coef, value, roles, attachment):
    return {"delay_samples": float(value)}


def _cubic_params(coef, value, roles, attachment):
    return {f"coef_{row}": float(values[0]) for row, values in coef.items()}


# ---------------------------------------------------------------------------------------------- the catalogue
register_effect(Effect(
    "coulomb_friction", "Coulomb friction: a force of constant size opposing the motion (smooth near zero speed)",
    "velocity", "smoothing_velocity", "velocity",
    lambda a, v: (f"tanh({a.signals[0]}/{_num(v)})",), _friction_params("Fc"),
    grid_fractions=(3e-4, 1e-3, 3e-3, 1e-2, 3e-2)))
register_effect(Effect(
    "viscous_asymmetry", "viscous friction that differs between positive and negative speed (|v| term)",
    "velocity", None, "", lambda a, v: (f"abs({a.signals[0]})",), _friction_params("viscous_asymmetry")))
register_effect(Effect(
    "stribeck", "Stribeck effect: extra friction at low speed (stiction) fading over the Stribeck velocity vs",
    "velocity", "vs", "velocity",
    lambda a, v: (f"exp(-({a.signals[0]}/{_num(v)})**2)*tanh({a.signals[0]}/{_num(v / 30)})",), _stribeck_params,
    grid_fractions=(3e-3, 1e-2, 3e-2, 0.1, 0.3)))
register_effect(Effect(
    "backlash", "backlash: a dead band in the coupling between two positions (no force inside the gap)",
    "pair", "half_width", "twist",
    lambda a, v: (_clip(f"({a.signals[0]}-{a.signals[1]})", v),), _backlash_params,
    grid_fractions=(0.02, 0.05, 0.1, 0.2, 0.4)))
register_effect(Effect(
    "deadzone", "dead zone on an input: small commands have no effect", "input", "width", "input",
    lambda a, v: (_clip(a.signals[0], v),), _input_level_params("width"),
    grid_fractions=(0.01, 0.03, 0.1, 0.2, 0.4)))
register_effect(Effect(
    "saturation", "saturation of an input: commands beyond a level are clipped", "input", "level", "input",
    lambda a, v: (f"{a.signals[0]}-({_clip(a.signals[0], v)})",), _input_level_params("level"),
    grid_fractions=(0.3, 0.5, 0.7, 0.85, 0.95)))
register_effect(Effect(
    "cogging", "cogging: a torque periodic in an angle (n periods per radian)", "position", "periods", "periods",
    lambda a, v: (f"sin({_num(v)}*{a.signals[0]})", f"cos({_num(v)}*{a.signals[0]})"), _periodic_params("periods"),
    grid_fractions=tuple(float(n) for n in range(2, 65)), integer=True))
register_effect(Effect(
    "gravity", "gravity: a torque proportional to the sine of an angle (an unbalanced load)", "position", None, "",
    lambda a, v: (f"sin({a.signals[0]})", f"cos({a.signals[0]})"), _periodic_params("periods")))
register_effect(Effect(
    "offset", "a constant force or torque (offset, unbalance, amplifier bias)", "none", None, "",
    lambda a, v: ("1",), _offset_params))
register_effect(Effect(
    "delay", "a time delay on an input (transport, computation)", "input", "delay", "samples",
    lambda a, v: (delayed_name(a.signals[0], int(round(v))),), _delay_params,
    grid_fractions=tuple(float(d) for d in (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50)), integer=True))
register_effect(Effect(
    "cubic_stiffness", "a hardening or softening spring: a force cubic in the twist between two positions",
    "pair", None, "", lambda a, v: (f"({a.signals[0]}-{a.signals[1]})**3",), _cubic_params))
