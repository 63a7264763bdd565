"""Compile-and-pack machinery shared by the bundled plant FMUs (:mod:`cosim.plant.build`) and the FMUs generated
from identified models (:mod:`cosim.export`): compiler lookup, flags, the FMI headers of fmpy, the shared
library build, and the reproducible zip archive written atomically.

Private: the public entries are :func:`cosim.plant.build.build_fmu` and :func:`cosim.export.export_fmu`.
"""

from __future__ import annotations

import os
import pathlib
import shlex
import shutil
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass

from cosim.errors import BuildError

__all__ = [
    "CFLAGS",
    "COMPILE_TIMEOUT_S",
    "Platform",
    "compile_and_pack",
    "compile_library",
    "compiler_version",
    "find_compiler",
    "platform_info",
    "write_zip",
    "write_zip_atomically",
]

CFLAGS = ("-std=c99", "-O2", "-ffp-contract=off", "-fvisibility=hidden", "-shared")
COMPILE_TIMEOUT_S = 300
ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamps: same inputs, same archive

#: One member of an FMU archive: (name in the archive, content, Unix mode).
Member = tuple[str, bytes, int]


@dataclass(frozen=True)
class Platform:
    folder: str  # binaries/<folder>/
    extension: str  # .so, .dylib, .dll
    headers: pathlib.Path  # fmpy's c-code folder with the FMI headers
    header_files: tuple[pathlib.Path, ...]  # the headers of this FMI version


def platform_info(version: int) -> Platform:
    """Binary folder, library extension and FMI headers (from fmpy) for FMI `version` (2 or 3)."""
    import fmpy

    headers = pathlib.Path(fmpy.__file__).resolve().parent / "c-code"
    names = (
        ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
        if version == 2
        else ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
    )
    header_files = tuple(headers / n for n in names)
    missing = [p.name for p in header_files if not p.is_file()]
    if missing:
        raise BuildError(
            f"FMI {version} headers {', '.join(missing)} not found in {headers}: "
            "reinstall fmpy (pip install fmpy)"
        )
    folder = fmpy.platform if version == 2 else fmpy.platform_tuple
    return Platform(folder=folder, extension=fmpy.sharedLibraryExtension, headers=headers, header_files=header_files)


def find_compiler() -> list[str]:
    """The C compiler command: ``$CC`` (split like a shell would), else ``cc``, else ``gcc``."""
    candidates: list[list[str]] = []
    cc = os.environ.get("CC", "").strip()
    if cc:
        try:
            words = shlex.split(cc)
        except ValueError:
            words = [cc]
        if words:
            candidates.append(words)
    candidates += [["cc"], ["gcc"]]
    for words in candidates:
        exe = shutil.which(words[0])
        if exe:
            return [exe, *words[1:]]
    raise BuildError("no C compiler found: install gcc or set CC")


def compiler_version(compiler: list[str]) -> str:
    """First line of ``<compiler> --version`` (part of the cache key of bundled FMUs)."""
    try:
        out = subprocess.run(
            [*compiler, "--version"], capture_output=True, text=True, timeout=60, check=False
        )
    except (OSError, subprocess.SubprocessError) as exc:
        raise BuildError(f"cannot run the C compiler {compiler[0]}: {exc}; install gcc or set CC") from None
    lines = (out.stdout or out.stderr).strip().splitlines()
    return lines[0] if lines else "unknown"


def compile_library(
    compiler: list[str],
    c_files: Sequence[pathlib.Path],
    include_dirs: Sequence[pathlib.Path],
    platform: Platform,
    library: pathlib.Path,
    *,
    what: str,
) -> None:
    """Compile `c_files` into the shared library `library` (FMI headers on the include path).

    `what` names the build in error messages, e.g. ``"two_mass_servo (FMI 2)"``.
    """
    windows = sys.platform.startswith("win") or sys.platform == "cygwin"
    cmd = [*compiler, *CFLAGS]
    if not windows:
        cmd.append("-fPIC")
    cmd += ["-I", str(platform.headers)]
    for folder in include_dirs:
        cmd += ["-I", str(folder)]
    cmd += [*map(str, c_files), "-o", str(library)]
    if not windows:
        cmd.append("-lm")
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        raise BuildError(f"compiling {what} with {compiler[0]} took longer than {COMPILE_TIMEOUT_S} s") from None
    except OSError as exc:
        raise BuildError(f"cannot run the C compiler {compiler[0]}: {exc}; install gcc or set CC") from None
    if proc.returncode != 0 or not library.is_file():
        output = (proc.stderr or "") + (proc.stdout or "")
        lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
        errors = [ln for ln in lines if "error" in ln.lower()] or lines
        detail = " | ".join(errors[:3]) or f"exit status {proc.returncode}"
        raise BuildError(f"compiling {what} with {compiler[0]} failed: {detail}")


def write_zip(fh, members: Sequence[Member]) -> None:
    """Write `members` into the open binary file `fh` as a deflated zip with fixed timestamps."""
    with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for arcname, data, mode in members:
            info = zipfile.ZipInfo(arcname, date_time=ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o100000 | mode) << 16
            zf.writestr(info, data)


def write_zip_atomically(target: pathlib.Path, members: Sequence[Member], *, mode: int = 0o644) -> None:
    """Zip `members` into a temporary file beside `target`, flush it to disk, then rename it onto `target`."""
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.stem}-", suffix=".fmu.tmp")
    tmp = pathlib.Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as fh:
            write_zip(fh, members)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)  # mkstemp made it private; the cache may be shared (COSIM_CACHE_DIR)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def compile_and_pack(path: str | os.PathLike, *, identifier: str, description: bytes, sources: dict[str, str],
                     compiled: Sequence[str], include_dirs: Sequence[pathlib.Path] = (),
                     libraries: Sequence[pathlib.Path] = (), what: str) -> pathlib.Path:
    """An FMI 2.0 FMU from generated C: `sources` (file name -> text) written to a temporary folder, the `compiled`
    ones built with the project's flags (and static `libraries`) into the binary, packed with `description` as
    ``modelDescription.xml`` and the sources under ``sources/``, written atomically to `path`. What the exported
    model FMU (:mod:`cosim.export.fmu`) and the controllers' FMUs (``controllers.pid.fmu``, ``controllers.mpc.fmu``)
    share."""
    from cosim.files import atomic_output

    path = pathlib.Path(path)
    platform = platform_info(2)
    with tempfile.TemporaryDirectory(prefix="cosim-fmu-") as tmp:
        folder = pathlib.Path(tmp)
        for name, text in sources.items():
            (folder / name).write_text(text, encoding="utf-8")
        library = folder / (identifier + platform.extension)
        compile_library(find_compiler(), [*(folder / name for name in compiled), *libraries],
                        [folder, *include_dirs], platform, library, what=what)
        members = [("modelDescription.xml", description, 0o644),
                   (f"binaries/{platform.folder}/{library.name}", library.read_bytes(), 0o755)]
        members += [(f"sources/{name}", text.encode("utf-8"), 0o644) for name, text in sources.items()]
        with atomic_output(path) as out, open(out, "wb") as fh:
            write_zip(fh, members)
    return path
