"""Module paths from before cosim's rooms still import, with a deprecation warning naming the new place.

Until version 0.1 the toolkit was one flat folder (``cosim.trajectory``, ``cosim.diagnosis``,
``cosim.identification``...). Those paths now live in the rooms (``cosim.data``, ``cosim.diagnose``,
``cosim.identify``...; see docs/architecture.md). A finder on ``sys.meta_path`` serves each old path as a small
module whose attributes are looked up in the new places, so that ``from cosim.diagnosis import diagnose``
keeps working and says where to import it from. Files on disk are not needed for this (no shim modules
clutter the rooms), and nothing is imported before an old path is asked for.

Examples
--------
>>> import warnings
>>> MOVED["cosim.trajectory"]
('cosim.data.trajectory',)
>>> with warnings.catch_warnings():
...     warnings.simplefilter("ignore")  # the first import says: cosim.trajectory has moved: import from ...
...     from cosim.trajectory import Trajectory
>>> import cosim.data.trajectory
>>> Trajectory is cosim.data.trajectory.Trajectory
True
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings
from collections.abc import Sequence
from typing import Any

from .errors import CosimDeprecationWarning

__all__ = ["MOVED", "install"]

#: Old module path -> the modules (or rooms) that hold its names now, searched in order.
MOVED: dict[str, tuple[str, ...]] = {
    "cosim.build": ("cosim.plant.build",),
    "cosim._compile": ("cosim.plant.toolchain",),
    "cosim.trajectory": ("cosim.data.trajectory",),
    "cosim.signals": ("cosim.data.signals",),
    "cosim.datafile": ("cosim.data.datafile", "cosim.data.derivatives"),
    "cosim.simulation": ("cosim.data.simulation",),
    "cosim.identification": ("cosim.identify.sindyc", "cosim.study.cases"),
    "cosim.model": ("cosim.identify.model",),
    "cosim.terms": ("cosim.identify.terms",),
    "cosim.output_error": ("cosim.identify.output_error",),
    "cosim.metrics": ("cosim.identify.metrics",),
    "cosim.residuals": ("cosim.diagnose.residuals",),
    "cosim.effects": ("cosim.diagnose.effects",),
    "cosim.screening": ("cosim.diagnose.screening",),
    "cosim.diagnosis": ("cosim.diagnose.diagnosis", "cosim.diagnose.candidates", "cosim.diagnose.diagnosis_report"),
    "cosim.closed_loop": ("cosim.loop.closed_loop",),
    "cosim.response": ("cosim.loop.response",),
    "cosim.validation": ("cosim.loop.validation",),
    "cosim.validation_report": ("cosim.loop.validation_report",),
    "cosim.reproduce": ("cosim.study.reproduce",),
    "cosim.sweep": ("cosim.study.sweep", "cosim.study.sweep_result"),
    "cosim.robustness": ("cosim.study.robustness",),
    "cosim.plots": ("cosim.figures", "cosim.data.plots", "cosim.loop.plots"),
    "controllers.pid_tuning": ("controllers.pid",),
    "controllers._qp_codegen": ("controllers.mpc._qp", "controllers.mpc._codegen"),
}


class _MovedModule(types.ModuleType):
    """An old module path: attributes come from the modules that hold them now."""

    def __init__(self, name: str, targets: Sequence[str]) -> None:
        super().__init__(name, f"Moved: import from {', '.join(targets)}.")
        self._targets = tuple(targets)

    def _modules(self) -> list[types.ModuleType]:
        return [importlib.import_module(t) for t in self._targets]

    def __getattr__(self, name: str) -> Any:
        if name == "__all__":
            return sorted({n for m in self._modules() for n in getattr(m, "__all__", ())})
        if name.startswith("__"):
            raise AttributeError(name)
        for module in self._modules():
            if hasattr(module, name):
                return getattr(module, name)
        raise AttributeError(f"module {self.__name__!r} (now {', '.join(self._targets)}) has no attribute {name!r}")

    def __dir__(self) -> list[str]:
        return sorted({n for m in self._modules() for n in dir(m)})


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old module paths of :data:`MOVED` (after every real finder has had its turn)."""

    def __init__(self, moved: dict[str, tuple[str, ...]]) -> None:
        self.moved = moved

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in self.moved:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        return _MovedModule(spec.name, self.moved[spec.name])

    def exec_module(self, module: types.ModuleType) -> None:
        new = " or ".join(t for t in self.moved[module.__name__] if "._" not in t)  # public places only
        _warn_caller(f"{module.__name__} has moved: import from {new} (the old path goes in a later release)")


def _warn_caller(message: str) -> None:
    """Warn as if from the import statement that asked for the old path (not from importlib's frames)."""
    frame = sys._getframe(1)
    while frame is not None and (frame.f_code.co_filename.startswith("<frozen importlib")
                                 or frame.f_code.co_filename == __file__):
        frame = frame.f_back
    if frame is None:
        warnings.warn(message, CosimDeprecationWarning, stacklevel=2)
        return
    module = frame.f_globals.get("__name__", "")
    registry = frame.f_globals.setdefault("__warningregistry__", {})
    warnings.warn_explicit(message, CosimDeprecationWarning, frame.f_code.co_filename, frame.f_lineno,
                           module=module, registry=registry)


def install(moved: dict[str, tuple[str, ...]] = MOVED) -> None:
    """Put the finder of the old paths at the end of ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) and f.moved is moved for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder(moved))
