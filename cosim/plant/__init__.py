"""The plant room: FMUs built from C source, opened and stepped.

* :mod:`~cosim.plant.build` - the bundled two-mass servo FMU (and any FMU source folder) compiled into a cached
  ``.fmu`` (:func:`build_fmu`);
* :mod:`~cosim.plant.toolchain` - the C compiler, platform names and zip files every compiled artefact uses
  (the bundled FMU, an exported model FMU, the MPC's generated step);
* :mod:`~cosim.plant.model_description` - :func:`open_model_description`: an FMU file checked (a zip, FMI 2.0
  or 3.0, co-simulation, a binary for this platform) and its modelDescription.xml read;
* :mod:`~cosim.plant.fmu_plant` - :class:`FmuPlant`, one FMI 2.0/3.0 co-simulation FMU stepped at a fixed
  sample time (its values set and read by type in :mod:`~cosim.plant._fmi_calls`, its FMI 2.0 messages
  logged through :mod:`~cosim.plant._fmi_callbacks`).

The lowest room: it imports only the foundation (:mod:`cosim.errors`, :mod:`cosim.files`).
"""

from __future__ import annotations

from .build import build_fmu, fmu_cache_dir, fmu_source_dir
from .fmu_plant import FmuPlant
from .model_description import open_model_description

__all__ = [
    "FmuPlant", "build_fmu", "fmu_cache_dir", "fmu_source_dir", "open_model_description",
]
