"""A model's prediction of measured data, scored: :func:`compare` (MATLAB's ``compare``, SysIdentPy's
simulate-and-score).

The model is simulated with the record's inputs (zero-order hold) in free run, or `horizon` samples ahead from
every measured state, and each state is scored three ways, named the same everywhere in cosim (``cosim
identify``, ``cosim diagnose``, ``cosim compare`` and this module):

==============  ======================================================================  ==================
``fit_pct``     MATLAB's NRMSE fit, ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)``       100 is perfect
``nrmse_pct``   the normalised error, ``100 * ||y - yhat|| / ||y - mean(y)||``           0 is perfect
``r2``          coefficient of determination ``1 - SS_res / SS_tot``                    1 is perfect
==============  ======================================================================  ==================

``fit_pct + nrmse_pct = 100``. A free run starts from an initial state that is, by default, estimated from the
record (``x0="estimate"``: least squares on the free-run error, as MATLAB's ``compare`` does), so that a noisy
first sample does not decide the score; ``"measured"`` takes the first sample, ``"model"`` the initial state the
model was identified with (its training record's).

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-2.0, 1.0]]))
>>> data = model.simulate([0.5], np.ones((300, 1)), dt=0.01).to_trajectory()
>>> result = compare(model, data)
>>> round(result.fit_pct["x"], 6), round(result.x0["x"], 6)
(100.0, 0.5)
"""

from __future__ import annotations

import html
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..data.trajectory import Trajectory
from ..errors import DataError, InvalidSettingError, UnknownVariableError
from .metrics import k_step_ahead_predictions, nrmse_fit_pct, r2
from .model import IdentifiedModel

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = ["Comparison", "compare"]

X0_CHOICES = ("estimate", "measured", "model")
_GN_ITERATIONS = 8


@dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare`.

    Attributes
    ----------
    fit_pct, nrmse_pct, r2 : dict
        State name -> score (see the module docstring).
    horizon : int or None
        Samples ahead of each prediction; None for the free run.
    x0 : dict
        The free run's initial state (empty for a k-step-ahead prediction).
    measured, predicted : Trajectory
        The compared samples: the record's, and the model's prediction of them.
    """

    fit_pct: dict[str, float]
    nrmse_pct: dict[str, float]
    r2: dict[str, float]
    horizon: int | None
    x0: dict[str, float]
    measured: Trajectory = field(repr=False)
    predicted: Trajectory = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the scores per state, the horizon (None: free run) and the initial state."""
        clean = {key: {k: (v if math.isfinite(v) else None) for k, v in getattr(self, key).items()}
                 for key in ("fit_pct", "nrmse_pct", "r2")}
        return {**clean, "horizon": self.horizon, "x0": dict(self.x0),
                "samples": len(self.measured)}

    def plot(self, path: str | os.PathLike | None = None) -> matplotlib.figure.Figure:
        """Each state measured (thin, dark, on top) and predicted, with the error (measured minus model) under it.

        Parameters
        ----------
        path : path-like, optional
            Write the figure there as PNG too.

        Returns
        -------
        matplotlib.figure.Figure
        """
        from ..figures import COLOURS, FONT_SIZE, axis_label, finish, new_figure

        names = list(self.fit_pct)
        fig = new_figure(figsize=(9, 2.4 * len(names) + 0.8), layout="constrained")
        axes = fig.subplots(2 * len(names), 1, sharex=True, squeeze=False,
                            gridspec_kw={"height_ratios": [3, 1] * len(names)})[:, 0]
        t = self.measured.time
        for i, name in enumerate(names):
            unit = self.measured.units[self.measured.names.index(name)]
            top, bottom = axes[2 * i], axes[2 * i + 1]
            top.plot(t, self.predicted[name], color=COLOURS["model"], lw=1.6, alpha=0.85, zorder=2,
                     label=f"model (fit {self.fit_pct[name]:.1f} %)")
            top.plot(t, self.measured[name], color=COLOURS["measured"], lw=0.7, zorder=3, label="measured")
            top.set_ylabel(axis_label(name, unit), fontsize=FONT_SIZE)
            top.legend(fontsize=FONT_SIZE, loc="upper right")
            bottom.plot(t, self.measured[name] - self.predicted[name], color=COLOURS["model"], lw=0.8)
            bottom.axhline(0.0, color=COLOURS["reference"], lw=0.5)
            bottom.set_ylabel(axis_label("error", unit), fontsize=FONT_SIZE)
            for ax in (top, bottom):
                ax.grid(alpha=0.3)
        axes[-1].set_xlabel("time [s]", fontsize=FONT_SIZE + 1)
        what = "free run" if self.horizon is None else f"{self.horizon}-step-ahead prediction"
        fig.suptitle(f"model against data: {what}", fontsize=FONT_SIZE + 2)
        return finish(fig, path)

    def _repr_html_(self) -> str:
        rows = "".join(f"<tr><td>{html.escape(n)}</td><td>{self.fit_pct[n]:.2f}</td><td>{self.nrmse_pct[n]:.2f}"
                       f"</td><td>{self.r2[n]:.5f}</td></tr>" for n in self.fit_pct)
        what = "free run" if self.horizon is None else f"{self.horizon}-step-ahead"
        return (f"<table><caption>model against data ({what}, {len(self.measured)} samples)</caption>"
                "<tr><th>state</th><th>fit %</th><th>NRMSE %</th><th>R²</th></tr>" + rows + "</table>")


def compare(model: Any, data: Trajectory, *, horizon: int | None = None,
            x0: str | Mapping[str, float] | Sequence[float] = "estimate") -> Comparison:
    """Predict `data` with `model` (free run, or `horizon` samples ahead) and score it per state.

    Parameters
    ----------
    model : IdentifiedModel or fitted SINDYc
        The model; `data` must hold its states and inputs by name, uniformly sampled.
    data : Trajectory
        The record to predict.
    horizon : int, optional
        Predict each sample from the measured state `horizon` samples before (``1 <= horizon < samples``);
        default the free run.
    x0 : {"estimate", "measured", "model"} or mapping or sequence
        The free run's initial state: estimated from the record (default), its first sample, the model's own
        (identified with it), or given by value.

    Returns
    -------
    Comparison

    Raises
    ------
    UnknownVariableError
        `data` lacks a state or input of the model.
    InvalidSettingError, DataError
        A bad `horizon` or `x0`; data that are not uniformly sampled.
    """
    model = getattr(model, "model_", model)
    if not isinstance(model, IdentifiedModel):
        raise InvalidSettingError(f"expected an IdentifiedModel or a fitted SINDYc, got {type(model).__name__}")
    missing = [n for n in (*model.states, *model.inputs) if n not in data.names]
    if missing:
        raise UnknownVariableError(f"the data lack {', '.join(missing)} of the model; present: "
                                   f"{', '.join(data.names)}; name the columns as the model does")
    if len(data) < 3 or not data.is_uniform():
        raise DataError("compare needs at least 3 uniformly sampled rows; resample the record first")
    states, dt = list(model.states), data.dt
    x = np.asarray(data[states], dtype=float).reshape(len(data), -1)
    u = np.asarray(data[list(model.inputs)], dtype=float).reshape(len(data), -1) if model.inputs else None
    if horizon is None:
        start = _initial_state(model, x, u, dt, x0)
        sim = model.simulate(start, None if u is None else u[:-1], dt=dt, n_steps=len(data) - 1)
        predicted, first, start_of = sim.states, 0, dict(zip(states, start.tolist(), strict=True))
    else:
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or not 1 <= horizon < len(data):
            raise InvalidSettingError(f"horizon must be a whole number of samples in 1..{len(data) - 1}, "
                                      f"got {horizon!r}")
        predicted = k_step_ahead_predictions(model, x, u, dt, int(horizon))
        first, start_of = int(horizon), {}
    measured = x[first:]
    ok = np.all(np.isfinite(predicted), axis=1)
    if ok.all():
        fit = np.atleast_1d(nrmse_fit_pct(measured, predicted))
        rr = np.atleast_1d(r2(measured, predicted))
    else:  # a prediction that left the model's range scores as badly as can be
        fit, rr = np.full(len(states), -math.inf), np.full(len(states), -math.inf)
    keep = data.select([*states, *model.inputs])
    measured_traj = keep.slice(float(data.time[first]), None) if first else keep
    predicted_traj = Trajectory.from_arrays(data.time[first:], {n: predicted[:, i] for i, n in enumerate(states)},
                                            units={n: measured_traj.units[measured_traj.names.index(n)]
                                                   for n in states},
                                            roles=dict.fromkeys(states, "state"),
                                            meta={"source": "compare", "horizon": horizon})
    return Comparison(fit_pct=dict(zip(states, fit.tolist(), strict=True)),
                      nrmse_pct=dict(zip(states, (100.0 - fit).tolist(), strict=True)),
                      r2=dict(zip(states, rr.tolist(), strict=True)), horizon=horizon, x0=start_of,
                      measured=measured_traj, predicted=predicted_traj)


def _initial_state(model: IdentifiedModel, x: np.ndarray, u: np.ndarray | None, dt: float, how: Any) -> np.ndarray:
    """The free run's initial state: `how` as :func:`compare` documents it."""
    if not isinstance(how, str):
        values = [how[n] for n in model.states] if isinstance(how, Mapping) else list(how)
        start = np.asarray(values, dtype=float).ravel()
        if start.shape != (len(model.states),) or not np.all(np.isfinite(start)):
            raise InvalidSettingError(f"x0 must give {len(model.states)} finite values ({', '.join(model.states)})")
        return start
    if how not in X0_CHOICES:
        raise InvalidSettingError(f"x0={how!r}; choose one of {', '.join(X0_CHOICES)}, or give the values")
    if how == "model":
        stored = model.meta.get("x0")
        if not stored:
            raise InvalidSettingError("the model holds no initial state; use x0='estimate' or 'measured'")
        return np.asarray(stored[0] if isinstance(stored[0], list) else stored, dtype=float)
    start = x[0].copy()
    if how == "measured":
        return start
    return _estimated_state(model, x, u, dt, start)


def _estimated_state(model: IdentifiedModel, x: np.ndarray, u: np.ndarray | None, dt: float,
                     start: np.ndarray) -> np.ndarray:
    """Least squares on the free-run error over the initial state (Gauss-Newton, finite differences: the
    states are few, and for a linear model one step is exact). Each state is weighted by its spread."""
    scale = np.where(x.std(axis=0) > 0, x.std(axis=0), 1.0)
    inputs = None if u is None else u[:-1]

    def residual(z: np.ndarray) -> np.ndarray | None:
        sim = model.simulate(z, inputs, dt=dt, n_steps=len(x) - 1)
        return ((sim.states - x) / scale).ravel() if sim.ok else None

    r = residual(start)
    if r is None:
        return start
    cost = float(r @ r)
    for _ in range(_GN_ITERATIONS):
        step = 1e-6 * np.maximum(np.abs(start), scale)
        columns = []
        for i in range(len(start)):
            shifted = residual(start + np.eye(len(start))[i] * step[i])
            if shifted is None:
                return start
            columns.append((shifted - r) / step[i])
        delta = np.linalg.lstsq(np.column_stack(columns), -r, rcond=None)[0]
        trial = start + delta
        r_trial = residual(trial)
        if r_trial is None or float(r_trial @ r_trial) >= cost:
            break
        improvement = cost - float(r_trial @ r_trial)
        start, r, cost = trial, r_trial, float(r_trial @ r_trial)
        if improvement <= 1e-10 * max(cost, 1e-300):
            break
    return start
