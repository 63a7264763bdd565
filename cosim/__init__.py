"""cosim: identify, diagnose and control real machines, with the plant as an FMU.

Pipeline stages, one module each: ``build`` (FMUs from C source), ``plant`` (:class:`FmuPlant`),
``signals`` (excitations), ``trajectory`` (:class:`Trajectory`), ``simulation`` (:func:`simulate`),
``identification`` (:class:`SINDYc`), ``model`` (:class:`IdentifiedModel`), ``metrics``, ``export``
(python-control, MATLAB, FMI), ``sweep`` (:func:`run_sweep`), ``reproduce`` (the reference study), ``report``.

The heavier stages (identification, export, sweep) are imported on first use, so that ``import cosim`` stays
quick for worker processes.
"""

import logging

from . import signals
from .build import build_fmu, fmu_cache_dir
from .errors import (
    BuildError,
    ControllerError,
    CosimError,
    DataError,
    FmiCallError,
    FmuFormatError,
    FmuNotFoundError,
    FmuPlatformError,
    InvalidSettingError,
    SignalSpecError,
    SpecError,
    UnknownVariableError,
)
from .plant import FmuPlant, open_model_description
from .simulation import simulate
from .trajectory import Trajectory

__version__ = "0.1.0"

_LAZY = {
    "SINDYc": "identification",
    "IdentifiedModel": "model",
    "SimulationResult": "model",
    "to_statespace": "export",
    "export": "export",
    "run_sweep": "sweep",
    "SweepResult": "sweep",
    "reproduce_paper": "reproduce",
    "ResidualAnalysis": "residuals",
    "ClosedLoopResult": "closed_loop",
    "validate": "validation",
    "Verdict": "validation",
}


def __getattr__(name: str):
    """Import the heavier stages on first use (PEP 562)."""
    if name in _LAZY:
        import importlib

        module = importlib.import_module(f".{_LAZY[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module 'cosim' has no attribute {name!r}")

# A library logs, the application decides where to: FMUs' messages go to logger "cosim.fmu".
logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "BuildError",
    "ControllerError",
    "CosimError",
    "DataError",
    "FmiCallError",
    "FmuFormatError",
    "FmuNotFoundError",
    "FmuPlant",
    "FmuPlatformError",
    "InvalidSettingError",
    "SignalSpecError",
    "SpecError",
    "Trajectory",
    "UnknownVariableError",
    "build_fmu",
    "fmu_cache_dir",
    "open_model_description",
    "signals",
    "simulate",
    *_LAZY,
]
