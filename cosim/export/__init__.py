"""The export room: an :class:`~cosim.identify.model.IdentifiedModel` for other tools.

* :mod:`~cosim.export.statespace` - :func:`to_statespace`, a named python-control ``StateSpace`` (linearised at an
  :func:`operating_point` when the model is nonlinear, continuous or ZOH-discrete), and what becomes of the
  model's constant term; :mod:`~cosim.export.jacobian` - the analytic Jacobian it linearises with;
* :mod:`~cosim.export.matlab` - :func:`export_mat`, MATLAB ``.mat`` matrices;
* :mod:`~cosim.export.fmu` - :func:`export_fmu`, an FMI 2.0 co-simulation FMU compiled from generated C;
* :func:`export` - one of them (or the model's JSON) by file suffix. The room is also that function:
  ``cosim.export(model, "model.fmu")``.

Imports the identify room and below.
"""

from __future__ import annotations

import os
import sys
import types
from pathlib import Path
from typing import Any

from ..errors import InvalidSettingError
from ..identify.model import IdentifiedModel
from .fmu import export_fmu
from .matlab import export_mat
from .statespace import (
    CONSTANT_INPUT,
    CONSTANT_MODES,
    OperatingPoint,
    control_label,
    label_name,
    operating_point,
    to_statespace,
)

__all__ = [
    "CONSTANT_INPUT", "CONSTANT_MODES", "OperatingPoint", "control_label", "export", "export_fmu", "export_mat",
    "label_name", "operating_point", "to_statespace",
]


_EXPORTERS = (".mat", ".fmu", ".json")


def export(model: IdentifiedModel, path: str | os.PathLike, **options: Any) -> Path:
    """Export by file suffix: ``.mat`` (:func:`export_mat`), ``.fmu`` (:func:`export_fmu`), ``.json``
    (:meth:`IdentifiedModel.save`, no options).

    Parameters
    ----------
    model : IdentifiedModel
    path : path-like
    **options
        Keyword options of the chosen exporter.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-1.0]]))
    >>> export(model, pathlib.Path(tempfile.mkdtemp()) / "model.json").suffix
    '.json'
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return export_mat(model, path, **options)
    if suffix == ".fmu":
        return export_fmu(model, path, **options)
    if suffix == ".json":
        if options:
            raise InvalidSettingError(f"a .json export takes no options, got {', '.join(options)}; it saves the "
                                      "model as it is")
        return model.save(path)
    raise InvalidSettingError(f"cannot export to {path.name!r}: unknown suffix {path.suffix or '(none)'!r}; "
                              f"use one of {', '.join(_EXPORTERS)}")


class _ExportRoom(types.ModuleType):
    """The room is also the function: ``cosim.export(model, "model.fmu")`` keeps working.

    Before the rooms, ``cosim.export`` was both a module and (from ``cosim``) the function :func:`export`;
    once the module loads, Python binds the name ``cosim.export`` to it, so the room answers calls itself.
    """

    def __call__(self, model: Any, path: Any, **options: Any) -> Any:
        return export(model, path, **options)


sys.modules[__name__].__class__ = _ExportRoom
