"""The MPC step's C build and call (private to :mod:`controllers.mpc`).

* :func:`compile_function` generates the C source of a casadi Function (the step of
  :func:`~controllers.mpc._qp.step_function`), keys it by a SHA-256 over the source, the compiler, the
  flags, the casadi version and the static solver library, and compiles it (once) into
  ``fmu_cache_dir()/"mpc"/<name>-<key>.so`` with the project's compiler helpers. The library is built in a
  temporary folder beside its final place and renamed into place: a crash never leaves a half-written
  library, two processes building at once both succeed;
* :class:`BoundFunction` loads the library with the work arrays and the argument / result pointer arrays
  prepared once, so that a call is one foreign-function call.

Only DAQP (``libdaqpstat.a`` and headers shipped in casadi's wheels) and casadi's own ``qrqp`` can be compiled;
:func:`codegen_support` says why not otherwise. Called through casadi's Python API a step costs several times
more, mostly interpreter and conversion overhead.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import pathlib
import sys
import tempfile
from collections.abc import Sequence

import casadi as ca
import numpy as np

from cosim.errors import BuildError
from cosim.plant.build import fmu_cache_dir
from cosim.plant.toolchain import CFLAGS, Platform, compile_library, compiler_version, find_compiler

__all__ = ["BoundFunction", "codegen_support", "compile_function"]

_FORMAT = "1"  # bump when the way libraries are built changes
_CODEGEN_SOLVERS = {"daqp": "libdaqpstat.a", "qrqp": None}
# the generated code marks its entry points CASADI_SYMBOL_EXPORT, which is empty unless this is defined;
# the project's flags compile with -fvisibility=hidden
_WRAPPER = "#define GCC_HASCLASSVISIBILITY 1\n#include \"{source}\"\n"


def _casadi_dir() -> pathlib.Path:
    return pathlib.Path(ca.__file__).resolve().parent


def _extension() -> str:
    if sys.platform.startswith("win") or sys.platform == "cygwin":
        return ".dll"
    return ".dylib" if sys.platform == "darwin" else ".so"


def codegen_support(solver: str) -> tuple[list[pathlib.Path], str]:
    """Static libraries to link for `solver`, and ``""``; or ``[]`` and the reason it cannot be compiled."""
    if solver not in _CODEGEN_SOLVERS:
        return [], f"casadi cannot generate C for the QP solver {solver!r} (only {sorted(_CODEGEN_SOLVERS)})"
    name = _CODEGEN_SOLVERS[solver]
    if name is None:
        return [], ""
    lib = _casadi_dir() / name
    if not lib.is_file():
        return [], f"{name} is not shipped with this casadi installation ({_casadi_dir()})"
    if not (_casadi_dir() / "include" / solver).is_dir():
        return [], f"the {solver} headers are not shipped with this casadi installation"
    return [lib], ""


def compile_function(fun: ca.Function, static_libs: Sequence[pathlib.Path],
                     cache_dir: pathlib.Path | None = None) -> pathlib.Path:
    """Generate C for `fun`, compile it with `static_libs` into the cache (if not there yet), return the path.

    Raises
    ------
    BuildError
        If no C compiler is found or the compilation fails.
    """
    root = (cache_dir or fmu_cache_dir()) / "mpc"
    root.mkdir(parents=True, exist_ok=True)
    compiler = find_compiler()
    version_line = compiler_version(compiler)
    generator = ca.CodeGenerator(f"{fun.name()}.c", {"with_header": False})
    generator.add(fun)
    source = generator.dump().encode()
    key = _key(source, static_libs, compiler, version_line)
    target = root / f"{fun.name()}-{key}{_extension()}"
    if target.is_file():
        return target
    with tempfile.TemporaryDirectory(prefix=".mpc-build-", dir=root) as tmp:
        folder = pathlib.Path(tmp)
        source_name = f"{fun.name()}.c"
        (folder / source_name).write_bytes(source)
        wrapper = folder / "wrapper.c"
        wrapper.write_text(_WRAPPER.format(source=source_name), encoding="utf-8")
        platform = Platform(folder="", extension=_extension(), headers=_casadi_dir() / "include", header_files=())
        built = folder / f"build{_extension()}"
        compile_library(compiler, [wrapper, *static_libs], [folder], platform, built, what=f"MPC step {fun.name()}")
        os.chmod(built, 0o755)
        os.replace(built, target)  # same folder as the target: an atomic rename
    return target


def _key(source: bytes, static_libs: Sequence[pathlib.Path], compiler: list[str], version_line: str) -> str:
    digest = hashlib.sha256()

    def add(label: str, data: bytes) -> None:
        digest.update(label.encode() + b"\0" + len(data).to_bytes(8, "little") + data)

    add("source", source)
    add("wrapper", _WRAPPER.encode())
    for lib in static_libs:
        add("lib:" + lib.name, hashlib.sha256(lib.read_bytes()).digest())
    add("casadi", ca.__version__.encode())
    add("compiler", " ".join([pathlib.Path(compiler[0]).name, *compiler[1:], version_line]).encode())
    add("flags", " ".join(CFLAGS).encode())
    add("platform", sys.platform.encode())
    add("format", _FORMAT.encode())
    return digest.hexdigest()[:16]


class BoundFunction:
    """A compiled casadi Function called with numpy buffers bound once.

    Parameters
    ----------
    library : pathlib.Path
        The shared library from :func:`compile_function`.
    name : str
        The Function's name (its C entry point).
    bindings : sequence of (inputs, outputs)
        One or more sets of float64 C-contiguous arrays, one per Function input and output. Each set gets
        its own pointer arrays; :meth:`pointers` returns them for a call ``fn(arg, res, iw, w, 0)``.
    """

    def __init__(self, library: pathlib.Path, name: str,
                 bindings: Sequence[tuple[Sequence[np.ndarray], Sequence[np.ndarray]]]) -> None:
        # PyDLL keeps the GIL during the call: the library's static solver memory is never entered twice
        try:
            self._lib = ctypes.PyDLL(str(library))
        except OSError as exc:
            raise BuildError(f"cannot load the compiled MPC library {library}: {exc}") from None
        if ctypes.sizeof(ctypes.c_longlong) != 8:  # casadi_int is long long in the generated code
            raise BuildError("unsupported platform: long long is not 64 bits")
        work = getattr(self._lib, f"{name}_work")
        work.restype = ctypes.c_int
        sizes = [ctypes.c_longlong() for _ in range(4)]
        if work(*(ctypes.byref(s) for s in sizes)) != 0:
            raise BuildError(f"the compiled MPC library {library.name} reports no work sizes")
        sz_arg, sz_res, sz_iw, sz_w = (max(int(s.value), 1) for s in sizes)
        self.fn = getattr(self._lib, name)
        self.fn.restype = ctypes.c_int
        self.iw = (ctypes.c_longlong * sz_iw)()
        self.w = (ctypes.c_double * sz_w)()
        self._keep: list[np.ndarray] = []
        self._ptrs: list[tuple[ctypes.Array, ctypes.Array]] = []
        for inputs, outputs in bindings:
            arg = (ctypes.c_void_p * sz_arg)()
            res = (ctypes.c_void_p * sz_res)()
            for array_set, ptrs in ((inputs, arg), (outputs, res)):
                for i, a in enumerate(array_set):
                    if a.dtype != np.float64 or not a.flags.c_contiguous:
                        raise BuildError("internal: bound buffers must be contiguous float64 arrays")
                    ptrs[i] = a.ctypes.data
                    self._keep.append(a)
            self._ptrs.append((arg, res))
        self.library = library

    def pointers(self, index: int) -> tuple[ctypes.Array, ctypes.Array]:
        """The (arg, res) pointer arrays of binding set `index`."""
        return self._ptrs[index]
