"""A PID as an FMI 2.0 co-simulation FMU: :func:`export_fmu`.

The controller's sample law is the C of ``_fmu.c``, operation for operation as :meth:`PID.__call__
<controllers.pid.PID.__call__>` computes it, with the PID's settings as the FMU's parameters (start values) and
its names as the FMU's variables: inputs ``setpoint``, the measured output (and the measured velocity), output the
command. Placed in a system beside the plant FMUs (:class:`cosim.plant.system_plant.SystemPlant`), the loop it
closes gives cosim's own closed loop with the Python PID (tests/test_controller_fmu.py). Users then hand the tested
controller to any FMI tool.
"""

from __future__ import annotations

import math
import os
import uuid
import xml.etree.ElementTree as ET
from importlib import resources
from pathlib import Path
from typing import Any

from cosim.errors import InvalidSettingError
from cosim.plant.toolchain import compile_and_pack

__all__ = ["export_fmu"]

_PARAMETERS = ("kp", "ki", "kd", "tf", "b", "tt", "u0", "u_min", "u_max", "du_max")
_ANTI_WINDUP = {None: 0, "back-calculation": 1, "clamping": 2}


def _c_double(value: float) -> str:
    if math.isinf(value):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    return repr(float(value))


def _values(pid: Any) -> dict[str, float]:
    return {"kp": pid.kp, "ki": pid.ki, "kd": pid.kd, "tf": pid.tf, "b": pid.b, "tt": pid.tt, "u0": pid.u0,
            "u_min": pid._umin, "u_max": pid._umax, "du_max": pid._dumax}


def _config(pid: Any, identifier: str, guid: str) -> str:
    values = _values(pid)
    return "\n".join([
        f'#define PID_IDENTIFIER "{identifier}"', f'#define PID_GUID "{guid}"',
        f"#define PID_DT {pid.dt!r}", f"#define PID_VELOCITY {int(pid.velocity is not None)}",
        f"#define PID_ANTI_WINDUP {_ANTI_WINDUP[pid.anti_windup]}",
        "#define PID_PARAMETER_STARTS {" + ", ".join(_c_double(values[k]) for k in _PARAMETERS) + "}", ""])


def _xml_double(value: float) -> str:
    return ("INF" if value > 0 else "-INF") if math.isinf(value) else repr(float(value))


def _model_description(pid: Any, identifier: str, guid: str) -> bytes:
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": guid, "generationTool": "cosim (controllers.pid)",
        "description": f"PID of {pid.inputs[0]} on {pid.tracked[0]}", "variableNamingConvention": "flat",
        "numberOfEventIndicators": "0"})
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": identifier, "canHandleVariableCommunicationStepSize":
                                         "false", "canGetAndSetFMUstate": "true", "canNotUseMemoryManagementFunctions":
                                         "true"})
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0", "stepSize": repr(float(pid.dt))})
    variables = ET.SubElement(root, "ModelVariables")
    measured = pid.outputs[pid._iy]
    rows: list[tuple[str, int, dict, str, dict]] = [
        ("time", 0, {"causality": "independent", "variability": "continuous"}, "Real", {}),
        ("setpoint", 1, {"causality": "input", "variability": "discrete"}, "Real", {"start": "0"}),
        (measured, 2, {"causality": "input", "variability": "discrete"}, "Real", {"start": "0"})]
    if pid.velocity is not None:
        rows.append((pid.velocity, 3, {"causality": "input", "variability": "discrete"}, "Real", {"start": "0"}))
    rows.append((pid.inputs[0], 4, {"causality": "output", "variability": "discrete", "initial": "calculated"},
                 "Real", {}))
    values = _values(pid)
    rows += [(k, 5 + i, {"causality": "parameter", "variability": "fixed"}, "Real", {"start": _xml_double(values[k])})
             for i, k in enumerate(_PARAMETERS)]
    rows.append(("anti_windup", 15, {"causality": "parameter", "variability": "fixed",
                                     "description": "0 none, 1 back-calculation, 2 clamping"}, "Integer",
                 {"start": str(_ANTI_WINDUP[pid.anti_windup])}))
    rows.append(("dt", 16, {"causality": "local", "variability": "constant", "description": "sample time"},
                 "Real", {"start": repr(float(pid.dt))}))
    index = {}
    for position, (name, vr, attrs, kind, typed) in enumerate(rows, start=1):
        var = ET.SubElement(variables, "ScalarVariable", {"name": name, "valueReference": str(vr), **attrs})
        ET.SubElement(var, kind, typed)
        index[vr] = position
    structure = ET.SubElement(root, "ModelStructure")
    inputs = [str(index[vr]) for vr in (1, 2, 3) if vr in index]
    for group in ("Outputs", "InitialUnknowns"):
        ET.SubElement(ET.SubElement(structure, group), "Unknown", {"index": str(index[4]),
                                                                   "dependencies": " ".join(inputs)})
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def export_fmu(pid: Any, path: str | os.PathLike, *, name: str | None = None) -> Path:
    """Write `pid` as an FMI 2.0 co-simulation FMU (compiled from C, written atomically).

    Parameters
    ----------
    pid : controllers.pid.PID
    path : path-like
        The ``.fmu`` file; its stem is the model identifier unless `name` is given.
    name : str, optional
        The model identifier (a C identifier).

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from cosim import FmuPlant
    >>> from controllers.pid import PID
    >>> pid = PID(kp=2.0, ki=1.0, dt=0.1, inputs="Tm", outputs="theta_L")
    >>> fmu = export_fmu(pid, pathlib.Path(tempfile.mkdtemp()) / "pid.fmu")
    >>> with FmuPlant(fmu, dt=0.1, inputs=["setpoint", "theta_L"], outputs=["Tm"]) as plant:
    ...     plant.set_inputs([1.0, 0.5])
    ...     float(plant.read_outputs()[0])    # 2*(1 - 0.5), as pid(0, [0.5]) with setpoint 1
    1.0
    """
    path = Path(path)
    identifier = name or path.stem
    if not identifier.isidentifier():
        raise InvalidSettingError(f"{identifier!r} is not a C identifier; name the FMU file (or pass name=) with "
                                  "letters, digits and _")
    settings = pid.to_json() if hasattr(pid, "to_json") else repr(pid)
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"cosim-pid:{identifier}:{settings}")) + "}"
    source = resources.files("controllers.pid").joinpath("_fmu.c").read_text()
    compile_and_pack(path, identifier=identifier, description=_model_description(pid, identifier, guid),
                     sources={"fmi2.c": source, "pid_config.h": _config(pid, identifier, guid)}, compiled=["fmi2.c"],
                     what=f"the PID FMU {identifier}")
    return path
