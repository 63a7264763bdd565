"""The export room: an :class:`~cosim.identify.model.IdentifiedModel` for other tools.

* :func:`to_statespace` - a named python-control ``StateSpace`` (linearised at an :func:`operating_point` when
  the model is nonlinear, continuous or ZOH-discrete);
* :func:`export_mat` - MATLAB ``.mat`` matrices; :func:`export_fmu` - an FMI 2.0 co-simulation FMU compiled
  from generated C; :func:`export` - one of them by file suffix.

Imports the identify room and below.
"""

from __future__ import annotations

import sys
import types
from typing import Any

from .core import (
    CONSTANT_INPUT,
    CONSTANT_MODES,
    OperatingPoint,
    export,
    export_fmu,
    export_mat,
    operating_point,
    to_statespace,
)

__all__ = [
    "CONSTANT_INPUT", "CONSTANT_MODES", "OperatingPoint", "export", "export_fmu", "export_mat", "operating_point",
    "to_statespace",
]


class _ExportRoom(types.ModuleType):
    """The room is also the function: ``cosim.export(model, "model.fmu")`` keeps working.

    Before the rooms, ``cosim.export`` was both a module and (from ``cosim``) the function :func:`export`;
    once the module loads, Python binds the name ``cosim.export`` to it, so the room answers calls itself.
    """

    def __call__(self, model: Any, path: Any, **options: Any) -> Any:
        return export(model, path, **options)


sys.modules[__name__].__class__ = _ExportRoom
