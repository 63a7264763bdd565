"""The MPC's condensed QP and its step as one casadi Function (private to :mod:`controllers.mpc`).

* :class:`StepProblem` holds everything one MPC step needs, as plain matrices;
* :func:`condense` eliminates the states from the MPC problem it describes: a QP in the input moves (scaled to
  their range) and the slacks of soft constraints, with a constant Hessian (:class:`CondensedQP`);
* :func:`step_function` builds one casadi Function for a whole controller step (observer update, target,
  condensed QP solved by DAQP, first move clipped to the limits, constraint violation of the solution, next
  estimate and shifted plan), ``(meas, state) -> (out, state_next)`` with the positions of :class:`Layout`.

:mod:`controllers.mpc._codegen` compiles that Function to C and calls it.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["CondensedQP", "Layout", "StepProblem", "condense", "step_function"]


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
