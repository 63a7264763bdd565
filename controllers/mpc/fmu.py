"""An MPC as an FMI 2.0 co-simulation FMU: :func:`export_fmu`.

The FMU's step is the controller's own: the casadi Function of :func:`~controllers.mpc._qp.step_function`
(filter, target, condensed QP, the clipped first move, the prediction) generated as C and linked with the QP
solver's static library, as :class:`~controllers.mpc.MPC` compiles it for itself (:mod:`controllers.mpc._codegen`);
around it ``_fmu.c`` holds the state between samples and the fallback :meth:`MPC._fallback
<controllers.mpc.MPC._fallback>` applies when the QP fails. Inputs: the measured outputs and the set-points
(``r_<tracked>``); outputs: the commands, with direct feedthrough. Beside the plant in a system
(:class:`cosim.plant.system_plant.SystemPlant`) it closes cosim's own closed loop with the Python MPC
(tests/test_controller_fmu.py).

The generated step keeps its QP solver's memory static, so the FMU says ``canBeInstantiatedOnlyOncePerProcess``.
"""

from __future__ import annotations

import hashlib
import os
import uuid
import xml.etree.ElementTree as ET
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import InvalidSettingError
from cosim.plant.toolchain import compile_and_pack

__all__ = ["export_fmu"]

_ON_INFEASIBLE = {"previous_plan": 0, "hold": 1, "raise": 2}
_WRAPPER = "#define GCC_HASCLASSVISIBILITY 1\n#include \"step_generated.c\"\n"


def _array(name: str, values: Any) -> str:
    flat = np.asarray(values, dtype=float).ravel()
    items = ", ".join("INFINITY" if v == np.inf else "(-INFINITY)" if v == -np.inf else repr(float(v)) for v in flat)
    return f"static const double {name}[{max(flat.size, 1)}] = {{{items or '0.0'}}};"


def _config(mpc: Any, identifier: str, guid: str, step_name: str) -> str:
    from controllers.mpc.controller import _VIOLATION_TOL

    lay, sp = mpc._lay, mpc._problem
    state0 = np.zeros(lay.n_state)  # the state MPC.reset() starts from
    state0[:lay.n] = mpc._x0
    state0[lay.na:lay.na + lay.m] = mpc._u0
    state0[lay.na + lay.m:] = np.tile(mpc._u0, lay.N)
    return "\n".join([
        f'#define MPC_IDENTIFIER "{identifier}"', f'#define MPC_GUID "{guid}"', f"#define MPC_DT {mpc.dt!r}",
        f"#define MPC_STEP {step_name}", f"#define MPC_STEP_WORK {step_name}_work",
        f"#define MPC_P {lay.p}", f"#define MPC_NT {lay.nt}", f"#define MPC_NA {lay.na}", f"#define MPC_N {lay.n}",
        f"#define MPC_M {lay.m}", f"#define MPC_HORIZON {lay.N}", f"#define MPC_NMEAS {lay.n_meas}",
        f"#define MPC_NSTATE {lay.n_state}", f"#define MPC_NOUT {lay.n_out}",
        f"#define MPC_VIOLATION_TOL {_VIOLATION_TOL!r}",
        f"#define MPC_ON_INFEASIBLE {_ON_INFEASIBLE[mpc.on_infeasible]}",
        f"#define MPC_MAX_FALLBACKS {int(mpc.max_fallbacks)}",
        _array("MPC_STATE0", state0), _array("MPC_UMIN", mpc.u_min), _array("MPC_UMAX", mpc.u_max),
        _array("MPC_DUMAX", mpc.du_max), _array("MPC_L", sp.L), _array("MPC_CO", sp.Co), _array("MPC_FO", sp.fo),
        _array("MPC_AO", sp.Ao), _array("MPC_BO", sp.Bo), _array("MPC_EO", sp.eo), _array("MPC_T", sp.T),
        _array("MPC_T0", sp.t0), ""])


