"""cosim: identify, diagnose and control real machines, with the plant as an FMU.

The toolkit is a house with a room per pipeline stage, and imports flow one way, from the apps down to the
plant (docs/architecture.md draws the arrows):

* :mod:`cosim.plant` - FMUs built from C (:func:`build_fmu`) and stepped (:class:`FmuPlant`), systems of FMUs
  (SSP, OSP or :class:`System`) run by a co-simulation master (:class:`SystemPlant`);
* :mod:`cosim.data` - records (:class:`Trajectory`), measured files, excitation :mod:`~cosim.data.signals`,
  FMU simulation (:func:`simulate`);
* :mod:`cosim.identify` - SINDYc (:class:`SINDYc`) and the :class:`IdentifiedModel`;
* :mod:`cosim.export` - python-control ``StateSpace`` (:func:`to_statespace`), MATLAB and FMI files;
* :mod:`cosim.diagnose` - the residual of a model traced to the effect it lacks;
* :mod:`cosim.loop` - closed loops against the FMU, validation (:func:`validate`, :class:`Verdict`);
* :mod:`cosim.study` - sweeps (:func:`run_sweep`), robustness, the reference study (:func:`reproduce_paper`);
* :mod:`cosim.cli` and :mod:`cosim.demo` - the ``cosim`` command and the main job.

What every room uses sits beside them: :mod:`cosim.errors`, :mod:`cosim.files` (atomic writes),
:mod:`cosim.numbers`, :mod:`cosim.report` (HTML) and :mod:`cosim.figures` (PNG).

``import cosim`` loads the plant and data rooms only; the names of the heavier rooms below are imported on
first use, so that the command line and sweep workers start quickly. Inside those two rooms, too, pandas,
scipy, pyarrow, fmpy and tqdm are imported by the functions that use them (``tests/test_light_imports.py``
checks the heaviest). Module paths of the flat layout before the rooms (``cosim.diagnosis``,
``cosim.trajectory``...) still import, with a :class:`~cosim.errors.CosimDeprecationWarning` naming the new place.
"""

import logging
from typing import TYPE_CHECKING

from . import _moved
from .data import signals
from .data.simulation import simulate
from .data.trajectory import Trajectory
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
    SimulationTerminated,
    SpecError,
    UnknownVariableError,
)
from .plant.build import build_fmu, fmu_cache_dir
from .plant.fmu_plant import FmuPlant
from .plant.model_description import open_model_description
from .plant.system_plant import SystemPlant
from .plant.system_structure import System, read_system

__version__ = "0.1.0"

if TYPE_CHECKING:
    # The lazy names of _LAZY, from the modules that define them, so that IDEs and type checkers see them; never
    # imported at runtime (``__getattr__`` below does that on first use). ``X as X`` marks a re-export (PEP 484).
    # tests/test_public_api.py checks that this block and _LAZY name the same objects.
    from .diagnose.residuals import ResidualAnalysis as ResidualAnalysis
    from .export import export as export
    from .export.statespace import to_statespace as to_statespace
    from .identify.compare import Comparison as Comparison
    from .identify.compare import compare as compare
    from .identify.model import IdentifiedModel as IdentifiedModel
    from .identify.model import SimulationResult as SimulationResult
    from .identify.sindyc import SINDYc as SINDYc
    from .loop.closed_loop import ClosedLoopResult as ClosedLoopResult
    from .loop.validation import Verdict as Verdict
    from .loop.validation import validate as validate
    from .study.reproduce import reproduce_paper as reproduce_paper
    from .study.sweep import run_sweep as run_sweep
    from .study.sweep_result import SweepResult as SweepResult

_LAZY = {  # name -> the room that exports it
    "SINDYc": "identify",
    "IdentifiedModel": "identify",
    "SimulationResult": "identify",
    "compare": "identify",
    "Comparison": "identify",
    "to_statespace": "export",
    "export": "export",
    "run_sweep": "study",
    "SweepResult": "study",
    "reproduce_paper": "study",
    "ResidualAnalysis": "diagnose",
    "ClosedLoopResult": "loop",
    "validate": "loop",
    "Verdict": "loop",
}


def __getattr__(name: str):
    """Import the heavier rooms on first use (PEP 562)."""
    if name in _LAZY:
        import importlib

        module = importlib.import_module(f".{_LAZY[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module 'cosim' has no attribute {name!r}")


# the old flat module paths, served on demand from the rooms (see cosim._moved)
_moved.install()

# A library logs, the application decides where to: FMUs' messages go to logger "cosim.fmu".
logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "BuildError",
    "ControllerError",
    "CosimError",
    "DataError",
    "FmiCallError",
    "SimulationTerminated",
    "FmuFormatError",
    "FmuNotFoundError",
    "FmuPlant",
    "FmuPlatformError",
    "InvalidSettingError",
    "SignalSpecError",
    "SpecError",
    "System",
    "SystemPlant",
    "Trajectory",
    "UnknownVariableError",
    "build_fmu",
    "fmu_cache_dir",
    "open_model_description",
    "read_system",
    "signals",
    "simulate",
    *_LAZY,
]
