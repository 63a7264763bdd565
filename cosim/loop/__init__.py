"""The loop room: controllers run against the plant, and the verdict on them.

* :mod:`~cosim.loop.closed_loop` - :func:`closed_loop`: a controller against the FMU and against its design
  model (:class:`ModelPlant`), with a :class:`ClosedLoopResult`;
* :mod:`~cosim.loop.response` - step-response figures (rise and settling time, overshoot, IAE...);
* :mod:`~cosim.loop.validation` - scenarios and specs into a :class:`Verdict` (:func:`validate`,
  :func:`assert_meets` for test suites); :mod:`~cosim.loop.validation_report` - its HTML report;
* :mod:`~cosim.loop.plots` - :func:`plot_closed_loop`.

Imports ``controllers`` and every room below it.
"""

from __future__ import annotations

from .closed_loop import ClosedLoopResult, ModelPlant, closed_loop
from .plots import plot_closed_loop
from .response import response_metrics
from .validation import (
    SCENARIO_KINDS,
    TELESCOPE_SPECS,
    Scenario,
    Spec,
    Verdict,
    assert_meets,
    disturbance_step,
    parse_scenario,
    parse_spec,
    setpoint_ramp,
    setpoint_step,
    validate,
)
from .validation_report import write_validation_report

__all__ = [
    "ClosedLoopResult", "ModelPlant", "SCENARIO_KINDS", "Scenario", "Spec", "TELESCOPE_SPECS", "Verdict",
    "assert_meets", "closed_loop", "disturbance_step", "parse_scenario", "parse_spec", "plot_closed_loop",
    "response_metrics", "setpoint_ramp", "setpoint_step", "validate", "write_validation_report",
]
