"""Build the bundled plant FMUs from their C source, once, into a cache.

The C source of each bundled FMU lives in the repository's ``fmus/<name>/`` folder,
installed as the package ``cosim.fmus``. :func:`build_fmu` compiles it with the
system C compiler (``$CC``, else ``cc``, else ``gcc``) against the FMI headers that
ship with fmpy, packs the shared library, the model description and the sources into
an FMU, and stores it under a key that changes whenever the sources, the FMI version,
the platform, the compiler or the FMI headers change. Later calls return the cached
file at once.

Layout of the cache::

    <cache>/fmus/<name>-fmi<2|3>-<key>/<name>.fmu

where ``<cache>`` is :func:`fmu_cache_dir` (``$COSIM_CACHE_DIR``, else
``$XDG_CACHE_HOME/cosim``, else ``~/.cache/cosim``) unless ``cache_dir`` is given, and
``<key>`` is the first 16 hex digits of a SHA-256 over the source files, the FMI
version, the platform, the compiler's version line and the FMI headers.

The compiler lookup, flags, compilation and packing are shared with the FMUs generated from
identified models (:func:`cosim.export.export_fmu`) in the private module ``cosim.plant.toolchain``.

Writes are atomic: the FMU is compiled in a temporary directory, zipped into a
temporary file next to its final place, then renamed into place. Two processes
building at once both succeed, and a crash never leaves a half-written FMU.

A source folder holds ``model*.c``/``*.h`` (the model), ``fmi2.c`` and ``fmi3.c`` (the
FMI wrappers), ``modelDescription.xml`` (FMI 2.0) and ``modelDescription3.xml``
(FMI 3.0); the builder compiles the model with the wrapper of the requested version
and stores that version's description as ``modelDescription.xml`` in the FMU. Only the
folder itself is compiled and packed (its include path, its sources, its cache key),
with one exception: a folder without its own wrappers takes its parent folder's (they then
count in its cache key and are packed with it), so that a family of FMUs written against
one ``model.h`` interface shares one wrapper.

A system of FMUs (``fmus/two_mass_servo_split``) is a folder holding an SSP 1.0
``SystemStructure.ssd`` and one FMU source folder per component, named after the
component's ``source="resources/<folder>.fmu"``. :func:`build_ssp` builds each
component with :func:`build_fmu` and packs the ``.ssd`` and the FMUs into an SSP::

    <cache>/fmus/<name>-fmi<2|3>-<key>/<name>.ssp

whose key covers the system folder's files and the components' keys.

Examples
--------
>>> from cosim.plant.build import build_fmu
>>> path = build_fmu("two_mass_servo", fmi_version="2.0")  # compiles on first use only
>>> path.name
'two_mass_servo.fmu'
>>> build_fmu("two_mass_servo") == path  # second call: the cached file
True
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import re
import sys
import tempfile
import xml.etree.ElementTree as ET
import zipfile

from cosim.errors import BuildError, FmuNotFoundError, InvalidSettingError

from .toolchain import (
    CFLAGS,
    Platform,
    compile_library,
    compiler_version,
    find_compiler,
    platform_info,
    write_zip_atomically,
)

__all__ = ["build_fmu", "build_ssp", "fmu_cache_dir", "fmu_source_dir"]

_DEFAULT_NAME = "two_mass_servo"
_DEFAULT_SYSTEM = "two_mass_servo_split"
_SSD = "SystemStructure.ssd"  # the SSP's default system structure, also the marker of a system folder
_SSD_NS = "{http://ssp-standard.org/SSP1/SystemStructureDescription}"
_FMU_MIME = "application/x-fmu-sharedlibrary"
_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_WRAPPERS = {2: "fmi2.c", 3: "fmi3.c"}
_DESCRIPTIONS = {2: "modelDescription.xml", 3: "modelDescription3.xml"}
_BUILDER_FORMAT = "1"  # bump when the layout of the built FMU changes


def fmu_cache_dir() -> pathlib.Path:
    """Return the root folder of the FMU cache.

    ``$COSIM_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/cosim`` if ``XDG_CACHE_HOME`` is
    an absolute path, else ``~/.cache/cosim``. The folder is not created here.

    Returns
    -------
    pathlib.Path
        The cache root; built FMUs go to its ``fmus/`` sub-folder.

    Examples
    --------
    >>> from cosim.plant.build import fmu_cache_dir
    >>> fmu_cache_dir().is_absolute()
    True
    """
    env = os.environ.get("COSIM_CACHE_DIR", "").strip()
    if env:
        return pathlib.Path(env).expanduser().absolute()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    if xdg and pathlib.Path(xdg).is_absolute():
        return pathlib.Path(xdg) / "cosim"
    return pathlib.Path.home() / ".cache" / "cosim"


def fmu_source_dir(name: str = _DEFAULT_NAME) -> pathlib.Path:
    """Return the folder holding the C source and model descriptions of a bundled FMU, or of a bundled system.

    Looks in the installed package ``cosim.fmus`` first (regular and editable
    installs), then in the ``fmus/`` folder next to the ``cosim`` package (a source
    checkout used without installing).

    Parameters
    ----------
    name : str
        Name of the bundled FMU, e.g. ``"two_mass_servo"``, or of a bundled system of FMUs,
        e.g. ``"two_mass_servo_split"`` (see :func:`build_ssp`).

    Returns
    -------
    pathlib.Path
        The source folder: it holds ``modelDescription.xml`` (an FMU) or ``SystemStructure.ssd``
        and the components' source folders (a system).

    Raises
    ------
    InvalidSettingError
        If ``name`` is not a plain identifier.
    FmuNotFoundError
        If no bundled FMU has that name.

    Examples
    --------
    >>> from cosim.plant.build import fmu_source_dir
    >>> (fmu_source_dir("two_mass_servo") / "model.c").is_file()
    True
    >>> (fmu_source_dir("two_mass_servo_split") / "SystemStructure.ssd").is_file()
    True
    """
    _check_name(name)
    for folder in _candidate_dirs(name):
        if _is_source_folder(folder):
            return folder
    available = sorted({p.name for root in _fmu_roots() for p in root.iterdir() if _is_source_folder(p)})
    raise FmuNotFoundError(
        f"no bundled FMU source named {name!r}: available are {', '.join(available) or 'none'}; "
        "check the name or reinstall cosim"
    )


def build_fmu(
    name: str | None = None,
    *,
    fmi_version: str = "2.0",
    cache_dir: str | os.PathLike[str] | None = None,
    force: bool = False,
    source: str | os.PathLike[str] | None = None,
) -> pathlib.Path:
    """Build a bundled FMU, or any source folder laid out as one, from its C source (once); return the FMU's path.

    Parameters
    ----------
    name : str, optional
        Name of the bundled FMU (a folder of ``fmus/``), default ``"two_mass_servo"``; with `source`, the name
        of the FMU file (default: the folder's name).
    fmi_version : str
        ``"2.0"`` or ``"3.0"`` (``"2"`` and ``"3"`` are accepted too), built from the same model core with
        that version's wrapper and model description (which say whether it is Co-Simulation, Model
        Exchange or both).
    cache_dir : str or os.PathLike, optional
        Root of the cache; default :func:`fmu_cache_dir`.
    force : bool
        Rebuild even if the cache already holds this build.
    source : str or os.PathLike, optional
        A folder holding the C source and model descriptions (the layout of the module docstring), instead of
        a bundled FMU: an FMU of one's own, or a test's (``tests/fmus/sliding_mass``).

    Returns
    -------
    pathlib.Path
        ``<cache>/fmus/<name>-fmi<2|3>-<key>/<name>.fmu``.

    Raises
    ------
    BuildError
        If no C compiler is found (``"no C compiler found: install gcc or set CC"``), the
        FMI headers are missing from fmpy, or the compiler reports errors (their first
        lines are in the message).
    FmuNotFoundError
        If there is no bundled FMU of that name (a bundled system's name says to use :func:`build_ssp`), or
        `source` is not a folder with a ``modelDescription.xml``.
    InvalidSettingError
        If ``fmi_version`` is not 2.0 or 3.0.

    Examples
    --------
    >>> import fmpy
    >>> from cosim.plant.build import build_fmu
    >>> path = build_fmu("two_mass_servo", fmi_version="3.0")
    >>> fmpy.read_model_description(str(path)).fmiVersion
    '3.0'
    """
    version = _parse_fmi_version(fmi_version)
    if source is None:
        name = _DEFAULT_NAME if name is None else name
        src = fmu_source_dir(name)
        if not (src / _DESCRIPTIONS[2]).is_file():  # a system's folder
            raise FmuNotFoundError(f"{name} is a system of FMUs ({_SSD}), not one FMU: build it with "
                                   f"build_ssp({name!r})")
    else:
        src = pathlib.Path(source).expanduser().absolute()
        if not (src / _DESCRIPTIONS[2]).is_file():
            raise FmuNotFoundError(f"{src} is no FMU source folder: it has no {_DESCRIPTIONS[2]}; give the folder "
                                   f"holding the C source and the model descriptions")
        name = src.name if name is None else name
        _check_name(name)
    description = src / _DESCRIPTIONS[version]
    wrapper = _wrapper(src, version)
    for needed in (description, wrapper):
        if not needed.is_file():
            raise BuildError(f"{name} has no FMI {version} source: {needed.name} is missing from {src}")
    model_identifier = _model_identifier(description)
    platform = platform_info(version)
    compiler = find_compiler()
    version_line = compiler_version(compiler)

    c_files = [p for p in _c_sources(src) if p.name not in _WRAPPERS.values()] + [wrapper]
    key = _cache_key(src, version, platform, compiler, version_line, wrapper)
    root = pathlib.Path(cache_dir).expanduser().absolute() if cache_dir is not None else fmu_cache_dir()
    target_dir = root / "fmus" / f"{name}-fmi{version}-{key}"
    target = target_dir / f"{name}.fmu"
    if target.is_file() and not force and zipfile.is_zipfile(target):
        return target

    with tempfile.TemporaryDirectory(prefix="cosim-build-") as tmp:
        library = pathlib.Path(tmp) / (model_identifier + platform.extension)
        compile_library(compiler, c_files, [src], platform, library, what=f"{name} (FMI {version})")
        target_dir.mkdir(parents=True, exist_ok=True)
        _write_fmu_atomically(target, description, library, platform, src, c_files, version, model_identifier)
    return target


def build_ssp(
    name: str = _DEFAULT_SYSTEM,
    *,
    fmi_version: str = "2.0",
    cache_dir: str | os.PathLike[str] | None = None,
    force: bool = False,
) -> pathlib.Path:
    """Build a bundled system of FMUs into an SSP (once): each component FMU from its C source, then the package.

    The system's folder (``fmus/<name>/``) holds ``SystemStructure.ssd`` (SSP 1.0) and, for each component
    whose ``source`` is ``resources/<id>.fmu``, the FMU source folder ``<id>/``. Each component is built by
    :func:`build_fmu` (and cached like any FMU), then the ``.ssd`` and the FMUs are packed as
    ``SystemStructure.ssd`` and ``resources/<id>.fmu`` into a zip written atomically (a temporary file, then a
    rename).

    Parameters
    ----------
    name : str
        Name of the bundled system, default ``"two_mass_servo_split"`` (the two-mass servo as a motor FMU and
        a shaft-and-load FMU).
    fmi_version : str
        ``"2.0"`` or ``"3.0"`` (``"2"`` and ``"3"`` are accepted too): the FMI version of every component.
    cache_dir : str or os.PathLike, optional
        Root of the cache; default :func:`fmu_cache_dir`.
    force : bool
        Rebuild the components and repack, even if the cache already holds this build.

    Returns
    -------
    pathlib.Path
        ``<cache>/fmus/<name>-fmi<2|3>-<key>/<name>.ssp``; the key covers the files of the system's folder (the
        ``.ssd``) and the cache keys of the components (their sources, the FMI version, the platform, the
        compiler and the FMI headers).

    Raises
    ------
    FmuNotFoundError
        If there is no bundled system of that name (a single FMU's name says to use :func:`build_fmu`).
    BuildError
        If a component's ``source`` is not ``resources/<id>.fmu`` with a source folder ``<id>/`` beside the
        ``.ssd``, the ``.ssd`` is not valid XML, or a component fails to compile.
    InvalidSettingError
        If ``fmi_version`` is not 2.0 or 3.0.

    Examples
    --------
    >>> import zipfile
    >>> from cosim.plant.build import build_ssp
    >>> path = build_ssp("two_mass_servo_split", fmi_version="2.0")  # compiles on first use only
    >>> path.name
    'two_mass_servo_split.ssp'
    >>> sorted(zipfile.ZipFile(path).namelist())
    ['SystemStructure.ssd', 'resources/motor.fmu', 'resources/shaft_load.fmu']
    >>> build_ssp("two_mass_servo_split") == path  # second call: the cached file
    True
    """
    version = _parse_fmi_version(fmi_version)
    src = fmu_source_dir(name)
    ssd = src / _SSD
    if not ssd.is_file():
        raise FmuNotFoundError(f"{name} is one FMU, not a system of FMUs (it has no {_SSD}): build it with "
                               f"build_fmu({name!r})")
    components = []
    for source in _ssd_component_sources(ssd):
        identifier = source[len("resources/"):-len(".fmu")]
        fmu = build_fmu(identifier, fmi_version=str(version), cache_dir=cache_dir, force=force,
                        source=src / identifier)
        components.append((source, fmu))

    # the key: the system folder's own files (the .ssd), and each component's cache key (its folder's name)
    parts = [("source:" + p.name, p.read_bytes()) for p in _source_files(src)]
    parts += [("component:" + source, fmu.parent.name.encode()) for source, fmu in components]
    parts.append(("builder", _BUILDER_FORMAT.encode()))
    digest = hashlib.sha256()
    for label, data in parts:
        digest.update(label.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    root = pathlib.Path(cache_dir).expanduser().absolute() if cache_dir is not None else fmu_cache_dir()
    target_dir = root / "fmus" / f"{name}-fmi{version}-{digest.hexdigest()[:16]}"
    target = target_dir / f"{name}.ssp"
    if target.is_file() and not force and zipfile.is_zipfile(target):
        return target
    target_dir.mkdir(parents=True, exist_ok=True)
    members = [(_SSD, ssd.read_bytes(), 0o644)] + [(source, fmu.read_bytes(), 0o644) for source, fmu in components]
    write_zip_atomically(target, members)
    return target


# --------------------------------------------------------------------------------------
# helpers


def _check_name(name: str) -> None:
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise InvalidSettingError(
            f"invalid FMU name {name!r}: expected an identifier such as 'two_mass_servo'"
        )


def _parse_fmi_version(fmi_version: str) -> int:
    text = str(fmi_version).strip()
    if text in ("2", "2.0"):
        return 2
    if text in ("3", "3.0"):
        return 3
    raise InvalidSettingError(f"fmi_version must be '2.0' or '3.0', got {fmi_version!r}")


def _as_path(resource: object) -> pathlib.Path | None:
    """A filesystem path for an importlib resource, or None (e.g. inside a zip)."""
    try:
        path = pathlib.Path(os.fspath(resource))  # type: ignore[arg-type]
    except TypeError:
        return None
    return path if path.exists() else None


def _package_resource() -> object | None:
    try:
        from importlib.resources import files

        return files("cosim.fmus")
    except Exception:  # not installed as a package (source checkout used in place)
        return None


def _candidate_dirs(name: str) -> list[pathlib.Path]:
    """Where the source of FMU `name` may be: installed package data first, then the checkout."""
    found: list[pathlib.Path] = []
    resource = _package_resource()
    if resource is not None:
        # joinpath on a namespace package's MultiplexedPath returns the matching real directory
        path = _as_path(resource.joinpath(name))  # type: ignore[attr-defined]
        if path is not None:
            found.append(path)
    found += [root / name for root in _fmu_roots()]
    return found


def _fmu_roots() -> list[pathlib.Path]:
    """Folders whose sub-folders are FMU sources."""
    roots: list[pathlib.Path] = []
    resource = _package_resource()
    if resource is not None:
        for part in getattr(resource, "_paths", None) or [resource]:  # MultiplexedPath holds several
            path = _as_path(part)
            if path is not None and path.is_dir():
                roots.append(path)
    fallback = pathlib.Path(__file__).resolve().parents[2] / "fmus"  # the checkout: cosim/plant/build.py
    if fallback.is_dir() and fallback not in roots:
        roots.append(fallback)
    return roots


def _is_source_folder(folder: pathlib.Path) -> bool:
    """An FMU's source folder (a modelDescription.xml) or a system's (a SystemStructure.ssd)."""
    return (folder / _DESCRIPTIONS[2]).is_file() or (folder / _SSD).is_file()


def _ssd_component_sources(ssd: pathlib.Path) -> list[str]:
    """The distinct ``resources/<id>.fmu`` sources of the components of a system's .ssd, each with its folder."""
    try:
        tree = ET.parse(ssd)
    except ET.ParseError as exc:
        raise BuildError(f"{ssd} is not valid XML: {exc}") from None
    sources: list[str] = []
    for component in tree.getroot().iter(_SSD_NS + "Component"):
        what = f"component {component.get('name')!r} of {ssd}"
        if component.get("type", _FMU_MIME) != _FMU_MIME:
            raise BuildError(f"{what} is of type {component.get('type')!r}: only FMUs ({_FMU_MIME}) are built")
        source = component.get("source") or ""
        identifier = source[len("resources/"):-len(".fmu")] if re.fullmatch(r"resources/\w+\.fmu", source) else ""
        if not _NAME_RE.fullmatch(identifier) or not (ssd.parent / identifier / _DESCRIPTIONS[2]).is_file():
            raise BuildError(f"{what} has source={source!r}: expected 'resources/<id>.fmu' with the FMU's source "
                             f"folder <id>/ (a {_DESCRIPTIONS[2]}) beside the .ssd")
        if source not in sources:
            sources.append(source)
    if not sources:
        raise BuildError(f"{ssd} has no components: nothing to build")
    return sources


def _wrapper(src: pathlib.Path, version: int) -> pathlib.Path:
    """The FMI `version` wrapper of a source folder: its own ``fmi2.c``/``fmi3.c``, else its parent folder's (a
    family of FMUs written against one ``model.h`` interface shares one wrapper: the split servo's two FMUs, the
    tests' loop FMUs)."""
    own = src / _WRAPPERS[version]
    shared = src.parent / _WRAPPERS[version]
    return own if own.is_file() or not shared.is_file() else shared


def _c_sources(src: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for p in src.iterdir() if p.is_file() and p.suffix == ".c")


def _headers(src: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for p in src.iterdir() if p.is_file() and p.suffix == ".h")


def _build_description(model_identifier: str, c_files: list[pathlib.Path]) -> str:
    """sources/buildDescription.xml of an FMI 3.0 FMU: how an importer recompiles it."""
    files = "\n".join(f'      <SourceFile name="{p.name}"/>' for p in c_files)
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<fmiBuildDescription fmiVersion="3.0">\n'
        f'  <BuildConfiguration modelIdentifier="{model_identifier}">\n'
        '    <SourceFileSet language="C99">\n'
        f"{files}\n"
        "    </SourceFileSet>\n"
        "  </BuildConfiguration>\n"
        "</fmiBuildDescription>\n"
    )


