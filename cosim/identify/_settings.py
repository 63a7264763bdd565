"""The settings of :class:`~cosim.identify.sindyc.SINDYc`: the values each one accepts, and their checks.

:func:`_check_settings` raises :class:`~cosim.errors.InvalidSettingError` naming the setting, what it accepts
and the value given; :func:`_check_number` and :func:`_check_mapping` check one value (the study room checks
its own arguments with :func:`_check_number` too). :data:`DIFFERENTIATION_METHODS` is public, from
:mod:`cosim.identify.sindyc`.

Examples
--------
>>> _check_number("window", 2, low=3, integer=True)
Traceback (most recent call last):
...
cosim.errors.InvalidSettingError: window must be an integer >= 3, got 2
>>> _check_mapping("kinematics", {"theta_m": "omega_m"})
{'theta_m': 'omega_m'}
>>> _kinematics_setting(None), _kinematics_setting("auto")
('none', 'auto')
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any

from ..errors import InvalidSettingError
from .terms import Term

_PYSINDY_KINDS = ("savitzky_golay", "spline", "kalman", "trend_filtered", "spectral", "kernel")
#: Names accepted by ``differentiation`` (and ``velocity_method``, except "integral" and "zoh").
DIFFERENTIATION_METHODS = ("integral", "zoh", "finite_difference", "smoothed_finite_difference") + _PYSINDY_KINDS
_LIBRARIES = ("linear", "polynomial")
_REFINE = (None, "output_error")


def _check_number(name: str, value: Any, *, low: float | None = None, integer: bool = False,
                  allow_zero: bool = True) -> None:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))
    if ok and integer:
        ok = float(value).is_integer()
    if ok and low is not None:
        ok = value >= low if allow_zero else value > low
    if not ok:
        kind = "an integer" if integer else "a finite number"
        bound = "" if low is None else f" {'>=' if allow_zero else '>'} {low}"
        raise InvalidSettingError(f"{name} must be {kind}{bound}, got {value!r}")


def _check_mapping(name: str, value: Any) -> dict[str, str]:
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and isinstance(v, str)
                                                 for k, v in value.items()):
        raise InvalidSettingError(f"{name} must map names to names, e.g. {{'theta_m': 'omega_m'}}, got {value!r}")
    return dict(value)


def _kinematics_setting(value: Any) -> str | dict[str, str]:
    """``kinematics=`` as "auto" (detect), "none" (off: None too) or a checked mapping position -> velocity."""
    if value is None or (isinstance(value, str) and value.lower() == "none"):
        return "none"
    if isinstance(value, str):
        if value.lower() == "auto":
            return "auto"
        raise InvalidSettingError(f"kinematics must be 'auto', 'none' (or None) or a mapping such as "
                                  f"{{'theta_m': 'omega_m'}}, got {value!r}")
    return _check_mapping("kinematics", value)


def _check_settings(est: Any) -> None:
    """Check the settings of `est`, a :class:`~cosim.identify.sindyc.SINDYc` (its attributes, as given)."""
    if est.library not in _LIBRARIES:
        raise InvalidSettingError(f"library must be one of {', '.join(_LIBRARIES)}, got {est.library!r}")
    _check_number("degree", est.degree, low=1, integer=True)
    for term in est.terms:
        if not isinstance(term, str):
            raise InvalidSettingError(f"terms must be expression strings such as 'omega_m*Tm', got {term!r}")
        Term(term)  # raises InvalidSettingError with the reason
    if not isinstance(est.include_constant, bool):
        raise InvalidSettingError(f"include_constant must be True or False, got {est.include_constant!r}")
    if est.threshold != "auto":
        if isinstance(est.threshold, str):
            raise InvalidSettingError(f"threshold must be a number >= 0 or 'auto', got {est.threshold!r}")
        _check_number("threshold", est.threshold, low=0.0)
    _check_number("ridge", est.ridge, low=0.0)
    if est.differentiation not in DIFFERENTIATION_METHODS:
        raise InvalidSettingError(f"unknown differentiation {est.differentiation!r}; choose one of "
                                  f"{', '.join(DIFFERENTIATION_METHODS)}")
    if est.differentiation == "integral":
        extra = set(est.differentiation_options) - {"window"}
        if extra:
            raise InvalidSettingError(f"differentiation 'integral' takes the option 'window' only, got "
                                      f"{', '.join(sorted(extra))}")
        _check_number("window", est.differentiation_options.get("window", 30), low=3, integer=True)
    elif est.differentiation == "zoh" and est.differentiation_options:
        raise InvalidSettingError("differentiation 'zoh' takes no options")
    if not isinstance(est.noise_compensation, bool):
        raise InvalidSettingError(f"noise_compensation must be True or False, got {est.noise_compensation!r}")
    _kinematics_setting(est.kinematics)
    _check_mapping("velocities", est.velocities)
    if est.velocity_method != "auto" and est.velocity_method not in DIFFERENTIATION_METHODS[2:]:
        raise InvalidSettingError(f"velocity_method must be 'auto' or a differentiator, one of "
                                  f"{', '.join(DIFFERENTIATION_METHODS[2:])}; got {est.velocity_method!r}")
    if est.velocity_method == "auto" and est.velocity_options:
        raise InvalidSettingError("velocity_method 'auto' takes no velocity_options; give derive_window=N to fix "
                                  "its window")
    if est.derive_window is not None:
        _check_number("derive_window", est.derive_window, low=5, integer=True)
        if int(est.derive_window) % 2 == 0:
            raise InvalidSettingError(f"derive_window must be odd (samples centred on the point), got "
                                      f"{est.derive_window!r}")
        if est.velocity_method != "auto":
            raise InvalidSettingError(f"derive_window sets the window of velocity_method 'auto'; with "
                                      f"{est.velocity_method!r} give velocity_options instead")
    if est.decimate != "auto" and (isinstance(est.decimate, bool) or not isinstance(est.decimate, numbers.Integral)
                                   or est.decimate < 1):
        raise InvalidSettingError(f'decimate must be "auto" or a positive integer, got {est.decimate!r}')
    if not isinstance(est.allow_unstable, bool):
        raise InvalidSettingError(f"allow_unstable must be True or False, got {est.allow_unstable!r}")
    if est.prefer_stable is not None and not isinstance(est.prefer_stable, bool):
        raise InvalidSettingError(f"prefer_stable must be True, False or None, got {est.prefer_stable!r}")
    if est.refine not in _REFINE:
        raise InvalidSettingError(f"refine must be None or 'output_error', got {est.refine!r}")
    if not isinstance(est.refine_initial_state, bool):
        raise InvalidSettingError("refine_initial_state must be True or False")
    extra = set(est.refine_options) - {"prior", "continuation", "max_nfev", "exact_jacobian", "stability_limit"}
    if extra:
        raise InvalidSettingError(f"unknown refine_options {', '.join(sorted(extra))}; valid: prior, "
                                  "continuation, max_nfev, exact_jacobian, stability_limit")
    limit = est.refine_options.get("stability_limit")
    if limit is not None and not (isinstance(limit, (int, float)) and not isinstance(limit, bool)
                                  and math.isfinite(limit) and limit > 0):
        raise InvalidSettingError(f"refine_options stability_limit must be a positive number (1/s), got {limit!r}")


#: The settings of ``SINDYc()`` (its ``repr`` shows the others).
_DEFAULTS = {"library": "linear", "degree": 2, "terms": [], "include_constant": True, "threshold": "auto",
             "ridge": 0.0, "differentiation": "integral", "differentiation_options": {}, "noise_compensation": True,
             "kinematics": "auto", "velocities": {}, "velocity_method": "auto", "velocity_options": {},
             "derive_window": None, "refine": "output_error", "refine_initial_state": True, "refine_options": {},
             "allow_unstable": False, "decimate": "auto", "prefer_stable": None}
