"""Linear MPC: condensed QP solved by DAQP inside one casadi Function, compiled to C and called through ctypes.

Each call of :class:`MPC` does, in one compiled function:

1. **observer** - a steady-state Kalman filter (or a given Luenberger gain) on the model augmented with
   constant disturbances, so that unmeasured states (e.g. velocities when only encoders are read) and the
   disturbances are estimated;
2. **target** - the steady state ``(xs, us)`` at which the tracked outputs equal the setpoint under the
   estimated disturbance (offset-free tracking);
3. **condensed QP** over ``N`` moves: stage cost on the state and input deviations from the target and on
   the input rate, terminal cost from the discrete algebraic Riccati equation, input and input-rate bounds,
   soft (or hard) state constraints; solved by DAQP;
4. the first move, clipped to the bounds, and the prediction of the next estimate.

The function is generated as C by casadi, compiled once into ``fmu_cache_dir()/"mpc"`` and called with
numpy buffers bound once: 5-10 microseconds per call for N = 20 (benchmarks/results/mpc_speed.md). Without a
C compiler (or with ``codegen=False``) the same function is evaluated through casadi's Python API instead
(slower, same result).
Inputs are held between calls (zero-order hold) and ``t = t0 + k*dt`` as everywhere in cosim.

The pieces: :class:`MPC` and its calling convention in :mod:`controllers.mpc.controller`; the design from the
settings (weights, terminal cost, disturbance model and observer gain, target map, state constraints, input
scaling) in :mod:`controllers.mpc._design`; the condensed QP and the step Function in :mod:`controllers.mpc._qp`;
its C build and call in :mod:`controllers.mpc._codegen`.
"""

from __future__ import annotations

from ._design import DEFAULT_OBSERVER, DEFAULT_WEIGHTS
from .controller import MPC

__all__ = ["MPC", "DEFAULT_WEIGHTS", "DEFAULT_OBSERVER"]
