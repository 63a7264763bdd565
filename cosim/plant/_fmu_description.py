"""Opening one FMU: the file checked and its modelDescription.xml read (:func:`open_model_description`), behind
:mod:`cosim.plant.model_description`, which also describes a system of FMUs as one (the system room opens its
components here, so that the two never import each other).

:func:`open_model_description` tells in one line what makes a file unusable (missing, not a zip, no model
description, an FMI version or interface cosim does not drive, no binary for this platform) before anything is
extracted or loaded. :func:`_close_matches` is the hint given with an unknown variable name.
"""

from __future__ import annotations

import difflib
import os
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import FmuFormatError, FmuNotFoundError, FmuPlatformError, InvalidSettingError

if TYPE_CHECKING:
    from fmpy.model_description import ModelDescription

__all__ = ["KINDS", "interface_kind", "open_model_description", "parameter_names", "variable_unit"]

#: The FMI interfaces cosim drives: co-simulation (the FMU integrates itself) and Model Exchange (FMPy's solvers).
KINDS = ("cs", "me")
_KIND_NAMES = {"cs": "co-simulation", "me": "Model Exchange"}


def interface_kind(md: ModelDescription, kind: str | None = None) -> str:
    """The interface an FMU is driven through: `kind` if the FMU has it, else co-simulation first, then Model
    Exchange. FmuFormatError (one line) when it has neither, or not the one asked for.

    Examples
    --------
    >>> from cosim import build_fmu
    >>> interface_kind(open_model_description(build_fmu()))
    'cs'
    """
    has = {"cs": md.coSimulation is not None, "me": md.modelExchange is not None}
    if kind is not None:
        if kind not in KINDS:
            raise InvalidSettingError(f"kind={kind!r}; choose cs (co-simulation) or me (Model Exchange)")
        if not has[kind]:
            other = [k for k in KINDS if has[k]]
            hint = f"; use --kind {other[0]}" if other else ""
            raise FmuFormatError(f"{md.modelName} has no {_KIND_NAMES[kind]} interface (it has "
                                 f"{', '.join(_KIND_NAMES[k] for k in other) or 'neither'}){hint}")
        return kind
    for k in KINDS:
        if has[k]:
            return k
    scheduled = getattr(md, "scheduledExecution", None) is not None
    what = "only Scheduled Execution" if scheduled else "no interface at all"
    raise FmuFormatError(f"{md.modelName} has neither a co-simulation nor a Model Exchange interface ({what}); "
                         "cosim steps co-simulation FMUs and integrates Model Exchange ones: re-export it with one")


def open_model_description(fmu: str | os.PathLike, kind: str | None = None) -> ModelDescription:
    """Check that `fmu` is a usable FMU for this platform and return its model description.

    Parameters
    ----------
    fmu : path-like
        Path of the ``.fmu`` file.
    kind : {"cs", "me"}, optional
        The interface to check (see :func:`interface_kind`); default: co-simulation, else Model Exchange.

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
    path = Path(fmu)
    if not path.exists():
        raise FmuNotFoundError(f"FMU not found: {path}; check the path (`cosim fmu build` prints the bundled one)")
    if path.is_dir() or not zipfile.is_zipfile(path):
        raise FmuFormatError(f"{path} is not an FMU: it is not a zip archive; pass the .fmu file a tool exported")
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
    if "modelDescription.xml" not in names:
        raise FmuFormatError(f"{path} is not an FMU: the zip has no modelDescription.xml at its top level; "
                             "re-export the model as an FMU")
    import fmpy  # imported when an FMU is opened, not with cosim (tens of ms)
    from fmpy.model_description import read_model_description

    try:
        md = read_model_description(str(path), validate=False)
    except Exception as exc:  # fmpy raises bare Exceptions and lxml errors
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FmuFormatError(f"{path}: modelDescription.xml cannot be read ({first}); re-export the FMU") from None
    if md.fmiVersion not in ("2.0",) and not str(md.fmiVersion).startswith("3."):
        raise FmuFormatError(f"{path} is an FMI {md.fmiVersion} FMU; cosim drives FMI 2.0 and 3.0 FMUs: "
                             "re-export it as FMI 2.0 or 3.0")
    try:
        interface = getattr(md, {"cs": "coSimulation", "me": "modelExchange"}[interface_kind(md, kind)])
    except FmuFormatError as exc:
        raise FmuFormatError(f"{path}: {exc}") from None
    platform = fmpy.platform if md.fmiVersion == "2.0" else fmpy.platform_tuple
    library = f"binaries/{platform}/{interface.modelIdentifier}{fmpy.sharedLibraryExtension}"
    if library not in names:
        found = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
        has = ", ".join(found) if found else "none"
        raise FmuPlatformError(f"{path} has no binary for this platform ({platform}; it has: {has}); "
                               "export it for this platform")
    return md


def parameter_names(md: ModelDescription) -> list[str]:
    """The parameters a run may set (causality parameter, variability fixed or tunable), in declaration order."""
    return [v.name for v in md.modelVariables if v.causality == "parameter" and v.variability in ("fixed", "tunable")]


def variable_unit(var: object) -> str:
    """A model variable's unit: its own, else its declared type's, else ``""``."""
    return str(getattr(var, "unit", None) or getattr(getattr(var, "declaredType", None), "unit", None) or "")


def _close_matches(name: str, candidates: Iterable[str]) -> str:
    """The hint for an unknown variable `name`: the nearest `candidates`, then all of them (40 at most)."""
    candidates = list(candidates)
    near = difflib.get_close_matches(name, candidates, n=3)
    hint = f" Did you mean {', '.join(near)}?" if near else ""
    listed = ", ".join(candidates[:40]) + (" ..." if len(candidates) > 40 else "")
    return f"{hint} Known: {listed or 'none'}"
