"""Model-based compensation of identified effects: a linear controller plus the input that cancels the effect.

:func:`cosim.diagnose.diagnosis.diagnose` adds physical effects to a linear model as nonlinear terms, e.g. Coulomb
friction on the motor speed, ``omega_m' = ... + b Tm + c tanh(omega_m/eps)`` with ``c = -Fc b``. A linear
controller is designed on the model's linear part (:meth:`cosim.identify.model.IdentifiedModel.linear_part`), and
:class:`EffectCompensation` wraps it: at every call it evaluates the effect's terms on the measured outputs and
adds their **input equivalent** to the inner controller's input::

    u = sat(u_inner + G phi(y)),    G = -pinv(B_e) C_e

where ``phi`` are the terms the linear part lacks, ``C_e`` their coefficients and ``B_e`` the input gains in
the rows the effect enters. For one effect in one row driven by one input (friction on the motor, torque on
the motor) ``B_e G = -C_e`` exactly: the compensation cancels the modelled effect, ``Fc tanh(omega_m/eps)`` for
the friction above, and the inner controller sees the linear plant it was designed for. Where the effect
enters rows the inputs cannot reach as it does (``B_e G != -C_e``), the part that remains is reported in
``info["uncancelled_fraction"]``; rows no input acts on cannot be compensated and are refused.

The sum is limited to the inner controller's ``u_min``/``u_max`` and ``du_max``. The inner controller's
anti-windup sees its own output only, so keep the compensation small against the limits (friction of 2 % of
the rated torque, say). The terms may only use measured outputs (states), never inputs; the compensation
measures what it needs in addition to the inner controller's outputs (the motor speed for an MPC that
measures positions).

Examples
--------
A mass with viscous and Coulomb friction, ``v' = -2 v + u - 0.5 tanh(v/0.001)``, and a proportional speed
controller designed on its linear part; the compensation adds ``0.5 tanh(v/0.001)``:

>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> from controllers.pid import PID
>>> model = IdentifiedModel(states=("v",), inputs=("u",), terms=("v", "u", "tanh(v/0.001)"),
...                         coef=np.array([[-2.0, 1.0, -0.5]]))
>>> inner = PID(kp=4.0, dt=0.01, inputs="u", outputs="v")
>>> ctrl = EffectCompensation.from_model(inner, model)
>>> ctrl.terms, ctrl.gains.tolist(), ctrl.outputs
(('tanh(v/0.001)',), [[0.5]], ('v',))
>>> ctrl.setpoint = 1.0
>>> round(float(ctrl(0.0, [0.2])[0]), 6)    # 4*(1 - 0.2) + 0.5*tanh(200)
3.7
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cosim.errors import ControllerError, InvalidSettingError
from cosim.identify.model import IdentifiedModel
from cosim.identify.terms import FUNCTIONS, Term

from .base import Controller, ControllerEvent, _jsonable, controller_from_json, register

__all__ = ["EffectCompensation", "effect_terms"]

#: A row counts as driven by the inputs when its input gains reach this fraction of the largest one.
_DRIVEN = 1e-9


def effect_terms(model: IdentifiedModel) -> tuple[tuple[str, ...], np.ndarray]:
    """The terms of `model` that its linear part lacks, and their coefficients (states x terms).

    Parameters
    ----------
    model : IdentifiedModel
        Typically :attr:`cosim.diagnose.diagnosis.DiagnosisReport.model_after`.

    Returns
    -------
    terms : tuple of str
        Terms other than the constant, a state or an input, with a non-zero coefficient.
    coef : numpy.ndarray, shape (len(model.states), len(terms))

    Examples
    --------
    >>> model = IdentifiedModel(states=("v",), inputs=("u",), terms=("v", "u", "tanh(v/0.001)"),
    ...                         coef=np.array([[-2.0, 1.0, -0.5]]))
    >>> effect_terms(model)
    (('tanh(v/0.001)',), array([[-0.5]]))
    """
    linear = {"1", *model.states, *model.inputs}
    keep = [k for k, t in enumerate(model.terms) if t not in linear and np.any(model.coef[:, k] != 0.0)]
    return tuple(model.terms[k] for k in keep), np.array(model.coef[:, keep], dtype=float).reshape(len(model.states),
                                                                                                    len(keep))


def _compile_law(outputs: Sequence[str], terms: Sequence[Term], gains: np.ndarray):
    """A fast ``law(y) -> list`` computing ``gains @ terms(y)`` (a few µs per call; generated like
    :func:`cosim.identify.terms.compile_rhs`, from checked expressions only)."""
    names = {name: f"y[{i}]" for i, name in enumerate(outputs)}
    rows = [" + ".join(f"{float(g)!r}*{term.to_source(names)}" for g, term in zip(row, terms, strict=True)
                       if g != 0.0) or "0.0" for row in gains]
    namespace = {f"_f_{name}": funcs[1] for name, funcs in FUNCTIONS.items()}
    exec(compile(f"def law(y):\n    return [{', '.join(rows)}]", "<cosim compensation>", "exec"), namespace)
    return namespace["law"]


@register("compensation")
class EffectCompensation(Controller):
    """An inner controller plus the input equivalent of identified effects, computed from the measured outputs.

    Parameters
    ----------
    inner : Controller or mapping
        The controller designed on the linear part of the model (or its :meth:`Controller.to_dict` form).
    terms : sequence of str
        Term expressions of measured outputs (see :mod:`cosim.identify.terms`), e.g. ``["tanh(omega_m/0.00114)"]``.
    gains : array-like, shape (len(inner.inputs), len(terms))
        Input equivalent of each term: ``u_comp = gains @ terms(y)``.
    info : mapping, optional
        Design figures (the effects, the uncancelled fraction...), saved with the controller.

    Attributes
    ----------
    inner : Controller
    terms : tuple of str
    gains : numpy.ndarray
    outputs : tuple of str
        The inner controller's measured outputs, then the other outputs the terms use.
    compensation : numpy.ndarray
        The compensation input of the last call.

    Notes
    -----
    Set-points go to the inner controller; :attr:`events` are the inner controller's and this one's. The
    compensated controller has no linear design model (:attr:`design_model` is None): run it against the
    nonlinear model it was built from with ``closed_loop(..., model=model)``.
    """

    def __init__(self, inner: Controller | Mapping[str, Any], *, terms: Sequence[str], gains: Any,
                 info: Mapping[str, Any] | None = None) -> None:
        if isinstance(inner, Mapping):
            inner = controller_from_json(_jsonable(inner))
        if not isinstance(inner, Controller):
            raise InvalidSettingError(f"inner must be a controller, got {type(inner).__name__}")
        self._own_events: list[ControllerEvent] = []
        parsed = tuple(Term(str(t)) for t in ([terms] if isinstance(terms, str) else terms))
        if not parsed:
            raise InvalidSettingError("a compensation needs at least one term; without one use the inner controller")
        extra = [v for term in parsed for v in term.variables if v not in inner.outputs]
        outputs = tuple(inner.outputs) + tuple(dict.fromkeys(extra))
        taken = [v for term in parsed for v in term.variables if v in inner.inputs]
        if taken:
            raise InvalidSettingError(f"term uses the manipulated input {taken[0]!r}: a compensation is computed "
                                      "from measured outputs before the input is chosen")
        try:
            g = np.array(gains, dtype=float).reshape(len(inner.inputs), len(parsed))
        except (TypeError, ValueError):
            raise InvalidSettingError(f"gains must be a ({len(inner.inputs)}, {len(parsed)}) array (inputs x terms), "
                                      f"got {gains!r}") from None
        if not np.all(np.isfinite(g)):
            raise InvalidSettingError("compensation gains hold NaN or inf")
        super().__init__(dt=inner.dt, inputs=inner.inputs, outputs=outputs, tracked=inner.tracked,
                         u_min=inner.u_min, u_max=inner.u_max, du_max=inner.du_max, info=info)
        self.inner = inner
        self.terms = tuple(t.text for t in parsed)
        g.setflags(write=False)
        self.gains = g
        self._n_inner = len(inner.outputs)
        self._law = _compile_law(outputs, parsed, g)
        self._p = len(outputs)
        self._single = len(self.inputs) == 1
        self._rate = bool(np.any(np.isfinite(self.du_max)))
        self._lo, self._hi, self._du = float(self.u_min[0]), float(self.u_max[0]), float(self.du_max[0])
        self.compensation = np.zeros(len(self.inputs))
        self._u_prev: np.ndarray | None = None
        self._setpoint = np.array(inner.setpoint, dtype=float)

    @classmethod
    def from_model(cls, inner: Controller, model: IdentifiedModel, *,
                   info: Mapping[str, Any] | None = None) -> EffectCompensation:
        """Compensate the terms of `model` that its linear part lacks, at the input of `inner`.

        Parameters
        ----------
        inner : Controller
            Designed on ``model.linear_part()``; its inputs must be inputs of `model`.
        model : IdentifiedModel
            The model with the effects (e.g. ``diagnose(...).model_after``).
        info : mapping, optional
            Extra design figures to save.

        Raises
        ------
        InvalidSettingError
            `model` has no such term, an inner input is not a model input, or the effect enters only rows
            that no manipulated input acts on.
        """
        terms, coef = effect_terms(model)
        if not terms:
            raise InvalidSettingError("the model has no nonlinear term to compensate; use the controller as it is")
        missing = [name for name in inner.inputs if name not in model.inputs]
        if missing:
            raise InvalidSettingError(f"the controller drives {missing[0]!r}, which is not an input of the model "
                                      f"({list(model.inputs)})")
        b = np.zeros((len(model.states), len(inner.inputs)))
        for j, name in enumerate(inner.inputs):
            b[:, j] = model.coef[:, model.terms.index(name)] if name in model.terms else 0.0
        rows = np.flatnonzero(np.any(coef != 0.0, axis=1))
        b_e, c_e = b[rows], coef[rows]
        scale = float(np.max(np.abs(b))) if b.size else 0.0
        if scale == 0.0 or np.all(np.abs(b_e) <= _DRIVEN * scale):
            names = ", ".join(model.states[i] for i in rows)
            raise InvalidSettingError(f"the effect enters {names}, which no manipulated input acts on: it cannot be "
                                      "compensated at the input")
        gains = -np.linalg.pinv(b_e) @ c_e
        left = c_e + b_e @ gains
        uncancelled = float(np.linalg.norm(left) / np.linalg.norm(c_e))
        figures = {"compensated_rows": [model.states[i] for i in rows], "uncancelled_fraction": uncancelled,
                   **dict(info or {})}
        return cls(inner, terms=terms, gains=gains, info=figures)

    # ------------------------------------------------------------------ the calling convention
    @property
    def events(self) -> list[ControllerEvent]:  # type: ignore[override]
        """The inner controller's events and this one's, in time order."""
        inner = getattr(self, "inner", None)
        return sorted([*(inner.events if inner is not None else []), *self._own_events], key=lambda e: e.time)

    @events.setter
    def events(self, value: list[ControllerEvent]) -> None:
        self._own_events = list(value)

    def _set_setpoint(self, r: np.ndarray) -> None:
        self._setpoint = r
        if hasattr(self, "inner"):
            self.inner.setpoint = r

    def reset(self) -> None:
        """Reset the inner controller; clear the last input and :attr:`events`."""
        self.inner.reset()
        self._own_events.clear()
        self._u_prev = None
        self.compensation = np.zeros(len(self.inputs))

    def __call__(self, t: float, y: Sequence[float]) -> np.ndarray:
        """The inner controller's input plus the compensation, limited; `y` in :attr:`outputs` order."""
        try:
            if len(y) != self._p:
                raise ValueError
            comp = self._law(y)
        except (TypeError, ValueError, IndexError):
            raise InvalidSettingError(f"the compensated controller measures {list(self.outputs)}; "
                                      f"got y={y!r}") from None
        u = self.inner(t, y[:self._n_inner])
        if self._single:  # the common case, kept lean: a few µs per call at kHz rates
            c = comp[0]
            if c - c != 0.0:
                raise ControllerError(f"the compensation is not finite at t={t:.6g} s for "
                                      f"{list(self.outputs)}={list(y)}")
            total = float(u[0]) + c
            prev = self._u_prev
            if prev is not None and self._rate:
                total = min(max(total, prev - self._du), prev + self._du)
            total = min(max(total, self._lo), self._hi)
            self._u_prev = total
            self.compensation = np.array((c,))
            return np.array((total,))
        comp = np.asarray(comp, dtype=float)
        if not np.all(np.isfinite(comp)):
            raise ControllerError(f"the compensation is not finite at t={t:.6g} s for {list(self.outputs)}={list(y)}")
        total = np.asarray(u, dtype=float) + comp
        if self._u_prev is not None and self._rate:
            total = np.clip(total, self._u_prev - self.du_max, self._u_prev + self.du_max)
        total = np.clip(total, self.u_min, self.u_max)
        self._u_prev = total
        self.compensation = comp
        return total

    # ------------------------------------------------------------------ files
    def _settings(self) -> dict[str, Any]:
        return {"inner": self.inner.to_dict(), "terms": list(self.terms), "gains": self.gains}

    def __repr__(self) -> str:
        law = " + ".join(f"{g:.6g}*{t}" for g, t in zip(self.gains[0], self.terms, strict=True))
        return f"EffectCompensation({self.inner!r}, u += {law})"
