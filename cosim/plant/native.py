"""Hand-written C compiled once per machine and kept in cosim's cache: :func:`compiled_c`.

A C `source` is hashed with the compiler's version, and its shared library kept under ``<cache>/jit/`` (the cache of
the bundled FMUs: ``$COSIM_CACHE_DIR``, else ``~/.cache/cosim``), written atomically, so that another process or a
later run loads it instead of compiling; at most :data:`MAX_LIBRARIES` are kept, the least recently used removed
first. Used by the system master's C loop (:mod:`cosim.plant.system_plant`) and, through
:mod:`cosim.identify._jit`, by CasADi functions compiled to machine code. Written by hand because neither CasADi
nor ctypes keeps a persistent cache of compiled code.
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

__all__ = ["COMPILE_TIMEOUT_S", "MAX_LIBRARIES", "compiled_c", "library", "prune"]

#: Seconds a compilation may take.
COMPILE_TIMEOUT_S = 120
#: Most shared libraries kept (about 145 kB each on average, so at most about 150 MB): after a new one is compiled,
#: the least recently used beyond this many are removed (a library is marked used each time it is loaded). The test
#: suite alone uses 288 structures; at 256 kept, an LRU cache that holds a little less than the working set evicts
#: each library shortly before it is needed again, and the suite took 499 s of wall time instead of 432 s
#: (2-core AMD EPYC, a cold cache, 2026-12-01).
MAX_LIBRARIES = 1024


def compiled_c(source: str, name: str) -> ctypes.CDLL | None:
    """Hand-written C `source` compiled (once per machine, kept in the cache) and loaded with ctypes, or
    None where that cannot be done: the caller then runs its NumPy version."""
    if sys.platform.startswith("win"):
        return None
    try:
        return ctypes.CDLL(str(library(source.encode(), name)))
    except Exception:  # noqa: BLE001 - no compiler, no cache folder, a failed build
        return None


@lru_cache(maxsize=4)
def _compiler(cc: str) -> tuple[tuple[str, ...], str]:
    """The compiler command and its version, asked once a process (a run of ``cc --version``, about 2 ms, at each
    of a diagnosis's hundreds of lookups before). `cc` is ``$CC``, read by ``find_compiler``: the cache's key."""
    from .toolchain import compiler_version, find_compiler

    compiler = find_compiler()
    return tuple(compiler), compiler_version(compiler)


def library(source: bytes, name: str) -> Path:
    """The shared library of C `source`, from the cache or compiled into it (atomically); raises where it cannot."""
    from .build import fmu_cache_dir

    compiler, version = _compiler(os.environ.get("CC", ""))
    key = hashlib.sha256(source + version.encode()).hexdigest()[:24]
    folder = fmu_cache_dir() / "jit"
    library = folder / f"{name}_{key}.so"
    if library.is_file():
        os.utime(library)  # used now: the last to be pruned
        return library
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
