"""The linear free run of the output-error refinement, without a Python loop over the samples.

:func:`simulate_linear_batch` steps ``x[k+1] = ad x[k] + bd u[k] + cd`` by :func:`_scan`, a blocked scan, and
:func:`_expm_batch` discretises a stack of small matrices at once; :mod:`cosim.identify.output_error` builds its
residuals and exact Jacobian of a linear model on them (and exports :func:`simulate_linear_batch`). Written by
hand: NumPy and SciPy have no scan of a linear recursion, and SciPy's ``expm`` costs milliseconds per small
matrix.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["simulate_linear_batch"]


def _scan(ad: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Solve ``y[0] = s[0], y[k] = ad @ y[k-1] + s[k]`` along axis 0 by a scan in blocks.

    `s` has shape (n+1, ..., n_x); ``ad`` (n_x, n_x) acts on the last axis. The steps are cut into ``B``
    blocks of ``L ~ sqrt(n)``: every block is run from zero, all blocks at once (``L`` batched products);
    then the state entering each block, block after block (``B`` small products); then each block's entering
    state carried through it by the powers of ``ad`` (one product). About ``2 sqrt(n)`` NumPy calls doing
    ``O(n)`` work, where a prefix scan (``log2 n`` passes over everything, used until 2026-11) did
    ``O(n log n)``: 2.4 times faster on a 20 000-sample record. The same recursion as
    :class:`cosim.diagnose._sensitivity.Propagator`'s for a linear model, on this module's layout.
    """
    y = np.array(s, dtype=float, copy=True)
    steps = y.shape[0] - 1
    if steps <= 0:
        return y
    ad = np.asarray(ad, dtype=float)
    size = max(1, math.isqrt(steps))
    blocks = -(-steps // size)
    tail = y.shape[1:]
    g = np.zeros((blocks * size, *tail))
    g[:steps] = y[1:]
    g = g.reshape(blocks, size, *tail)
    with np.errstate(over="ignore", invalid="ignore"):
        for j in range(1, size):  # every block from a zero state
            g[:, j] += g[:, j - 1] @ ad.T
        powers = np.empty((size, *ad.shape))  # ad^(j+1)
        powers[0] = ad
        for j in range(1, size):
            powers[j] = ad @ powers[j - 1]
        carry = np.empty((blocks, *tail))  # the state entering each block
        carry[0] = y[0]
        for b in range(blocks - 1):
            carry[b + 1] = carry[b] @ powers[-1].T + g[b, -1]
        g += np.moveaxis(np.tensordot(carry, powers, axes=([-1], [2])), -2, 1)
    y[1:] = g.reshape(blocks * size, *tail)[:steps]
    return y


def _expm_batch(m: np.ndarray) -> np.ndarray:
    """``expm`` of a stack of small matrices (shape (..., q, q)): scaling and squaring of a degree-16 Taylor
    polynomial, vectorised over the stack (scipy's ``expm`` costs milliseconds per small matrix).

    Each matrix is scaled by ``2^-s`` to a 1-norm of at most 1/4, where the truncation error of the series
    (``0.25^17/17!``) is below double precision, then squared ``s`` times.
    """
    norm = float(np.max(np.sum(np.abs(m), axis=-2))) if m.size else 0.0
    if not math.isfinite(norm):
        return np.full_like(m, np.nan)
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    a = m / 2.0 ** s
    eye = np.broadcast_to(np.eye(m.shape[-1]), m.shape)
    result = eye + a
    term = a
    for k in range(2, 17):
        term = term @ a / k
        result = result + term
    for _ in range(s):
        result = result @ result
    return result


def simulate_linear_batch(ad: np.ndarray, bd: np.ndarray, cd: np.ndarray, x0: np.ndarray,
                          u: np.ndarray) -> np.ndarray:
    """Free-run ``x[k+1] = ad x[k] + bd u[k] + cd`` from `x0` for ``len(u)`` steps, without a Python loop.

    Parameters
    ----------
    ad, bd, cd : ndarray
        Discrete-time matrices (see :meth:`IdentifiedModel.discretize`).
    x0 : ndarray, shape (n_x,)
    u : ndarray, shape (n, n_u)

    Returns
    -------
    ndarray, shape (n+1, n_x)
        Non-finite where the model diverges.

    Examples
    --------
    >>> import numpy as np
    >>> simulate_linear_batch(np.array([[0.5]]), np.array([[1.0]]), np.zeros(1), np.array([2.0]),
    ...                       np.ones((3, 1))).ravel().tolist()
    [2.0, 2.0, 2.0, 2.0]
    """
    s = np.empty((u.shape[0] + 1, ad.shape[0]))
    s[0] = x0
    s[1:] = u @ bd.T + cd
    return _scan(ad, s)
