"""cosim: identify, diagnose and control real machines, with the plant as an FMU.

Pipeline stages, one module each: ``build`` (FMUs from C source), ``plant`` (:class:`FmuPlant`),
``signals`` (excitations), ``trajectory`` (:class:`Trajectory`), ``simulation`` (:func:`simulate`).
"""

import logging

from . import signals
from .build import build_fmu, fmu_cache_dir
from .errors import (
    BuildError,
    CosimError,
    DataError,
    FmiCallError,
    FmuFormatError,
    FmuNotFoundError,
    FmuPlatformError,
    InvalidSettingError,
    SignalSpecError,
    UnknownVariableError,
)
from .plant import FmuPlant, open_model_description
from .simulation import simulate
from .trajectory import Trajectory

__version__ = "0.1.0"

# A library logs, the application decides where to: FMUs' messages go to logger "cosim.fmu".
logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "BuildError",
    "CosimError",
    "DataError",
    "FmiCallError",
    "FmuFormatError",
    "FmuNotFoundError",
    "FmuPlant",
    "FmuPlatformError",
    "InvalidSettingError",
    "SignalSpecError",
    "Trajectory",
    "UnknownVariableError",
    "build_fmu",
    "fmu_cache_dir",
    "open_model_description",
    "signals",
    "simulate",
]