def _source_files(src: pathlib.Path) -> list[pathlib.Path]:
    """Every file of the source folder that goes into the cache key."""
    return sorted(
        p for p in src.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix != ".pyc"
    )


def _model_identifier(description: pathlib.Path) -> str:
    try:
        tree = ET.parse(description)
    except ET.ParseError as exc:
        raise BuildError(f"{description} is not valid XML: {exc}") from None
    node = tree.getroot().find("CoSimulation")
    identifier = node.get("modelIdentifier") if node is not None else None
    if not identifier or not _NAME_RE.fullmatch(identifier):
        raise BuildError(f"{description} has no valid CoSimulation modelIdentifier")
    return identifier


def _cache_key(
    src: pathlib.Path, version: int, platform: Platform, compiler: list[str], compiler_version: str,
    wrapper: pathlib.Path | None = None,
) -> str:
    digest = hashlib.sha256()

    def add(label: str, data: bytes) -> None:
        digest.update(label.encode() + b"\0" + len(data).to_bytes(8, "little") + data)

    for path in _source_files(src):
        add("source:" + path.name, path.read_bytes())
    if wrapper is not None and wrapper.parent != src:  # a shared wrapper, from the parent folder
        add("wrapper:" + wrapper.name, wrapper.read_bytes())
    for path in platform.header_files:
        add("header:" + path.name, path.read_bytes())
    add("fmi", str(version).encode())
    add("platform", f"{platform.folder} {platform.extension} {sys.platform}".encode())
    add("compiler", " ".join([pathlib.Path(compiler[0]).name, *compiler[1:], compiler_version]).encode())
    add("flags", " ".join(CFLAGS).encode())
    add("builder", _BUILDER_FORMAT.encode())
    return digest.hexdigest()[:16]


def _write_fmu_atomically(
    target: pathlib.Path,
    description: pathlib.Path,
    library: pathlib.Path,
    platform: Platform,
    src: pathlib.Path,
    c_files: list[pathlib.Path],
    version: int,
    model_identifier: str,
) -> None:
    members: list[tuple[str, bytes, int]] = [
        ("modelDescription.xml", description.read_bytes(), 0o644),
        (f"binaries/{platform.folder}/{library.name}", library.read_bytes(), 0o755),
    ]
    members += [(f"sources/{p.name}", p.read_bytes(), 0o644) for p in (*c_files, *_headers(src))]
    if version == 3:
        members.append(("sources/buildDescription.xml", _build_description(model_identifier, c_files).encode(), 0o644))
    write_zip_atomically(target, members)
