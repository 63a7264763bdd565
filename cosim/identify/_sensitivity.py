"""Exact free-run sensitivities of a model with nonlinear terms, for the output-error refinement.

:func:`~cosim.identify.output_error.refine_output_error` differentiated a nonlinear model's free run by forward
differences: one more simulation per parameter, each stepped sample by sample in NumPy. With a few nonlinear
terms beside a two-mass model's linear ones (20-odd coefficients and initial states) one Jacobian took about
0.4 s on a 4000-sample record, and a multi-start refinement a minute or more.

Here the RK4 step of the model (the same arithmetic as the forward-difference path's) is built as a CasADi
expression together with its derivatives, and the sensitivities are carried with the state:
``S[k+1] = dF/dx S[k] + dF/dc``, ``S[0] = [0 | I]`` (coefficients on the support, then the initial state), the
step and its sensitivity stepped :data:`~cosim.identify.terms._CASADI_CHUNK` samples a call (``mapaccum``).
The derivatives are exact (no step size to choose) and a Jacobian costs about one simulation; on records of a
chunk or more the chunk runs compiled to machine code, as the plain run does. Written by hand
around CasADi because it has no integrator with sensitivities for a fixed-step, zero-order-hold discrete run
that is cheaper than this (its ``integrator`` plugins are adaptive and per call).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .model import DIVERGENCE_LIMIT, IdentifiedModel
from .terms import _CASADI_CHUNK, _JIT_MIN_STEPS, FUNCTIONS, _chunked_run, _emit


def free_run_sensitivities(model: IdentifiedModel, coef: np.ndarray, support: np.ndarray, x0: np.ndarray,
                           u: np.ndarray, dt: float, steps: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The free run of `model` with coefficients `coef` from `x0` over `steps` samples of the inputs `u`
    (zero-order hold, one RK4 step a sample), and its sensitivities.

    Returns ``(states, sens)``: states of shape (steps+1, n_x), the first `x0`; sens of shape
    (steps+1, n_x, n_c + n_x), the derivative of each state with respect to the coefficients on `support`
    (in ``np.argwhere(support)`` order) and then to the initial state. None when the run diverges.

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> m = IdentifiedModel(states=("x",), inputs=(), terms=("x", "sin(x)"), coef=np.array([[-1.0, 0.5]]))
    >>> states, sens = free_run_sensitivities(m, m.coef, m.coef != 0, np.array([1.0]), np.zeros((3, 0)), 0.1, 3)
    >>> states.shape, sens.shape
    ((4, 1), (4, 1, 3))
    """
    n, m = len(model.states), len(model.inputs)
    numbers: list[float] = []
    names = {**{name: f"x[{i}]" for i, name in enumerate(model.states)},
             **{name: f"u[{j}]" for j, name in enumerate(model.inputs)}}
    sources = tuple(_emit(term._tree.body, names, "python", numbers) for term in model._parsed)
    support = np.asarray(support, dtype=bool)
    run = _sensitivity_chunk(n, m, sources, len(numbers), len(model.terms), support.tobytes(),
                             jit=steps >= _JIT_MIN_STEPS)
    q = int(support.sum()) + n
    z0 = np.concatenate([np.asarray(x0, dtype=float), np.hstack([np.zeros((n, q - n)), np.eye(n)]).ravel("F")])
    rows = np.asarray(u, dtype=float).reshape(len(u), m)[:steps]
    if steps == 0:
        return z0[None, :n], z0[n:].reshape(1, q, n).transpose(0, 2, 1)
    status, _, out = _chunked_run(run, (dt, np.asarray(coef, dtype=float).ravel(), np.asarray(numbers, float)),
                                  z0, rows, DIVERGENCE_LIMIT)
    if status != "ok":
        return None
    z = np.vstack([z0, out])
    return z[:, :n], z[:, n:].reshape(len(z), q, n).transpose(0, 2, 1)


@lru_cache(maxsize=64)  # a compiled structure holds its interpreted one too
def _sensitivity_chunk(n: int, m: int, sources: tuple[str, ...], n_numbers: int, n_terms: int,
                       support_bytes: bytes, jit: bool = False):
    """The chunked run of the state and its sensitivities for one model structure and support (cached).

    With `jit`, compiled to machine code (:mod:`._jit`) where a C compiler works: the same bits as CasADi's
    interpreter, a sixth of its time a call (a two-mass model with a cogging and a Stribeck friction, 22
    sensitivities, 4000 samples: 81 -> 13.5 ms), 0.8 s to compile a structure the first time on a machine, then
    loaded from the cache. For records of a chunk or more, as the plain run (:data:`~.terms._JIT_MIN_STEPS`)."""
    if jit:
        from ._jit import compiled

        interpreted = _sensitivity_chunk(n, m, sources, n_numbers, n_terms, support_bytes)
        return compiled(interpreted, "cosim_sens") or interpreted
    import casadi as ca

    support = np.frombuffer(support_bytes, dtype=bool).reshape(n, n_terms)
    chosen = np.flatnonzero(support.ravel()).tolist()  # row-major: np.argwhere's order
    q = len(chosen) + n
    x, u, h = ca.SX.sym("x", n), ca.SX.sym("u", m), ca.SX.sym("h")
    c, k = ca.SX.sym("c", n * n_terms), ca.SX.sym("k", n_numbers)
    sens = ca.SX.sym("S", n, q)
    namespace = {f"_f_{name}": getattr(ca, {"abs": "fabs"}.get(name, name)) for name in FUNCTIONS}
    code = [compile(src, "<cosim term>", "eval") for src in sources]
    coef = ca.reshape(c, n_terms, n).T  # (CasADi reshapes column-major: the transpose of the row-major coef)

    def rhs(s):
        local = {"x": [s[i] for i in range(n)], "u": [u[j] for j in range(m)],
                 "k": [k[i] for i in range(n_numbers)]}
        terms = ca.vertcat(*[ca.SX(eval(c_, namespace, local)) for c_ in code])  # from checked ASTs only
        return ca.mtimes(coef, terms)

    a = rhs(x)  # the arithmetic of the forward-difference path's RK4 step
    b = rhs(x + 0.5 * h * a)
    c3 = rhs(x + 0.5 * h * b)
    d = rhs(x + h * c3)
    nxt = x + h / 6.0 * (a + 2.0 * b + 2.0 * c3 + d)
    moved = ca.mtimes(ca.jacobian(nxt, x), sens) + ca.horzcat(ca.jacobian(nxt, c)[:, chosen], ca.SX.zeros(n, n))
    z = ca.vertcat(x, ca.vec(sens))
    step = ca.Function("cosim_sens_step", [z, u, h, c, k], [ca.vertcat(nxt, ca.vec(moved))])
    mapped = step.mapaccum("cosim_sens_run", _CASADI_CHUNK, [0], [0])
    zs, us = ca.MX.sym("z", n + n * q), ca.MX.sym("u", m, _CASADI_CHUNK)
    hs, cs, ks = ca.MX.sym("h"), ca.MX.sym("c", n * n_terms), ca.MX.sym("k", n_numbers)
    return ca.Function("cosim_sens", [zs, us, hs, cs, ks], [mapped(zs, us, hs, cs, ks)])
