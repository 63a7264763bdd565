"""Errors raised by cosim.

Every error derives from :class:`CosimError` and also from the builtin it refines, so
``except ValueError`` keeps working. Messages are one line: what was wrong, what was
expected, and what to do.
"""

from __future__ import annotations

__all__ = [
    "CosimError",
    "FmuNotFoundError",
    "FmuFormatError",
    "FmuPlatformError",
    "UnknownVariableError",
    "InvalidSettingError",
    "FmiCallError",
    "DataError",
    "SignalSpecError",
    "BuildError",
    "ControllerError",
    "SpecError",
    "CosimDeprecationWarning",
]


class CosimError(Exception):
    """Base class of every error cosim raises on purpose."""


class FmuNotFoundError(CosimError, FileNotFoundError):
    """A path that should hold an FMU or a data file does not exist."""

    def __str__(self) -> str:  # FileNotFoundError would print errno fields
        return str(self.args[0]) if self.args else ""


class FmuFormatError(CosimError, ValueError):
    """A file is not a usable FMU: not a zip, no modelDescription.xml, no co-simulation."""


class FmuPlatformError(CosimError, RuntimeError):
    """The FMU has no binary for this platform, or the binary cannot be loaded."""


class UnknownVariableError(CosimError, LookupError):
    """A variable, parameter or column name that the FMU or data file does not have."""


class InvalidSettingError(CosimError, ValueError):
    """A setting out of its range, for instance a non-positive step size."""


class FmiCallError(CosimError, RuntimeError):
    """An FMI function returned an error status.

    Attributes
    ----------
    function : str
        Name of the FMI function that failed, e.g. ``"fmi2DoStep"``.
    status : int
        The FMI status it returned (2 warning... 3 discard, 4 error, 5 fatal for FMI 2).
    time : float or None
        Simulation time of the failing call, when known.
    """

    def __init__(self, message: str, *, function: str, status: int, time: float | None = None):
        super().__init__(message)
        self.function = function
        self.status = status
        self.time = time


class DataError(CosimError, ValueError):
    """A data file or array is unusable: NaN, non-monotonic time, missing columns..."""


class SignalSpecError(CosimError, ValueError):
    """An excitation signal specification such as ``square:amp=0.1,freq=2`` is malformed."""


class BuildError(CosimError, RuntimeError):
    """Building an FMU from C source failed (no compiler, or the compiler reported errors)."""


class ControllerError(CosimError, RuntimeError):
    """A controller cannot be designed as asked, or failed while running (its message says when and why)."""


class SpecError(CosimError, ValueError):
    """A closed-loop scenario or specification such as ``settling_time<=0.5`` is malformed."""


class CosimDeprecationWarning(DeprecationWarning):
    """A name or module path that still works but has moved or changed; the message says what to use."""
