"""A plant of several FMUs described: :class:`System`, its :class:`Component` s and :class:`Connection` s, read from
an SSP 1.0 file (``.ssp`` archive or a bare ``SystemStructure.ssd``), an Open Simulation Platform
``OspSystemStructure.xml``, or written in Python.

The description only names things: which FMU each component is, which connector drives which, the parameter
values bound to a component, the linear transformation and unit of a connection. Whether the names exist in the
FMUs, whether the types and units agree and in which order the components step is decided against the FMUs'
model descriptions by :func:`cosim.plant.system_wiring.wire`, and the system is run by
:class:`cosim.plant.system_plant.SystemPlant`.

Variables of a system are named ``component.variable`` (SSP's own naming); a nested SSP system's components are
named by their path (``drive.motor``), so a variable is ``drive.motor.omega_m``.

Why not FMPy's SSP reader (``fmpy.ssp.ssd.read_ssd``): it reads only a zipped ``.ssp``, drops the connectors'
types and units, and resolves a connection through a nested system's connectors by the first match it finds.
The SSD format is small XML, read here with the standard library; FMPy's XML schema still validates it where
lxml is installed (:func:`read_system` ``validate=True``).

Examples
--------
>>> from cosim.plant.system_structure import System
>>> s = System(components={"motor": "motor.fmu", "load": "shaft_load.fmu"},
...            connections=[("motor.theta_m", "load.theta_m"), ("load.Tc", "motor.Tc")])
>>> [c.end for c in s.connections]
['load.theta_m', 'motor.Tc']
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import FmuFormatError, FmuNotFoundError, InvalidSettingError

__all__ = ["Component", "Connection", "System", "is_system_file", "read_system", "split_name"]

_SSP = "http://ssp-standard.org/SSP1/"
NS = {"ssd": _SSP + "SystemStructureDescription", "ssc": _SSP + "SystemStructureCommon",
      "ssv": _SSP + "SystemStructureParameterValues", "ssm": _SSP + "SystemStructureParameterMapping",
      "osp": "http://opensimulationplatform.com/MSMI/OSPSystemStructure"}
_VALUE_TYPES = ("Real", "Float64", "Float32", "Integer", "Boolean", "String", "Enumeration")


@dataclass(frozen=True)
class Component:
    """One FMU of a system.

    Parameters
    ----------
    source : path-like
        The ``.fmu`` file.
    parameters : mapping, optional
        Values applied before initialisation (parameters, or start values of other variables), by the FMU's
        variable names.
    kind : {"cs", "me"}, optional
        The FMU's interface (default: co-simulation when it has it, else Model Exchange).
    step_multiple : int
        The component steps every `step_multiple` communication steps of the system, over that many steps at
        once (a slow controller or sensor); 1 by default.
    units : mapping, optional
        Units the system file declares on the component's connectors (``{"theta_m": "rad"}``).
    """

    source: Path
    parameters: Mapping[str, Any] = field(default_factory=dict)
    kind: str | None = None
    step_multiple: int = 1
    units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "source", Path(self.source))
        object.__setattr__(self, "parameters", dict(self.parameters))
        object.__setattr__(self, "units", dict(self.units))
        if not isinstance(self.step_multiple, int) or isinstance(self.step_multiple, bool) or self.step_multiple < 1:
            raise InvalidSettingError(f"step_multiple={self.step_multiple!r} of {self.source.name}; give a whole "
                                      "number >= 1 (the component steps every that many communication steps)")
        if self.kind not in (None, "cs", "me"):
            raise InvalidSettingError(f"kind={self.kind!r} of {self.source.name}; choose cs or me")


@dataclass(frozen=True)
class Connection:
    """A connector driving another: ``end = factor * start + offset`` (SSP's linear transformation).

    `start` and `end` are ``component.variable`` names. With `convert_units` (the default, as SSP asks unless
    ``suppressUnitConversion``), a start and an end of different units are converted where both units are
    defined over the same base units; otherwise the run refuses the connection.
    """

    start: str
    end: str
    factor: float = 1.0
    offset: float = 0.0
    convert_units: bool = True

    def __post_init__(self) -> None:
        for side in (self.start, self.end):
            if not isinstance(side, str) or "." not in side.strip(". "):
                raise InvalidSettingError(f"connection {self.start!r} -> {self.end!r}: name each side as "
                                          "component.variable (e.g. motor.theta_m)")
        for name in ("factor", "offset"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InvalidSettingError(f"connection {self.start} -> {self.end}: {name}={value!r}; give a finite "
                                          "number")
        if self.factor == 0:
            raise InvalidSettingError(f"connection {self.start} -> {self.end}: factor 0 cuts the connection; "
                                      "remove it instead")


@dataclass(frozen=True)
class System:
    """A plant of several FMUs: components by name and the connections between their connectors.

    Parameters
    ----------
    components : mapping
        Component name -> :class:`Component`, or an FMU path (a component with no parameters).
    connections : sequence
        :class:`Connection` s, or ``(start, end)`` pairs of ``component.variable`` names.
    name : str
        The system's name.
    dt : float, optional
        The communication step the system file proposes (an OSP BaseStepSize, an SSP fixed-step master's).
    unit_definitions : mapping, optional
        Units a system file defines: name -> (kg, m, s, A, K, mol, cd, rad exponents, factor, offset).
    source : path, optional
        The file it was read from.

    Raises
    ------
    InvalidSettingError
        A connection names a component the system does not have, or drives an input that another connection
        drives already (one line each).
    """

    components: Mapping[str, Component]
    connections: Sequence[Connection] = ()
    name: str = "system"
    dt: float | None = None
    unit_definitions: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    source: Path | None = None

    def __post_init__(self) -> None:
        comps: dict[str, Component] = {}
        for cname, comp in dict(self.components).items():
            if not isinstance(cname, str) or not re.fullmatch(r"[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*", cname):
                raise InvalidSettingError(f"component name {cname!r}: use letters, digits and _ (a nested "
                                          "system's path joined by dots)")
            comps[cname] = comp if isinstance(comp, Component) else Component(Path(comp))
        if not comps:
            raise InvalidSettingError("a system needs at least one component")
        conns = tuple(c if isinstance(c, Connection) else Connection(*c) for c in self.connections)
        object.__setattr__(self, "components", comps)
        object.__setattr__(self, "connections", conns)
        driven: dict[str, str] = {}
        for c in conns:
            for side in (c.start, c.end):
                split_name(side, comps, what=f"connection {c.start} -> {c.end}")
            if c.end in driven:
                raise InvalidSettingError(f"input {c.end} is connected twice (from {driven[c.end]} and from "
                                          f"{c.start}); an input takes one source: remove one connection")
            driven[c.end] = c.start

    @property
    def driven(self) -> dict[str, Connection]:
        """The connections by the input they drive."""
        return {c.end: c for c in self.connections}


def split_name(name: str, components: Mapping[str, Any], *, what: str = "variable") -> tuple[str, str]:
    """``component.variable`` split at the longest component name that prefixes it (a variable may hold dots
    itself, ``load.mass.s``; a nested component's name too, ``drive.motor.omega_m``).

    Examples
    --------
    >>> split_name("load.mass.s", {"load": None, "motor": None})
    ('load', 'mass.s')
    """
    best = max((c for c in components if name.startswith(c + ".") and len(name) > len(c) + 1), key=len, default=None)
    if best is None:
        known = ", ".join(components)
        raise InvalidSettingError(f"{what}: {name!r} names no component of the system ({known}); name it as "
                                  "component.variable")
    return best, name[len(best) + 1:]


def is_system_file(path: str | os.PathLike) -> bool:
    """Whether `path` names a system of FMUs (``.ssp``, ``.ssd``, an OSP ``...SystemStructure.xml``), by its name."""
    p = Path(path)
    return p.suffix.lower() in (".ssp", ".ssd") or (p.suffix.lower() == ".xml" and "systemstructure" in p.name.lower())


def read_system(path: str | os.PathLike, *, cache_dir: str | os.PathLike | None = None) -> System:
    """Read a system of FMUs from an SSP archive, a bare SSD, or an OSP system structure file.

    Parameters
    ----------
    path : path-like
        ``X.ssp`` (its FMUs are extracted once into the cache, keyed by the archive's contents),
        ``SystemStructure.ssd`` (FMU paths relative to its folder) or ``OspSystemStructure.xml``.
    cache_dir : path-like, optional
        Where an ``.ssp`` is extracted (default: :func:`cosim.plant.build.fmu_cache_dir`).

    Returns
    -------
    System

    Raises
    ------
    FmuNotFoundError
        The file, or an FMU it names, does not exist.
    FmuFormatError
        The file is not a system description cosim reads.

    Examples
    --------
    >>> from cosim.plant.build import build_ssp
    >>> system = read_system(build_ssp())
    >>> sorted(system.components)
    ['load', 'motor']
    """
    p = Path(path)
    if not p.exists():
        raise FmuNotFoundError(f"{p}: no such system file; give an .ssp, a SystemStructure.ssd or an "
                               "OspSystemStructure.xml")
    if p.is_dir():
        for candidate in ("SystemStructure.ssd", "OspSystemStructure.xml"):
            if (p / candidate).exists():
                return read_system(p / candidate, cache_dir=cache_dir)
        raise FmuFormatError(f"{p}: a folder without SystemStructure.ssd or OspSystemStructure.xml")
    if p.suffix.lower() == ".ssp":
        folder = _extracted(p, cache_dir)
        system = _read_ssd(folder / "SystemStructure.ssd", folder)
        return System(system.components, system.connections, name=system.name, dt=system.dt,
                      unit_definitions=system.unit_definitions, source=p.absolute())
    root = _parse(p)
    tag = root.tag.split("}")[-1]
    if tag == "SystemStructureDescription":
        return _read_ssd(p, p.parent, root)
    if tag == "OspSystemStructure":
        return _read_osp(p, root)
    raise FmuFormatError(f"{p.name}: its root element is {tag}, not an SSP SystemStructureDescription nor an "
                         "OspSystemStructure; give an .ssp, a SystemStructure.ssd or an OspSystemStructure.xml")


# ---------------------------------------------------------------------------------------------------- files
def _parse(p: Path) -> ET.Element:
    try:
        return ET.parse(p).getroot()
    except ET.ParseError as exc:
        raise FmuFormatError(f"{p.name} is not well-formed XML ({exc}); check the file") from None


def _extracted(ssp: Path, cache_dir: str | os.PathLike | None) -> Path:
    """The archive extracted once into ``<cache>/systems/<name>-<hash>/`` (atomically: a temporary folder renamed
    into place), so that its FMUs have paths as long as anyone needs them."""
    from .build import fmu_cache_dir

    try:
        zf = zipfile.ZipFile(ssp)
    except zipfile.BadZipFile:
        raise FmuFormatError(f"{ssp.name} is not an SSP archive (not a zip file); give an .ssp made by an SSP "
                             "tool, or the bare SystemStructure.ssd") from None
    with zf:
        names = zf.namelist()
        if "SystemStructure.ssd" not in names:
            raise FmuFormatError(f"{ssp.name} holds no SystemStructure.ssd; it is not an SSP archive")
        digest = hashlib.sha256()
        for info in sorted(zf.infolist(), key=lambda i: i.filename):
            digest.update(f"{info.filename}:{info.CRC}:{info.file_size};".encode())
        root = Path(cache_dir) if cache_dir is not None else fmu_cache_dir()
        target = root / "systems" / f"{ssp.stem}-{digest.hexdigest()[:16]}"
        if target.exists():
            return target
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
            for name in names:
                resolved = (Path(tmp) / name).resolve()
                if not str(resolved).startswith(str(Path(tmp).resolve())):
                    raise FmuFormatError(f"{ssp.name}: member {name!r} points outside the archive; refusing it")
            zf.extractall(tmp)
            try:
                os.replace(tmp, target)
            except OSError:  # another process put it there first
                if not target.exists():
                    raise
            else:
                os.mkdir(tmp)  # for TemporaryDirectory's clean-up
    return target


def _source(text: str | None, base: Path, where: str) -> Path:
    if not text:
        raise FmuFormatError(f"{where}: no source FMU given")
    text = re.sub(r"^file:(//)?", "", text)
    path = (base / text) if not Path(text).is_absolute() else Path(text)
    if not path.exists():
        raise FmuNotFoundError(f"{where}: its FMU {text} is missing (looked for {path}); put it there or fix the "
                               "source attribute")
    return path


def _value(element: ET.Element, ns: str, where: str) -> tuple[Any, str | None]:
    """A typed value element's value (``<ssv:Real value="1"/>``, ``<Real value=.../>``) and its unit."""
    for kind in _VALUE_TYPES:
        node = element.find(f"{ns}{kind}", NS) if ns else element.find(kind)
        if node is None and not ns:
            node = next((c for c in element if c.tag.split("}")[-1] == kind), None)
        if node is None:
            continue
        text = node.get("value")
        if text is None:
            raise FmuFormatError(f"{where}: a {kind} without a value")
        if kind in ("Real", "Float64", "Float32"):
            return float(text), node.get("unit")
        if kind in ("Integer", "Enumeration"):
            return int(text), None
        if kind == "Boolean":
            return text.strip().lower() in ("true", "1"), None
        return text, None
    raise FmuFormatError(f"{where}: no value of a type cosim reads ({', '.join(_VALUE_TYPES)})")


# ---------------------------------------------------------------------------------------------------- SSP
def _read_ssd(p: Path, base: Path, root: ET.Element | None = None) -> System:
    root = _parse(p) if root is None else root
    if root.tag != f"{{{NS['ssd']}}}SystemStructureDescription":
        raise FmuFormatError(f"{p.name}: not an SSP 1.0 SystemStructureDescription (root {root.tag})")
    units = {}
    for u in root.findall("ssd:Units/ssc:Unit", NS):
        b = u.find("ssc:BaseUnit", NS)
        b = b.attrib if b is not None else {}
        units[u.get("name")] = (*(float(b.get(k, 0)) for k in ("kg", "m", "s", "A", "K", "mol", "cd", "rad")),
                                float(b.get("factor", 1)), float(b.get("offset", 0)))
    top = root.find("ssd:System", NS)
    if top is None:
        raise FmuFormatError(f"{p.name}: no System element")
    components: dict[str, Component] = {}
    edges: list[tuple[str, str, float, float, bool]] = []
    system_connectors: set[str] = set()
    _walk_ssd(top, "", base, p, components, edges, system_connectors)
    dt = None
    master = top.find(".//ssd:SimulationInformation/ssd:FixedStepMaster", NS)
    if master is not None and master.get("stepSize"):
        dt = float(master.get("stepSize"))
    return System(components, _resolve_edges(edges, system_connectors, components), name=root.get("name") or p.stem,
                  dt=dt, unit_definitions=units, source=p.absolute())


def _walk_ssd(system: ET.Element, prefix: str, base: Path, p: Path, components: dict, edges: list,
              system_connectors: set) -> None:
    """Components of `system` and its nested systems by path, and every connection as an edge between connector
    paths (a system's own connector: ``prefix + name``)."""
    own = _bindings(system, base, p)  # a system's bindings name component.parameter
    for c in system.findall("ssd:Connectors/ssd:Connector", NS):
        system_connectors.add(prefix + c.get("name"))
    for element in system.findall("ssd:Elements/*", NS):
        tag = element.tag.split("}")[-1]
        name = element.get("name")
        if tag == "System":
            _walk_ssd(element, prefix + name + ".", base, p, components, edges, system_connectors)
        elif tag == "Component":
            kind = element.get("type", "application/x-fmu-sharedlibrary")
            if kind != "application/x-fmu-sharedlibrary":
                raise FmuFormatError(f"{p.name}: component {prefix + name} is of type {kind}; cosim runs FMUs "
                                     "(application/x-fmu-sharedlibrary)")
            impl = (element.get("implementation") or "any").lower()
            units = {}
            for c in element.findall("ssd:Connectors/ssd:Connector", NS):
                for child in c:
                    if child.get("unit"):
                        units[c.get("name")] = child.get("unit")
            components[prefix + name] = Component(
                _source(element.get("source"), base, f"component {prefix + name}"),
                parameters=_bindings(element, base, p), units=units,
                kind={"coSimulation": "cs", "cosimulation": "cs", "modelexchange": "me"}.get(impl))
    for cname, params in own.items():  # bindings on a system address its components by (relative) path
        comp, param = split_name(prefix + cname, components, what=f"{p.name}: parameter binding")
        components[comp] = Component(components[comp].source, {**components[comp].parameters, param: params},
                                     components[comp].kind, components[comp].step_multiple,
                                     components[comp].units)
    for c in system.findall("ssd:Connections/ssd:Connection", NS):
        start = prefix + (c.get("startElement") + "." if c.get("startElement") else "") + c.get("startConnector")
        end = prefix + (c.get("endElement") + "." if c.get("endElement") else "") + c.get("endConnector")
        t = c.find("ssc:LinearTransformation", NS)
        factor = float(t.get("factor", 1.0)) if t is not None else 1.0
        offset = float(t.get("offset", 0.0)) if t is not None else 0.0
        if c.find("ssc:MapTransformation", NS) is not None or any(
                c.find(f"ssc:{k}MappingTransformation", NS) is not None for k in ("Boolean", "Integer",
                                                                                   "Enumeration")):
            raise FmuFormatError(f"{p.name}: connection {start} -> {end} has a mapping transformation; cosim "
                                 "applies linear transformations only")
        edges.append((start, end, factor, offset, c.get("suppressUnitConversion", "false").lower() != "true"))


def _bindings(element: ET.Element, base: Path, p: Path) -> dict[str, Any]:
    """The values an element's parameter bindings give (inline or ``.ssv`` sets, through ``.ssm`` mappings),
    names relative to the element."""
    values: dict[str, Any] = {}
    for b in element.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
        prefix = b.get("prefix") or ""
        sets = []
        if b.get("source"):
            sets.append(_parse(_source(b.get("source"), base, f"{p.name}: parameter binding")))
        sets += b.findall("ssd:ParameterValues/ssv:ParameterSet", NS)
        found: dict[str, Any] = {}
        for s in sets:
            for par in s.findall("ssv:Parameters/ssv:Parameter", NS):
                found[par.get("name")], _ = _value(par, "ssv:", f"{p.name}: parameter {par.get('name')}")
        mapping = b.find("ssd:ParameterMapping", NS)
        if mapping is not None:
            m = _parse(_source(mapping.get("source"), base, f"{p.name}: parameter mapping")) if mapping.get(
                "source") else mapping.find("ssm:ParameterMapping", NS)
            renamed = {}
            for entry in (m.findall("ssm:MappingEntry", NS) if m is not None else []):
                src, dst = entry.get("source"), entry.get("target")
                if src in found:
                    value = found.pop(src)
                    t = entry.find("ssc:LinearTransformation", NS)
                    if t is not None and isinstance(value, float):
                        value = float(t.get("factor", 1)) * value + float(t.get("offset", 0))
                    renamed[dst] = value
            found.update(renamed)
        for name, value in found.items():
            values[name[len(prefix):] if prefix and name.startswith(prefix) else name] = value
    return values


def _resolve_edges(edges: list, system_connectors: set, components: Mapping[str, Component]) -> list[Connection]:
    """Component-to-component connections: a chain through nested systems' connectors followed to its component
    ends, the linear transformations composed along it. A top-level system input that drives a component is left
    out: the component's input is then a free input of the system."""
    by_end: dict[str, list] = {}
    for e in edges:
        by_end.setdefault(e[1], []).append(e)
    out = []
    for start, end, factor, offset, convert in edges:
        if end in system_connectors:
            continue  # followed from the component input it reaches
        while start in system_connectors and start in by_end:
            prev = by_end[start][0]
            start, factor, offset = prev[0], factor * prev[2], factor * prev[3] + offset
            convert = convert and prev[4]
        if start in system_connectors:
            continue  # a free input of the system, named by the component input it drives
        out.append(Connection(start, end, factor, offset, convert))
    return out


# ---------------------------------------------------------------------------------------------------- OSP
def _read_osp(p: Path, root: ET.Element) -> System:
    def find(node, path):
        return node.find(path if not root.tag.startswith("{") else "/".join(f"osp:{x}" for x in path.split("/")),
                         NS)

    def findall(node, path):
        return node.findall(path if not root.tag.startswith("{") else "/".join(f"osp:{x}" for x in path.split("/")),
                            NS)

    base_step = find(root, "BaseStepSize")
    dt = float(base_step.text) if base_step is not None and base_step.text else None
    components = {}
    for sim in findall(root, "Simulators/Simulator"):
        name = sim.get("name")
        values = {}
        for iv in findall(sim, "InitialValues/InitialValue"):
            values[iv.get("variable")], _ = _value(iv, "", f"{p.name}: initial value {iv.get('variable')}")
        multiple = 1
        if sim.get("stepSize") and dt:
            ratio = float(sim.get("stepSize")) / dt
            multiple = max(1, round(ratio))
            if abs(ratio - multiple) > 1e-9 * ratio:
                raise FmuFormatError(f"{p.name}: simulator {name}'s stepSize {sim.get('stepSize')} is not a "
                                     f"multiple of BaseStepSize {dt}")
        components[name] = Component(_source(sim.get("source"), p.parent, f"simulator {name}"), values,
                                     step_multiple=multiple)
    connections = []
    for conn in findall(root, "Connections/VariableConnection") + findall(root, "Connections/SignalConnection"):
        ends = findall(conn, "Variable") or findall(conn, "Signal")
        if len(ends) != 2:
            raise FmuFormatError(f"{p.name}: a connection with {len(ends)} variables; it takes two")
        first, second = ends
        if first.get("causality") == "input" or second.get("causality") == "output":
            first, second = second, first
        connections.append(Connection(f"{first.get('simulator')}.{first.get('name')}",
                                      f"{second.get('simulator')}.{second.get('name')}"))
    if findall(root, "Connections/VariableGroupConnection"):
        raise FmuFormatError(f"{p.name}: variable group connections (power bonds declared in OspModelDescription "
                             "files) are not read; write them as VariableConnections")
    return System(components, connections, name=p.stem, dt=dt, source=p.absolute())
