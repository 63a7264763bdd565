"""Closed-loop performance figures of a response: rise and settling time, overshoot, IAE, steady-state error.

Definitions (the usual ones of control textbooks, e.g. Åström & Murray, *Feedback Systems*, ch. 5):

* the **event** is the last set-point change (or, for a disturbance test, the disturbance step) at ``t_event``;
  the **step** is the change of the reference there, ``r_final - r_before``;
* **rise time**: from the first crossing of 10 % to the first crossing of 90 % of the step (after the event);
* **overshoot** [%]: the largest excursion beyond the final reference, in the step's direction, as a percentage
  of the step;
* **settling time**: time after the event from which ``|r - y|`` stays within the band for good; the band is
  `band` times ``|step|`` for a set-point step, the absolute `band_abs` when given, or `band_peak` times the
  peak error (the *recovery time* of a disturbance test);
* **IAE**: integral of ``|r - y|`` over the whole run (rectangle rule, samples held);
* **steady-state error**: ``|mean(r - y)|`` over the final `final_window` of the run (10 % by default);
  ``final_error_max`` is ``max |r - y|`` over the same window;
* **peak error**: ``max |r - y|`` after the event.

A figure that does not apply (no step: no rise time or overshoot; never settles) is NaN.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["response_metrics"]


def _first_crossing(t: np.ndarray, y: np.ndarray, level: float, direction: float) -> float:
    above = (y - level) * direction >= 0.0
    hits = np.flatnonzero(above)
    return float(t[hits[0]]) if hits.size else math.nan


def response_metrics(t: np.ndarray, y: np.ndarray, r: np.ndarray, *, t_event: float | None = None,
                     band: float = 0.02, band_abs: float | None = None, band_peak: float | None = None,
                     final_window: float = 0.1) -> dict[str, float]:
    """Step-response figures of output `y` following reference `r`, sampled at times `t`.

    Parameters
    ----------
    t, y, r : array_like
        Times [s], the output and its reference, same length.
    t_event : float, optional
        Time of the set-point change or disturbance the figures refer to. Default: the last change of `r`
        (or the start, where the step is taken from the output's initial value).
    band : float, default 0.02
        Settling band as a fraction of the step.
    band_abs : float, optional
        Settling band in the output's unit; overrides `band` (use it when the reference does not move).
    band_peak : float, optional
        Settling band as a fraction of the peak error after the event; overrides `band` and `band_abs`. With
        0.1 the settling time is the usual *recovery time* of a disturbance test.
    final_window : float, default 0.1
        Fraction of the run, at its end, over which the steady-state error is averaged.

    Returns
    -------
    dict
        ``rise_time``, ``settling_time``, ``overshoot_pct``, ``iae``, ``steady_state_error``,
        ``final_error_max``, ``peak_error``, ``step``.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0.0, 10.0, 10001)
    >>> y = 1.0 - np.exp(-t)          # first-order lag, time constant 1 s
    >>> m = response_metrics(t, y, np.ones_like(t), t_event=0.0)
    >>> round(m["rise_time"], 2), round(m["settling_time"], 2), m["overshoot_pct"]
    (2.2, 3.91, 0.0)
    """
    t, y, r = (np.asarray(v, dtype=float).reshape(-1) for v in (t, y, r))
    n = min(len(t), len(y), len(r))
    t, y, r = t[:n], y[:n], r[:n]
    out = dict.fromkeys(("rise_time", "settling_time", "overshoot_pct", "iae", "steady_state_error",
                         "final_error_max", "peak_error", "step"), math.nan)
    if n < 2:
        return out
    e = r - y
    dt = np.diff(t)
    out["iae"] = float(np.sum(np.abs(e[:-1]) * dt))
    tail = max(1, int(round(final_window * n)))
    out["steady_state_error"] = float(abs(np.mean(e[-tail:])))
    out["final_error_max"] = float(np.max(np.abs(e[-tail:])))
    if t_event is None:
        changes = np.flatnonzero(np.diff(r) != 0.0)
        t_event = float(t[changes[-1] + 1]) if changes.size else float(t[0])
    after = t >= t_event - 1e-12 * max(1.0, abs(t_event))
    if not np.any(after):
        return out
    k0 = int(np.argmax(after))
    r_before = float(r[k0 - 1]) if k0 > 0 else float(y[0])  # a step at the start goes from where y is
    r_final = float(r[-1])
    step = r_final - r_before
    out["step"] = step
    out["peak_error"] = float(np.max(np.abs(e[k0:])))
    ta, ya = t[k0:], y[k0:]
    # a reference still moving at the end (a ramp) has no final value to settle on or overshoot
    ramp = np.ptp(r[-tail:]) > 1e-12 * max(1.0, abs(r_final))
    if step != 0.0 and not ramp:
        direction = math.copysign(1.0, step)
        t10 = _first_crossing(ta, ya, r_before + 0.1 * step, direction)
        t90 = _first_crossing(ta, ya, r_before + 0.9 * step, direction)
        out["rise_time"] = t90 - t10
        out["overshoot_pct"] = float(max(0.0, np.max((ya - r_final) * direction)) / abs(step) * 100.0)
    width = band_abs if band_abs is not None else band * abs(step)
    if band_peak is not None:
        width = band_peak * out["peak_error"]
    if width > 0.0 and not ramp:
        outside = np.flatnonzero(np.abs(r_final - ya) > width)
        if outside.size == 0:
            out["settling_time"] = 0.0
        elif outside[-1] < len(ta) - 1:
            out["settling_time"] = float(ta[outside[-1] + 1] - t_event)
    return out


def jsonable_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """Metrics with NaN and infinities as None (JSON has neither)."""
    clean: dict[str, Any] = {}
    for key, value in metrics.items():
        if isinstance(value, float) and not math.isfinite(value):
            clean[key] = None
        elif isinstance(value, (np.floating, np.integer)):
            clean[key] = value.item() if math.isfinite(value) else None
        else:
            clean[key] = value
    return clean
