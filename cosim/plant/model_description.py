"""Opening a plant's description (:func:`open_model_description`): one FMU's modelDescription.xml
(:mod:`cosim.plant._fmu_description`), or a system of FMUs described as one FMU
(:func:`cosim.plant.system_wiring.description`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from ._fmu_description import KINDS, interface_kind, parameter_names, variable_unit
from ._fmu_description import open_model_description as _open_fmu

if TYPE_CHECKING:
    from fmpy.model_description import ModelDescription

__all__ = ["KINDS", "interface_kind", "open_model_description", "parameter_names", "variable_unit"]


def open_model_description(fmu: str | os.PathLike, kind: str | None = None) -> ModelDescription:
    """Check that `fmu` is a usable FMU for this platform and return its model description; or, for a system of
    FMUs (``.ssp``, ``SystemStructure.ssd``, an OSP ``...SystemStructure.xml``), the system described as one FMU
    whose variables are ``component.variable`` (its components checked the same way).

    Parameters
    ----------
    fmu : path-like
        The ``.fmu`` file, or the system's file.
    kind : {"cs", "me"}, optional
        The interface to check of one FMU (see :func:`interface_kind`); default: co-simulation, else Model
        Exchange.

    Returns
    -------
    fmpy.model_description.ModelDescription

    Raises
    ------
    FmuNotFoundError, FmuFormatError, FmuPlatformError
        With a one-line message saying what is wrong and what to do.

    Examples
    --------
    >>> from cosim import build_fmu
    >>> open_model_description(build_fmu()).coSimulation.modelIdentifier
    'two_mass_servo'
    """
    from .system_structure import is_system_file

    if is_system_file(Path(fmu)):
        from .system_structure import read_system
        from .system_wiring import description, wire

        return description(wire(read_system(fmu)))
    return _open_fmu(fmu, kind)
