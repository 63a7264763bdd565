"""A real, simple controller for loop tests: discrete LQR on the full measured state of the bundled plant."""

import time

import control
import numpy as np

from controllers.base import Controller, DesignModel
from cosim.study.paper import STATES, two_mass_matrices

DT = 1 / 2257


def true_model() -> control.StateSpace:
    a, b = two_mass_matrices()
    return control.ss(a, b, np.eye(4), 0, states=list(STATES), inputs=["Tm", "TL"], outputs=list(STATES))


class StateFeedback(Controller):
    """LQR on the full measured state with a reference pre-filter: a real, simple controller for the loop tests."""

    kind = "test-state-feedback"

    def __init__(self, *, fail_at: float | None = None, nan_at: float | None = None, slow_every: int = 0,
                 overshoot_limits: bool = False) -> None:
        super().__init__(dt=DT, inputs=["Tm"], outputs=list(STATES), tracked=["theta_L"], u_min=-5000, u_max=5000)
        self.design_model = DesignModel.from_statespace(true_model(), dt=DT)
        a, b = self.design_model.A, self.design_model.B[:, :1]
        self.k, _, _ = control.dlqr(a, b, np.diag([1e6, 1.0, 1e8, 10.0]), np.array([[1e-2]]))
        self.fail_at, self.nan_at, self.slow_every, self.loose = fail_at, nan_at, slow_every, overshoot_limits
        self.reset()

    def reset(self) -> None:
        self.calls = 0
        self.events.clear()

    def __call__(self, t, y):
        self.calls += 1
        if self.fail_at is not None and t >= self.fail_at:
            raise RuntimeError("solver exploded")
        if self.nan_at is not None and t >= self.nan_at:
            return np.array([np.nan])
        if self.slow_every and self.calls % self.slow_every == 0:
            time.sleep(1.5 * self.dt)
        r = self.setpoint[0]
        x_ref = np.array([r, 0.0, r, 0.0])
        u = -(self.k @ (np.asarray(y) - x_ref))
        return u if self.loose else np.clip(u, self.u_min, self.u_max)

    def _settings(self):
        return {}
