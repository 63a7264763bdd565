"""CasADi functions as machine code, compiled once per machine and kept in cosim's cache.

CasADi's own JIT (``{"jit": True}``) compiles in every process again: 0.2 s a model structure, about 1.8 s of
a 12 s diagnosis. Here the function's generated C is hashed and its shared library kept under
``<cache>/jit/`` (the cache of the bundled FMUs: ``$COSIM_CACHE_DIR``, else ``~/.cache/cosim``), written
atomically, so that another process or a later run loads it instead of compiling; at most
:data:`MAX_LIBRARIES` are kept, the least recently used removed first. Written by hand because CasADi has no
persistent cache of compiled functions.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import sys
import tempfile
from functools import lru_cache
from pathlib import Path

#: Seconds a compilation may take.
COMPILE_TIMEOUT_S = 120
#: Most shared libraries kept (about 145 kB each on average, so at most about 150 MB): after a new one is compiled,
#: the least recently used beyond this many are removed (a library is marked used each time it is loaded). The test
#: suite alone uses 288 structures; at 256 kept, an LRU cache that holds a little less than the working set evicts
#: each library shortly before it is needed again, and the suite took 499 s of wall time instead of 432 s
#: (2-core AMD EPYC, a cold cache, 2026-12-01).
MAX_LIBRARIES = 1024


def compiled(function, name: str):
    """`function` (a CasADi Function) loaded from a compiled shared library, or None where that cannot be done
    (no C compiler, Windows, a failed build): the caller then evaluates `function` itself."""
    try:
        source = _c_source(function, name)
        library = _library_path(source, name)
        if not library.is_file():
            _build(source, library, name)
        return _load(library, name)
    except Exception:  # noqa: BLE001 - no compiler, no cache folder, a failed build: the interpreter runs it
        return None


def compiled_c(source: str, name: str) -> ctypes.CDLL | None:
    """Hand-written C `source` compiled (as :func:`compiled`'s, cached the same way) and loaded with ctypes, or
    None where that cannot be done: the caller then runs its NumPy version."""
    if sys.platform.startswith("win"):
        return None
    try:
        library = _library_path(source.encode(), name)
        if library.is_file():
            os.utime(library)  # used now: the last to be pruned
        else:
            _build(source.encode(), library, name)
        return ctypes.CDLL(str(library))
    except Exception:  # noqa: BLE001 - no compiler, no cache folder, a failed build
        return None


def _c_source(function, name: str) -> bytes:
    """The C code CasADi generates for `function` (named `name`); raises on Windows (no compiled path there)."""
    import casadi as ca

    if sys.platform.startswith("win"):
        raise OSError("no compiled functions on Windows")
    with tempfile.TemporaryDirectory() as tmp:
        generator = ca.CodeGenerator(f"{name}.c")
        generator.add(function)
        generator.generate(tmp + os.sep)
        return Path(tmp, f"{name}.c").read_bytes()


def _load(library: Path, name: str):
    import casadi as ca

    os.utime(library)  # used now: the last to be pruned
    return ca.external(name, str(library))


@lru_cache(maxsize=4)
def _compiler(cc: str) -> tuple[tuple[str, ...], str]:
    """The compiler command and its version (a process's, asked once: a run of ``cc --version`` a structure
    was about 2 ms each of a diagnosis's thousands of lookups). `cc` is ``$CC``, the cache's key."""
    from ..plant.toolchain import compiler_version, find_compiler

    compiler = find_compiler()
    return tuple(compiler), compiler_version(compiler)


def _library_path(source: bytes, name: str) -> Path:
    """Where the shared library of C `source` is (or would be) in the cache; raises without a C compiler."""
    from ..plant.build import fmu_cache_dir

    _, version = _compiler(os.environ.get("CC", ""))
    key = hashlib.sha256(source + version.encode()).hexdigest()[:24]
    return fmu_cache_dir() / "jit" / f"{name}_{key}.so"


def _build(source: bytes, library: Path, name: str) -> Path:
    """Compile C `source` into `library` (atomically), then prune the cache; raises where it cannot."""
    compiler, _ = _compiler(os.environ.get("CC", ""))
    folder = library.parent
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp, f"{name}.c")
        path.write_bytes(source)
        fd, partial = tempfile.mkstemp(dir=folder, prefix=f".{name}-", suffix=".so.tmp")
        os.close(fd)
        try:
            # no fused multiply-add: the same bits as Python's arithmetic on every machine
            subprocess.run([*compiler, "-O1", "-ffp-contract=off", "-shared", "-fPIC", str(path), "-o", partial,
                            "-lm"], capture_output=True, timeout=COMPILE_TIMEOUT_S, check=True)
            os.chmod(partial, 0o755)
            os.replace(partial, library)  # atomic: a concurrent process sees all of it or nothing
        finally:
            Path(partial).unlink(missing_ok=True)
    prune(folder, MAX_LIBRARIES)
    return library


def prune(folder: Path, keep: int) -> list[Path]:
    """Remove all but the `keep` most recently used shared libraries of `folder` (by modification time, which a
    load refreshes); returns the removed ones. A library another process has loaded stays mapped there."""
    libraries = sorted(folder.glob("*.so"), key=lambda p: p.stat().st_mtime, reverse=True)
    removed = []
    for path in libraries[keep:]:
        try:
            path.unlink()
            removed.append(path)
        except OSError:  # removed by a concurrent prune, or not ours to remove
            pass
    return removed
