"""CasADi functions as machine code, compiled once per machine and kept in cosim's cache.

CasADi's own JIT (``{"jit": True}``) compiles in every process again: 0.2 s a model structure, about 1.8 s of
a 12 s diagnosis. Here the function's generated C is hashed and its shared library kept under
``<cache>/jit/`` (the cache of the bundled FMUs: ``$COSIM_CACHE_DIR``, else ``~/.cache/cosim``), written
atomically, so that another process or a later run loads it instead of compiling; at most
:data:`MAX_LIBRARIES` are kept, the least recently used removed first. Written by hand because CasADi has no
persistent cache of compiled functions. The cache itself is the plant room's (:mod:`cosim.plant.native`), shared
with the hand-written C of the system master.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from ..plant.native import COMPILE_TIMEOUT_S, MAX_LIBRARIES, compiled_c, prune
from ..plant.native import library as _library

__all__ = ["COMPILE_TIMEOUT_S", "MAX_LIBRARIES", "compiled", "compiled_c", "prune"]


def compiled(function, name: str):
    """`function` (a CasADi Function) loaded from a compiled shared library, or None where that cannot be done
    (no C compiler, Windows, a failed build): the caller then evaluates `function` itself."""
    import casadi as ca

    if sys.platform.startswith("win"):
        return None
    try:
        with tempfile.TemporaryDirectory() as tmp:
            generator = ca.CodeGenerator(f"{name}.c")
            generator.add(function)
            generator.generate(tmp + os.sep)
            library = _library(Path(tmp, f"{name}.c").read_bytes(), name)
        return ca.external(name, str(library))
    except Exception:  # noqa: BLE001 - no compiler, no cache folder, a failed build: the interpreter runs it
        return None


