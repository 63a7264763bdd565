"""CasADi functions as machine code, compiled once per machine and kept in cosim's cache.

CasADi's own JIT (``{"jit": True}``) compiles in every process again: 0.2 s a model structure, about 1.8 s of
a 12 s diagnosis. Here the function's generated C is hashed and its shared library kept under
``<cache>/jit/`` (the cache of the bundled FMUs: ``$COSIM_CACHE_DIR``, else ``~/.cache/cosim``), written
atomically, so that another process or a later run loads it instead of compiling; at most
:data:`MAX_LIBRARIES` are kept, the least recently used removed first. Written by hand because CasADi has no
persistent cache of compiled functions.

A structure is compiled only once its runs have cost what compiling it would (:class:`Tiered`): most model
structures a diagnosis tries run a few dozen chunks, less than a second's compilation is worth, and compiling
every one took a third of a diagnosis with a cold cache (record 5 of the generalisation benchmark: 3.5 of
10.5 s). The compiled and the interpreted function give the same bits, so where the switch falls changes no
result (``tests/test_screening_speedups.py``).
"""

from __future__ import annotations

import atexit
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


#: The cost model of :class:`Tiered`, measured on a 2-core AMD EPYC with gcc -O1 (2026-12-05): compiling a
#: function costs about ``COMPILE_S + COMPILE_S_PER_INSTRUCTION * instructions`` of its step (0.3-0.4 s for a
#: two-mass RK4 step of 190-360 instructions, 0.5-1.2 s for its sensitivities' step of 2100-4700), and CasADi's
#: interpreter about ``INTERPRETED_S_PER_INSTRUCTION`` an instruction and step (1.0-1.9 ms a 1024-step chunk
#: of the RK4 steps, 12-25 ms of the sensitivities'), about six times the compiled code's time.
COMPILE_S = 0.25
COMPILE_S_PER_INSTRUCTION = 1.5e-4
INTERPRETED_S_PER_INSTRUCTION = 5.5e-9
#: Most structures whose interpreted steps are remembered in the cache (``<library>.steps``, a few bytes each).
MAX_REMEMBERED = 8 * MAX_LIBRARIES

_pending: dict[Path, int] = {}  # steps interpreted in this process, per structure's count file, not written yet


class Tiered:
    """A CasADi function evaluated by CasADi's interpreter until the steps it has run would have paid for its
    compilation, then compiled (the ski-rental rule: never much more than twice the cheaper of the two choices,
    whatever the number of runs to come); loaded at once where the cache already holds it.

    `instructions` is the size of one step of the function (``n_instructions()`` of the function mapped over a
    chunk), from which :data:`COMPILE_S` and its neighbours give the steps that pay for a compilation. The steps
    are counted across processes (kept beside the libraries, written when a process ends), so that a structure
    every diagnosis runs a little is compiled once, as a structure one diagnosis runs much is. The count is of
    steps, not of seconds, so that when a structure is compiled does not depend on the machine's load."""

    def __init__(self, interpreted, name: str, instructions: int):
        self.interpreted, self.name = interpreted, name
        size = max(int(instructions), 1)
        self.budget = (COMPILE_S + COMPILE_S_PER_INSTRUCTION * size) / (INTERPRETED_S_PER_INSTRUCTION * size)
        self.compiled = None
        self._source = self._library = None
        self.steps = 0
        try:
            self._source = _c_source(interpreted, name)
            self._library = _library_path(self._source, name)
        except Exception:  # noqa: BLE001 - no compiler (or Windows): the interpreter runs it
            return
        if self._library.is_file():
            self.compiled = _loaded(self._library, name)
        if self.compiled is None:
            self.steps = _remembered(self._counts())

    def pick(self, steps: int):
        """The function to run `steps` more steps with: the compiled one once the steps so far (these included,
        and those of earlier processes) reach the budget and a C compiler works, else the interpreted one."""
        if self.compiled is None and self._library is not None:
            self.steps += steps
            counts = self._counts()
            _pending[counts] = _pending.get(counts, 0) + steps
            if self.steps >= self.budget:
                library, self._library = self._library, None  # one attempt
                _pending.pop(counts, None)
                counts.unlink(missing_ok=True)
                if not library.is_file():  # (another process may have built it meanwhile)
                    try:
                        _build(self._source, library, self.name)
                    except Exception:  # noqa: BLE001 - a failed build: the interpreter runs it
                        return self.interpreted
                self.compiled = _loaded(library, self.name)
        return self.interpreted if self.compiled is None else self.compiled

    def _counts(self) -> Path:
        return self._library.with_suffix(".steps")


def compiled(function, name: str, build: bool = True):
    """`function` (a CasADi Function) loaded from a compiled shared library, or None where that cannot be done
    (no C compiler, Windows, a failed build; with ``build=False``, also where the cache does not hold it yet):
    the caller then evaluates `function` itself."""
    try:
        source = _c_source(function, name)
        library = _library_path(source, name)
        if not library.is_file():
            if not build:
                return None
            _build(source, library, name)
        return _load(library, name)
    except Exception:  # noqa: BLE001 - no compiler, no cache folder, a failed build: the interpreter runs it
        return None


def compiled_c(source: str, name: str) -> ctypes.CDLL | None:
    """Hand-written C `source` compiled (as :func:`compiled`'s, cached the same way) and loaded with ctypes, or
    None where that cannot be done: the caller then runs its NumPy version."""
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


def _loaded(library: Path, name: str):
    """:func:`_load`, or None where the library cannot be loaded (removed by a concurrent prune, damaged)."""
    try:
        return _load(library, name)
    except Exception:  # noqa: BLE001 - the interpreter runs it
        return None


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


def _remembered(counts: Path) -> int:
    try:
        return int(counts.read_text())
    except (OSError, ValueError):
        return 0


@atexit.register
def _remember() -> None:
    """Add this process's interpreted steps to each structure's count in the cache (best effort: a count lost to
    a concurrent process or a full disk only delays a compilation)."""
    for counts, steps in list(_pending.items()):
        try:
            counts.parent.mkdir(parents=True, exist_ok=True)
            fd, partial = tempfile.mkstemp(dir=counts.parent, prefix=".", suffix=".steps.tmp")
            with os.fdopen(fd, "w") as out:
                out.write(str(_remembered(counts) + steps))
            os.replace(partial, counts)
        except OSError:
            pass
    folders = {counts.parent for counts in _pending}
    _pending.clear()
    for folder in folders:
        prune(folder, MAX_REMEMBERED, "*.steps")


def prune(folder: Path, keep: int, pattern: str = "*.so") -> list[Path]:
    """Remove all but the `keep` most recently used shared libraries of `folder` (by modification time, which a
    load refreshes; or the files matching `pattern`); returns the removed ones. A library another process has
    loaded stays mapped there."""
    libraries = sorted(folder.glob(pattern), key=lambda p: p.stat().st_mtime, reverse=True)
    removed = []
    for path in libraries[keep:]:
        try:
            path.unlink()
            removed.append(path)
        except OSError:  # removed by a concurrent prune, or not ours to remove
            pass
    return removed
