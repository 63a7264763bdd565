"""PID control: the discrete controller and its tuner on a linear model.

* :class:`PID` (:mod:`controllers.pid.controller`) - discrete parallel PID with setpoint weight, filtered
  derivative of the measurement or a measured velocity, limits, rate limit and anti-windup; the module
  docstring there gives the exact law;
* :func:`tune_pid` (:mod:`controllers.pid.tuning`) - designs the gains on a ``control.StateSpace``
  (continuous, sampled with zero-order hold, or discrete) for a phase margin or a crossover frequency, under
  gain-margin and modulus-margin constraints, and reports the achieved margins in ``pid.info``. Its search
  is in :mod:`controllers.pid._search`, the plant's frequency response in :mod:`controllers.pid._plant`.

The tuner builds a :class:`PID`; the controller knows nothing of the tuner.

Examples
--------
>>> import control
>>> pid = tune_pid(control.ss(control.tf([2.0], [0.5, 1.0])), dt=0.01, bandwidth=5.0)
>>> isinstance(pid, PID), pid.info["structure"]
(True, 'PI')
"""

from __future__ import annotations

from .controller import ANTI_WINDUP, PID
from .tuning import tune_pid

__all__ = ["ANTI_WINDUP", "PID", "tune_pid"]
