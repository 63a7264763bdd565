"""Errors raised by cosim.

Every error derives from :class:`CosimError` and also from the builtin it refines, so
``except ValueError`` keeps working. Messages are one line: what was wrong, what was
expected, and what to do.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "CosimError",
    "FmuNotFoundError",
    "FmuFormatError",
    "FmuPlatformError",
    "UnknownVariableError",
    "InvalidSettingError",
    "FmiCallError",
    "SimulationTerminated",
    "DataError",
    "SignalSpecError",
    "BuildError",
    "ControllerError",
    "SpecError",
    "UnstableModelError",
    "CosimDeprecationWarning",
    "IdentificationWarning",
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


class SimulationTerminated(CosimError):
    """The FMU ended the simulation itself (fmi2Discard with fmi2Terminated, FMI 3 terminateSimulation).

    Not a failure: :func:`cosim.simulate` keeps everything up to :attr:`time` and says
    ``status: "terminated"``. Raised by :meth:`FmuPlant.step` with the outputs read at that time.

    Attributes
    ----------
    time : float
        When the FMU ended the simulation [s].
    message : str
        The FMU's last log message ("" if it logged none).
    outputs : numpy.ndarray or None
        The outputs at `time`, in the plant's output order.
    """

    def __init__(self, text: str, *, time: float, message: str = "", outputs: Any = None) -> None:
        super().__init__(text)
        self.time = time
        self.message = message
        self.outputs = outputs


class DataError(CosimError, ValueError):
    """A data file or array is unusable: NaN, non-monotonic time, missing columns..."""


class SignalSpecError(CosimError, ValueError):
    """An excitation signal specification such as ``square:amp=500,freq=2`` is malformed."""


class BuildError(CosimError, RuntimeError):
    """Building an FMU from C source failed (no compiler, or the compiler reported errors)."""


class ControllerError(CosimError, RuntimeError):
    """A controller cannot be designed as asked, or failed while running (its message says when and why)."""


class SpecError(CosimError, ValueError):
    """A closed-loop scenario or specification such as ``settling_time<=0.5`` is malformed."""


class UnstableModelError(CosimError, ValueError):
    """An identified model is unstable where the plant that gave the data cannot be (it grows in a free run).

    A ``ValueError``, as :class:`DataError` is: the fit ran, but the data and settings it was given do not
    support a usable model (too short or too weakly exciting a record, too much noise for the equation error,
    kinematics not pinned), and ``except ValueError`` around a fit catches bad data of every kind.

    Attributes
    ----------
    model : object
        The unstable model, for inspection (an :class:`~cosim.identify.model.IdentifiedModel`).
    eigenvalues : list of complex
        Its eigenvalues, largest real part first (empty for a nonlinear model).
    """

    #: ``cosim`` exits with status 1 (the result does not meet what was asked), not 2 (bad input).
    exit_status = 1

    def __init__(self, message: str, *, model: object = None, eigenvalues: list | None = None):
        super().__init__(message)
        self.model = model
        self.eigenvalues = list(eigenvalues or [])


class IdentificationWarning(UserWarning):
    """Something about the data or the identified model that the user should know (cosim warning)."""


class CosimDeprecationWarning(DeprecationWarning):
    """A name or module path that still works but has moved or changed; the message says what to use."""
