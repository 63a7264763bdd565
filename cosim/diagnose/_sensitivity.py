"""The free-run sensitivity recursion ``s[k+1] = M[k] s[k] + g[k]`` over many columns, in blocks of time.

:class:`~cosim.diagnose.screening.OutputErrorScreen` integrates the sensitivities of a free run to each
coefficient, initial state and candidate term: ``M[k] = Ad + Gamma dJ[k]`` (the zero-order-hold step of the
model's linear part plus its time-varying rest, held over the sample; ``M[k] = Ad`` for a linear model) and
``g[k] = Gamma f[k]`` (the forcing). Stepped sample by sample it costs a handful of NumPy calls on 4 x m
matrices per sample, 20 000 samples a record: the calls, not the arithmetic, take the time (as long for
one column as for a hundred).

:class:`Propagator` cuts the record into ``B`` blocks of ``L`` samples (``B L >= N``) and runs the
recursion in three passes, the first and last over all blocks at once (a scan in blocks):

1. every block from a zero state, all blocks stepped together (``L`` batched products of ``B`` small
   matrices);
2. the state at each block start, block after block: ``c[b+1] = Psi[b, L-1] c[b] + local[b, L-1]``, with
   ``Psi[b, j] = M[bL+j] ... M[bL]`` the block's transition matrices (they depend on the model only, so they
   are computed once per free run);
3. ``s[bL+j+1] = local[b, j] + Psi[b, j] c[b]``, one batched product.

About ``2 sqrt(N)`` NumPy calls instead of ``5 N``. The sums are associated differently from the
sample-by-sample loop, so the result differs from it by rounding only (relative 1e-14 for a linear model,
1e-13 with a friction term, on the two-mass servo; :func:`propagate_stepwise` is that loop, the reference the
tests compare with). Written by hand rather than generated with CasADi (``mapaccum``): its virtual machine
steps one sample per call too, at some nanoseconds per scalar operation, slower than NumPy's batched
products for more than a few columns.

Where a C compiler works (the one the bundled FMUs are built with), the recursion runs sample by sample in a
small C loop instead (:data:`_C_SOURCE`, compiled once per machine into cosim's cache): on EMPS (two states,
25 000 samples) a tenth of the block scan's time, and its sums are associated the same way on every machine
(no BLAS call, whose kernel picks its own order). Its result is :func:`propagate_stepwise`'s to rounding (both
step sample by sample), the block scan's to 1e-13.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

#: ``out[k+1] += M[k] out[k]`` for k < steps: `out` holds the forcing ``g[k]`` at row k+1 and the start at row 0
#: on entry, the sensitivities on exit; ``M[k]`` is ``trans + k * stride`` (stride 0: one matrix for all steps).
#: Each entry's products are summed in one order (l = 0..n-1), then added to the forcing, as the block scan does.
_C_SOURCE = """
void cosim_propagate(long steps, long n, long m, const double *trans, long stride, double *out) {
    for (long k = 0; k < steps; ++k) {
        const double *M = trans + k * stride, *s = out + k * n * m;
        double *next = out + (k + 1) * n * m;
        for (long i = 0; i < n; ++i)
            for (long j = 0; j < m; ++j) {
                double acc = 0.0;
                for (long l = 0; l < n; ++l)
                    acc += M[i * n + l] * s[l * m + j];
                next[i * m + j] += acc;
            }
    }
}
"""

_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


@lru_cache(maxsize=1)
def _c_propagate():
    """The compiled loop, or None where no C compiler works (the block scan runs then)."""
    from ..identify._jit import compiled_c

    library = compiled_c(_C_SOURCE, "cosim_propagate")
    if library is None:
        return None
    function = library.cosim_propagate
    function.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_long, _DOUBLE_P, ctypes.c_long, _DOUBLE_P]
    function.restype = None
    return function


class Propagator:
    """``s[k+1] = (Ad + Gamma dJ[k]) s[k] + Gamma f[k]`` for ``steps`` samples (`delta_j` None: ``dJ = 0``)."""

    def __init__(self, ad: np.ndarray, gamma: np.ndarray, delta_j: np.ndarray | None, steps: int) -> None:
        n = ad.shape[0]
        self.ad, self.gamma, self.steps, self.n = ad, gamma, int(steps), n
        self._loop = _c_propagate()
        if self._loop is not None:  # the C loop steps sample by sample: only each step's matrix is needed
            self.L, self.B = 1, self.steps  # (the buffers' length)
            # what the loop reads, made once (a screen runs it for every group of columns)
            if delta_j is None:
                self._matrices, self._stride = np.ascontiguousarray(ad, dtype=float), 0
            else:
                self._matrices, self._stride = np.matmul(gamma, delta_j[:self.steps]), n * n
                self._matrices += ad
            return
        # passes 1 and 3 cost ~L batched calls, pass 2 ~N/L small ones (cheaper each)
        self.L = max(1, min(self.steps, int(math.sqrt(self.steps / 2.0)) + 1))
        self.B = -(-self.steps // self.L)
        L, B, total = self.L, self.B, self.L * self.B
        if delta_j is None:
            self.trans = None
            self.psi = np.empty((L, n, n))
            self.psi[0] = ad
            for j in range(1, L):
                np.matmul(ad, self.psi[j - 1], out=self.psi[j])
            self.last = np.broadcast_to(self.psi[-1], (B, n, n))
        else:
            trans = np.empty((total, n, n))
            np.matmul(gamma, delta_j[:self.steps], out=trans[:self.steps])
            trans[:self.steps] += ad
            trans[self.steps:] = np.eye(n)  # padding after the last sample: its values are dropped
            self.trans = trans.reshape(B, L, n, n)
            self.psi = np.empty((B, L, n, n))
            self.psi[:, 0] = self.trans[:, 0]
            for j in range(1, L):
                np.matmul(self.trans[:, j], self.psi[:, j - 1], out=self.psi[:, j])
            self.last = self.psi[:, -1]

    def integrate(self, forcing: np.ndarray, s0: np.ndarray | None = None) -> np.ndarray:
        """Sensitivities for a dense forcing (steps, n, m) from s0 (n, m): (steps+1, n, m)."""
        m = forcing.shape[2]
        out, g = self._buffer(m)
        np.matmul(self.gamma, forcing, out=g[:self.steps])
        return self._run(out, s0)

    def integrate_columns(self, rows: Sequence[int], values: np.ndarray, s0: np.ndarray | None = None,
                          ) -> np.ndarray:
        """Sensitivities when column c is forced in state `rows[c]` only, by ``values[:, c]`` (steps, m).

        The same numbers as :meth:`integrate` on the dense forcing (its other entries are zeros), without
        building it.
        """
        out, g = self._buffer(values.shape[1])
        np.multiply(self.gamma[:, list(rows)][None], values[:, None, :], out=g[:self.steps])
        return self._run(out, s0)

    def _buffer(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        out = np.empty((self.B * self.L + 1, self.n, m))
        out[self.steps + 1:] = 0.0
        return out, out[1:]

    def _run(self, out: np.ndarray, s0: np.ndarray | None) -> np.ndarray:
        n, m, B, L = self.n, out.shape[2], self.B, self.L
        out[0] = 0.0 if s0 is None else s0
        if self.steps == 0:
            return out[:1]
        if self._loop is not None:
            self._loop(self.steps, n, m, self._matrices.ctypes.data_as(_DOUBLE_P), self._stride,
                       out.ctypes.data_as(_DOUBLE_P))
            return out[:self.steps + 1]
        g = out[1:].reshape(B, L, n, m)
        step = np.empty((B, n, m))
        for j in range(1, L):  # pass 1: every block from zero, all blocks at once
            np.matmul(self.ad if self.trans is None else self.trans[:, j], g[:, j - 1], out=step)
            g[:, j] += step
        carry = np.empty((B, n, m))  # pass 2: the state at each block start
        carry[0] = out[0]
        for b in range(B - 1):
            np.matmul(self.last[b], carry[b], out=carry[b + 1])
            carry[b + 1] += g[b, -1]
        # pass 3: each block's start state carried through it
        if self.trans is None:  # one (L n, n) @ (n, B m) product
            g += np.tensordot(self.psi, carry, axes=([2], [1])).transpose(2, 0, 1, 3)
        else:
            g += np.matmul(self.psi, carry[:, None])
        return out[:self.steps + 1]


def propagate_stepwise(ad: np.ndarray, gamma: np.ndarray, delta_j: np.ndarray | None, forcing: np.ndarray,
                       s0: np.ndarray | None = None) -> np.ndarray:
    """The same recursion sample by sample (the reference of :class:`Propagator`; slow)."""
    steps, n, m = forcing.shape
    out = np.empty((steps + 1, n, m))
    s = np.zeros((n, m)) if s0 is None else np.array(s0, dtype=float)
    out[0] = s
    for k in range(steps):
        s = ad @ s + gamma @ ((delta_j[k] @ s if delta_j is not None else 0.0) + forcing[k])
        out[k + 1] = s
    return out
