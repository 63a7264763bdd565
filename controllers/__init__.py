"""Controllers that run against a plant, each designed from a ``control.StateSpace``.

* :class:`~controllers.pid.PID` - discrete PID with derivative filter, anti-windup, output limits and
  bumpless set-point changes; :func:`~controllers.pid.tune_pid` designs it for a phase margin or bandwidth.
* :class:`~controllers.mpc.MPC` - linear MPC solved with casadi (condensed QP), with terminal cost from the
  discrete Riccati equation, input and input-rate bounds, soft state constraints, offset-free tracking
  through a disturbance observer, and warm start.
* :class:`~controllers.compensation.EffectCompensation` - wraps either one and adds the input that cancels an
  effect identified by :func:`cosim.diagnose.diagnosis.diagnose` (Coulomb friction, say), from the measured outputs.

Every controller follows :class:`~controllers.base.Controller`: ``reset()``, ``__call__(t, y) -> u``,
``setpoint``, ``save(path)``; :func:`load_controller` reads any kind back.
"""

from __future__ import annotations

from .base import Controller, ControllerEvent, DesignModel, controller_from_json, controller_kinds, load_controller

_LAZY = {"PID": "pid", "tune_pid": "pid", "MPC": "mpc", "EffectCompensation": "compensation"}


def __getattr__(name: str):
    """Import a controller kind on first use (PEP 562): casadi loads only when the MPC is asked for."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'controllers' has no attribute {name!r}")


__all__ = ["Controller", "ControllerEvent", "DesignModel", "controller_from_json", "controller_kinds",
           "load_controller", *_LAZY]
