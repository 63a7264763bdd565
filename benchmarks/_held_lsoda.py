"""One sample interval integrated by LSODA, bit for bit what ``solve_ivp(method="LSODA")`` gives, at about half
its cost: the independent simulators integrate every sample interval on its own (the input held), thousands
of intervals per run, and ``solve_ivp`` spent most of that time building a new solver for each.

:func:`lsoda_interval` drives one of SciPy's LSODA integrators (``scipy.integrate._ode.lsoda``, what
``solve_ivp``'s ``LSODA`` class drives) through exactly the calls that class makes: reset, the interval's end as
the critical time, one-step mode (``itask=5``) until the end is reached. Only the solver object is reused.
The private class is checked once, on first use; where it is missing or changed, the interval goes through
``solve_ivp`` itself (the same numbers, slower). ``tests/test_independent_plants.py`` checks that the two agree
to the last bit.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

try:  # private to SciPy: see the module's docstring for the fallback
    from scipy.integrate._ode import lsoda as _Lsoda
except ImportError:  # pragma: no cover - a SciPy without the class
    _Lsoda = None

_LOCAL = threading.local()  # one integrator per thread


def _integrator(rtol: float, atol: float) -> _Lsoda:
    key = (rtol, atol)
    cached = getattr(_LOCAL, "solvers", None)
    if cached is None:
        cached = _LOCAL.solvers = {}
    if key not in cached:
        cached[key] = _Lsoda(rtol=rtol, atol=np.asarray(atol), first_step=0.0)
    return cached[key]


def lsoda_interval(f: Callable[[float, np.ndarray], object], a: float, b: float, y: np.ndarray, *,
                   rtol: float, atol: float, max_step: float, min_step: float) -> np.ndarray:
    """The state at `b` from `y` at `a`: ``solve_ivp(f, (a, b), y, method="LSODA", rtol=rtol, atol=atol,
    max_step=max_step, min_step=min_step).y[:, -1]``, as a new array. Raises RuntimeError when LSODA fails."""
    if _fast():
        return _reused(f, a, b, y, rtol=rtol, atol=atol, max_step=max_step, min_step=min_step)
    return _by_solve_ivp(f, a, b, y, rtol=rtol, atol=atol, max_step=max_step, min_step=min_step)


def _reused(f: Callable[[float, np.ndarray], object], a: float, b: float, y: np.ndarray, *, rtol: float,
            atol: float, max_step: float, min_step: float) -> np.ndarray:
    solver = _integrator(rtol, atol)
    solver.max_step, solver.min_step = max_step, min_step
    state = np.asarray(y, dtype=float).copy()  # the C code writes into it
    solver.reset(len(state), False)
    solver.rwork[0] = b  # the critical time: never step past the interval's end
    solver.call_args[4] = solver.rwork
    solver.call_args[2] = 5  # one step at a time, as solve_ivp's LSODA steps
    # (Both checked by _fast: `f` goes to the C code as is, its sequence of floats converted there, without an
    # np.asarray a call; and the steps call the class's C routine with the arguments its `run` passes, without
    # that method's Python around each of the six or seven steps of an interval. One record: 0.8 times the time.
    # One call to the interval's end instead (itask 4) is faster still but not the same bits: records 89, 109.)
    rtol, atol, itask, istate, rwork, iwork, jt = solver.call_args
    t = a
    while t < b:
        state, t, istate = solver.runner(f, state, t, b, rtol, atol, itask, istate, rwork, iwork, _no_jacobian, jt,
                                         (), 1, (), solver.state_doubles, solver.state_ints)
        if istate < 0:
            raise RuntimeError(f"LSODA failed at t={t:.6g} (istate {istate})")
        istate = 2
    return state.copy()


def _no_jacobian():  # LSODA's Jacobian argument: never called (jt 2, a finite-difference Jacobian)
    return None


@functools.cache
def _fast() -> bool:
    """Whether the reused integrator gives solve_ivp's bits here (checked once, on a stiff switching system)."""
    if _Lsoda is None:
        return False

    def f(t, s):
        return (s[1], -4e4 * s[0] - 30.0 * s[1] - 5.0 * np.tanh(s[1] / 1e-3) + 100.0)

    opts = {"rtol": 1e-7, "atol": 1e-10, "max_step": 1e-3, "min_step": 1e-12}
    try:
        y = y_ref = np.zeros(2)
        for k in range(20):
            y = _reused(f, k * 1e-3, (k + 1) * 1e-3, y, **opts)
            y_ref = _by_solve_ivp(f, k * 1e-3, (k + 1) * 1e-3, y_ref, **opts)
    except Exception:  # a changed private class: the public path
        return False
    return bool(np.array_equal(y, y_ref))


def _by_solve_ivp(f: Callable[[float, np.ndarray], object], a: float, b: float, y: np.ndarray, *, rtol: float,
                  atol: float, max_step: float, min_step: float) -> np.ndarray:
    sol = solve_ivp(f, (a, b), y, method="LSODA", rtol=rtol, atol=atol, max_step=max_step, min_step=min_step)
    if not sol.success:
        raise RuntimeError(f"LSODA failed at t={a:.6g}: {sol.message}")
    return sol.y[:, -1].copy()
