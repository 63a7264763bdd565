"""The MPC's machinery (private): the condensed QP, the one casadi Function per step, its C build and its call.

* :func:`condense` eliminates the states from the MPC problem described by a :class:`StepProblem`: a QP in the
  input moves (scaled to their range) and the slacks of soft constraints, with a constant Hessian;
* :func:`step_function` builds one casadi Function for a whole controller step (observer update, target,
  condensed QP solved by DAQP, first move clipped to the limits, constraint violation of the solution, next
  estimate and shifted plan), ``(meas, state) -> (out, state_next)`` with the positions of :class:`Layout`;
* :func:`compile_function` generates its C source, keys it by a SHA-256 over the source, the compiler, the
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
from dataclasses import dataclass

import casadi as ca
import numpy as np

from cosim.errors import BuildError
from cosim.plant.build import fmu_cache_dir
from cosim.plant.toolchain import CFLAGS, Platform, compile_library, compiler_version, find_compiler

__all__ = ["BoundFunction", "CondensedQP", "Layout", "StepProblem", "codegen_support", "compile_function", "condense",
           "step_function"]

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


# ---------------------------------------------------------------------------------------------------------------
# the condensed QP and the step Function


@dataclass(frozen=True)
class StepProblem:
    """Everything one MPC step needs, as plain matrices (built and checked by :class:`controllers.mpc.MPC`).

    Observer on the augmented model ``xa = [x; d]``: ``xa+ = Ao xa + Bo u + eo``, ``y = Co xa + fo``, filter
    gain ``L``. Target ``[xs; us] = T [r; d] + t0``. Stage cost ``dx'Q dx + du'R du + ddu'S ddu`` on the
    deviations from the target, terminal cost ``[dx_N; du_N-1]' P [dx_N; du_N-1]``. Constraints on
    ``c x + c0`` for each row of `cons` (soft unless `hard`).
    """

    Ao: np.ndarray
    Bo: np.ndarray
    eo: np.ndarray
    Co: np.ndarray
    fo: np.ndarray
    L: np.ndarray
    T: np.ndarray
    t0: np.ndarray
    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    S: np.ndarray
    P: np.ndarray
    N: int
    u_min: np.ndarray
    u_max: np.ndarray
    du_max: np.ndarray
    u_scale: np.ndarray
    cons: tuple[tuple[np.ndarray, float, float, float], ...]
    hard: bool
    soft_linear: float
    soft_quadratic: float
    solver: str


@dataclass(frozen=True)
class Layout:
    """Positions in the step Function's vectors: ``meas = [y; r]``, ``state = [xa_prior; u_prev; plan]``,
    ``out = [u; violation; xa_filtered; xs; us]``."""

    p: int
    nt: int
    na: int
    n: int
    m: int
    N: int

    @property
    def n_meas(self) -> int:
        return self.p + self.nt

    @property
    def n_state(self) -> int:
        return self.na + self.m + self.N * self.m

    @property
    def n_out(self) -> int:
        return self.m + 1 + self.na + self.n + self.m


@dataclass(frozen=True)
class CondensedQP:
    """``min 1/2 z'Hz + g'z`` with ``g = G [dx0; du_prev] + g0``, ``lbx <= z <= ubx`` (input part shifted by
    the target), ``lb0 - F [dx0; du_prev; xs] <= Ac z <= ub0 - F [...]``. ``U = D z[:N m] + us``."""

    H: np.ndarray
    G: np.ndarray
    g0: np.ndarray
    Ac: np.ndarray
    lb0: np.ndarray
    ub0: np.ndarray
    F: np.ndarray
    D: np.ndarray
    n_slack: int
    cost_scale: float


def condense(sp: StepProblem) -> CondensedQP:
    """Eliminate the states: the QP in the (scaled) input moves, slacks appended."""
    A, B, N = sp.A, sp.B, sp.N
    n, m = B.shape
    nu = N * m
    nw = n + m + nu  # w = [dx0; du_prev; v]
    sx = np.hstack([np.eye(n), np.zeros((n, m + nu))])
    su_prev = np.zeros((m, nw))
    su_prev[:, n:n + m] = np.eye(m)
    W = np.zeros((nw, nw))
    predictions = []
    for k in range(N):
        su = np.zeros((m, nw))
        su[:, n + m + k * m:n + m + (k + 1) * m] = np.eye(m)
        dsu = su - su_prev
        W += sx.T @ sp.Q @ sx + su.T @ sp.R @ su + dsu.T @ sp.S @ dsu
        sx = A @ sx + B @ su
        predictions.append(sx)
        su_prev = su
    z_end = np.vstack([sx, su_prev])
    W += z_end.T @ sp.P @ z_end
    W = (W + W.T) / 2
    D = np.tile(sp.u_scale, N)
    H = 2 * D[:, None] * W[n + m:, n + m:] * D[None, :]
    G = 2 * D[:, None] * W[n + m:, :n + m]
    cost_scale = float(np.max(np.diag(H)))
    H, G = H / cost_scale, G / cost_scale
    rows: list[tuple[np.ndarray, int, float]] = []  # (coefficients of v, slack index or -1, slack sign)
    lb0: list[float] = []
    ub0: list[float] = []
    F: list[np.ndarray] = []
    # input-rate rows: |u_0 - u_prev| <= du, |u_k - u_k-1| <= du
    for i in np.flatnonzero(np.isfinite(sp.du_max)):
        for k in range(N):
            a = np.zeros(nu)
            a[k * m + i] = D[k * m + i]
            f = np.zeros(n + m + n)
            if k:
                a[(k - 1) * m + i] = -D[(k - 1) * m + i]
            else:
                f[n + i] = -1.0  # v_0 - du_prev in [-du, du]: the bounds move with du_prev
            rows.append((a, -1, 0.0))
            lb0.append(-sp.du_max[i])
            ub0.append(sp.du_max[i])
            F.append(f)
    n_slack = 0 if sp.hard else len(sp.cons)
    # state rows: c x_k + c0 = c (xs + Sx_k w) + c0 in [lo, hi] for k = 1..N; soft: one slack per constraint
    sides = [(0, 1, 0.0)] if sp.hard else [(0, None, 1.0), (None, 1, -1.0)]  # which bound, slack sign
    for j, (c, c0, lo, hi) in enumerate(sp.cons):
        for sx in predictions:
            a = c @ sx[:, n + m:] * D
            f = np.concatenate([c @ sx[:, :n + m], c])
            for low_i, high_i, sign in sides:
                low = (lo, hi)[low_i] if low_i is not None else -np.inf
                high = (lo, hi)[high_i] if high_i is not None else np.inf
                if not (np.isfinite(low) or np.isfinite(high)):
                    continue
                rows.append((a, -1 if sp.hard else j, sign))
                lb0.append(low - c0)
                ub0.append(high - c0)
                F.append(f)
    nv = nu + n_slack
    Ac = np.zeros((len(rows), nv))
    slack_scale = float(np.sqrt(cost_scale / (2 * sp.soft_quadratic))) if n_slack else 1.0
    for k, (a, j, sign) in enumerate(rows):
        Ac[k, :nu] = a
        if j >= 0:
            Ac[k, nu + j] = sign * slack_scale
    F_arr = np.array(F).reshape(len(rows), 2 * n + m)
    lb_arr, ub_arr = np.array(lb0, dtype=float), np.array(ub0, dtype=float)
    norms = np.linalg.norm(Ac, axis=1) if len(rows) else np.zeros(0)
    norms[norms == 0] = 1.0
    Ac, F_arr, lb_arr, ub_arr = (Ac / norms[:, None], F_arr / norms[:, None], lb_arr / norms, ub_arr / norms)
    H_full = np.zeros((nv, nv))
    H_full[:nu, :nu] = H
    g0 = np.zeros(nv)
    if n_slack:  # rho1 s + rho2 s^2 with s = slack_scale zeta, in units of the scaled cost
        H_full[nu:, nu:] = np.eye(n_slack) * 2 * sp.soft_quadratic * slack_scale ** 2 / cost_scale
        g0[nu:] = sp.soft_linear * slack_scale / cost_scale
    G_full = np.zeros((nv, n + m))
    G_full[:nu] = G
    return CondensedQP(H=(H_full + H_full.T) / 2, G=G_full, g0=g0, Ac=Ac, lb0=lb_arr, ub0=ub_arr, F=F_arr, D=D,
                       n_slack=n_slack, cost_scale=cost_scale)


def step_function(sp: StepProblem, qp: CondensedQP, name: str) -> tuple[ca.Function, Layout]:
    """One casadi Function for a whole controller step: ``(meas, state) -> (out, state_next)``.

    1. filter: ``xa = xa_prior + L (y - Co xa_prior - fo)``;
    2. target ``[xs; us]`` from the setpoint and the disturbance estimate;
    3. condensed QP in the deviations from the target (`qp`), solved by ``sp.solver``;
    4. ``u`` = first move clipped to the bounds and the rate bound around ``u_prev``;
    5. largest constraint violation of the solution (NaN or inf if anything was not finite);
    6. prediction ``xa_prior+ = Ao xa + Bo u + eo`` and the plan shifted by one move.
    """
    n, m = sp.B.shape
    na, p, N = sp.Ao.shape[0], sp.Co.shape[0], sp.N
    nt = sp.T.shape[1] - (na - n)
    lay = Layout(p=p, nt=nt, na=na, n=n, m=m, N=N)
    nu = N * m
    DM = ca.DM
    meas = ca.MX.sym("meas", lay.n_meas)
    state = ca.MX.sym("state", lay.n_state)
    y, r = meas[:p, 0], meas[p:, 0]
    xa_prior, u_prev, plan = state[:na, 0], state[na:na + m, 0], state[na + m:, 0]
    xa = xa_prior + ca.mtimes(DM(sp.L), y - ca.mtimes(DM(sp.Co), xa_prior) - DM(sp.fo))
    x, d = xa[:n, 0], xa[n:, 0]
    target = ca.mtimes(DM(sp.T), ca.vertcat(r, d)) + DM(sp.t0)
    xs, us = target[:n, 0], target[n:, 0]
    dp = ca.vertcat(x - xs, u_prev - us)
    g = ca.mtimes(DM(qp.G), dp) + DM(qp.g0)
    US = ca.repmat(us, N, 1)
    Dv = DM(qp.D)
    lbx = ca.vertcat((DM(np.tile(sp.u_min, N)) - US) / Dv, DM.zeros(qp.n_slack))
    ubx = ca.vertcat((DM(np.tile(sp.u_max, N)) - US) / Dv, DM.inf(qp.n_slack))
    Fq = ca.mtimes(DM(qp.F), ca.vertcat(dp, xs)) if qp.Ac.shape[0] else DM.zeros(0)
    lba, uba = DM(qp.lb0) - Fq, DM(qp.ub0) - Fq
    z0 = ca.vertcat((plan - US) / Dv, DM.zeros(qp.n_slack))  # the shifted plan as primal start
    H, Ac = DM(qp.H), DM(qp.Ac)
    solver = ca.conic(f"{name}_qp", sp.solver, {"h": H.sparsity(), "a": Ac.sparsity()},
                      {"error_on_fail": True, "print_time": False, "verbose": False})
    sol = solver(h=H, g=g, a=Ac, lba=lba, uba=uba, lbx=lbx, ubx=ubx, x0=z0)
    z = sol["x"]
    U = Dv * z[:nu, 0] + US
    lo = ca.fmax(DM(sp.u_min), u_prev - DM(sp.du_max))
    hi = ca.fmin(DM(sp.u_max), u_prev + DM(sp.du_max))
    u = ca.fmin(ca.fmax(U[:m, 0], lo), hi)
    parts = [lbx - z, z - ubx]
    if qp.Ac.shape[0]:
        az = ca.mtimes(Ac, z)
        parts += [lba - az, az - uba]
    # fmax ignores NaN: the tiny product carries any NaN or inf of the step into the violation
    violation = ca.fmax(ca.mmax(ca.vertcat(*parts)), 0) + 1e-300 * (ca.dot(z, z) + ca.dot(xa, xa) + ca.dot(us, us))
    xa_next = ca.mtimes(DM(sp.Ao), xa) + ca.mtimes(DM(sp.Bo), u) + DM(sp.eo)
    plan_next = ca.vertcat(U[m:, 0], U[nu - m:, 0]) if N > 1 else U
    out = ca.vertcat(u, violation, xa, xs, us)
    fun = ca.Function(name, [meas, state], [out, ca.vertcat(xa_next, u, plan_next)], ["meas", "state"],
                      ["out", "state_next"])
    return fun, lay
