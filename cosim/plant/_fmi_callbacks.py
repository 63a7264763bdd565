"""The callbacks an FMI 2.0 instance is given: one process-wide logger that hands each message to its plant.

FMI 3.0 instances take a plain Python function for their messages (see ``FmuPlant._load``); FMI 2.0 ones take a
C structure of callbacks, built here by :func:`fmi2_callbacks`.
"""

from __future__ import annotations

import ctypes
import itertools
import weakref
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .fmu_plant import FmuPlant


# FMPy's C logger proxy keeps ONE process-wide pointer to the Python logger it forwards to. A logger per plant
# would leave that pointer dangling once the plant is gone (and route every FMU's messages to the last plant).
# So there is one logger for the process, never freed, which finds the plant by the componentEnvironment
# pointer it was instantiated with, and falls back to FMPy's own printer for FMUs that are not ours.
_PLANTS: weakref.WeakValueDictionary[int, FmuPlant] = weakref.WeakValueDictionary()
_NEXT_ID = itertools.count(1)
_LOGGER: list[Any] = []


def _register(plant: FmuPlant) -> int:
    key = next(_NEXT_ID)
    _PLANTS[key] = plant
    return key


def _fmi2_logger() -> Any:
    if not _LOGGER:
        import fmpy  # imported when an FMU is loaded, not with cosim
        from fmpy.fmi1 import printLogMessage

        def dispatch(env, instance, status, category, message):
            plant = _PLANTS.get(env) if env else None
            if plant is not None:
                plant._on_log(status, category, message)
            else:
                printLogMessage(env, instance, status, category, message)

        _LOGGER.append(fmpy.fmi2.fmi2CallbackLoggerTYPE(dispatch))
    return _LOGGER[0]


def fmi2_callbacks(plant: FmuPlant) -> Any:
    """The ``fmi2CallbackFunctions`` to instantiate `plant`'s FMU with: its messages go to ``plant._on_log``.

    The caller keeps the structure for the instance's life (FMPy passes a pointer to it).
    """
    import fmpy

    callbacks = fmpy.fmi2.fmi2CallbackFunctions()
    callbacks.logger = _fmi2_logger()
    callbacks.allocateMemory = fmpy.fmi2.fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
    callbacks.freeMemory = fmpy.fmi2.fmi2CallbackFreeMemoryTYPE(fmpy.free)
    callbacks.componentEnvironment = _register(plant)
    try:  # FMPy's C proxy formats printf-style arguments of the message
        from fmpy.logging import addLoggerProxy
        addLoggerProxy(ctypes.byref(callbacks))
    except Exception:  # without it, messages arrive unformatted: still readable
        pass
    return callbacks
