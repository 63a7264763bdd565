"""The plant room: FMUs built from C source, opened and stepped.

* :mod:`~cosim.plant.build` - the bundled two-mass servo FMU (and any FMU source folder) compiled into a cached
  ``.fmu`` (:func:`build_fmu`), and a bundled system of FMUs (the servo split into a motor and a shaft-and-load
  FMU) packed into a cached ``.ssp`` (:func:`build_ssp`);
* :mod:`~cosim.plant.toolchain` - the C compiler, platform names and zip files every compiled artefact uses
  (the bundled FMU, an exported model FMU, the MPC's generated step);
* :mod:`~cosim.plant.model_description` - :func:`open_model_description`: an FMU file checked (a zip, FMI 2.0
  or 3.0, co-simulation or Model Exchange, a binary for this platform) and its modelDescription.xml read;
* :mod:`~cosim.plant.fmu_plant` - :class:`FmuPlant`, one FMI 2.0/3.0 FMU stepped at a fixed sample time
  (signals of every numeric type and FMI 3 array elements named in :mod:`~cosim.plant._variables`, the step in
  :mod:`~cosim.plant._stepping`, values set and read by type in :mod:`~cosim.plant._fmi_calls`, FMI 2.0
  messages logged through :mod:`~cosim.plant._fmi_callbacks`);
* :mod:`~cosim.plant.model_exchange` - :class:`~cosim.plant.model_exchange.ModelExchangeSlave`, a Model
  Exchange FMU integrated by FMPy's CVode or Euler behind a co-simulation slave's calls;
* :mod:`~cosim.plant.system_structure` - :class:`System`, a plant of several FMUs described (read from SSP 1.0,
  OSP or written in Python: :func:`read_system`), checked against its FMUs by
  :mod:`~cosim.plant.system_wiring`, and run by :class:`SystemPlant` (:mod:`~cosim.plant.system_plant`: a
  Jacobi or Gauss-Seidel master with input extrapolation).

The lowest room: it imports only the foundation (:mod:`cosim.errors`, :mod:`cosim.files`).
"""

from __future__ import annotations

from .build import build_fmu, build_ssp, fmu_cache_dir, fmu_source_dir
from .fmu_plant import FmuPlant
from .model_description import open_model_description
from .system_plant import SystemPlant
from .system_structure import Component, Connection, System, read_system

__all__ = [
    "Component", "Connection", "FmuPlant", "System", "SystemPlant", "build_fmu", "build_ssp", "fmu_cache_dir",
    "fmu_source_dir", "open_model_description", "read_system",
]