def _model_description(mpc: Any, identifier: str, guid: str) -> bytes:
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": guid, "generationTool": "cosim (controllers.mpc)",
        "description": f"MPC of {', '.join(mpc.inputs)} on {', '.join(mpc.tracked)}",
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": identifier, "canHandleVariableCommunicationStepSize":
                                         "false", "canBeInstantiatedOnlyOncePerProcess": "true"})
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0", "stepSize": repr(float(mpc.dt))})
    variables = ET.SubElement(root, "ModelVariables")
    var = ET.SubElement(variables, "ScalarVariable", {"name": "time", "valueReference": "0",
                                                      "causality": "independent", "variability": "continuous"})
    ET.SubElement(var, "Real")
    names = [*mpc.outputs, *(f"r_{t}" for t in mpc.tracked)]
    for vr, name in enumerate(names, start=1):
        var = ET.SubElement(variables, "ScalarVariable", {"name": name, "valueReference": str(vr),
                                                          "causality": "input", "variability": "discrete"})
        ET.SubElement(var, "Real", {"start": "0"})
    outputs = []
    for j, name in enumerate(mpc.inputs):
        vr = 1 + len(names) + j
        var = ET.SubElement(variables, "ScalarVariable", {"name": name, "valueReference": str(vr),
                                                          "causality": "output", "variability": "discrete",
                                                          "initial": "calculated"})
        ET.SubElement(var, "Real")
        outputs.append(2 + len(names) + j)  # its index in ModelVariables (time is 1)
    structure = ET.SubElement(root, "ModelStructure")
    depends = " ".join(str(2 + i) for i in range(len(names)))
    for group in ("Outputs", "InitialUnknowns"):
        node = ET.SubElement(structure, group)
        for index in outputs:
            ET.SubElement(node, "Unknown", {"index": str(index), "dependencies": depends})
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def export_fmu(mpc: Any, path: str | os.PathLike, *, name: str | None = None) -> Path:
    """Write `mpc` as an FMI 2.0 co-simulation FMU (its step's generated C and the QP solver's library, compiled;
    written atomically).

    Parameters
    ----------
    mpc : controllers.mpc.MPC
        An MPC whose QP solver casadi can generate C for (``daqp``, the default, or ``qrqp``).
    path : path-like
        The ``.fmu`` file; its stem is the model identifier unless `name` is given.
    name : str, optional
        The model identifier (a C identifier).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    InvalidSettingError
        The name is no C identifier, or casadi cannot generate C for the MPC's solver.
    """
    import casadi as ca

    from controllers.mpc._codegen import _casadi_dir, codegen_support

    path = Path(path)
    identifier = name or path.stem
    if not identifier.isidentifier():
        raise InvalidSettingError(f"{identifier!r} is not a C identifier; name the FMU file (or pass name=) with "
                                  "letters, digits and _")
    libs, reason = codegen_support(mpc._problem.solver)
    if reason:
        raise InvalidSettingError(f"the MPC cannot be exported as an FMU: {reason}")
    # the Function the MPC compiles for itself, generated the same way (its symbols stay inside the FMU's library:
    # the project's flags hide them, so two MPC FMUs never collide in one process)
    fun = mpc._fun
    step_name = fun.name()
    generator = ca.CodeGenerator("step_generated.c", {"with_header": False})
    generator.add(fun)
    generated = generator.dump()
    digest = hashlib.sha256(generated.encode()).hexdigest()
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"cosim-mpc:{identifier}:{digest}")) + "}"
    source = resources.files("controllers.mpc").joinpath("_fmu.c").read_text()
    files = {"mpc_config.h": _config(mpc, identifier, guid, step_name), "fmi2.c": source,
             "step_generated.c": generated, "step.c": _WRAPPER}
    compile_and_pack(path, identifier=identifier, description=_model_description(mpc, identifier, guid),
                     sources=files, compiled=["fmi2.c", "step.c"], include_dirs=[_casadi_dir() / "include"],
                     libraries=libs, what=f"the MPC FMU {identifier}")
    return path
