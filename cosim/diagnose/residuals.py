"""Residuals of a model on data, and the tests that say whether anything is left to explain.

Three residuals, per state, of an :class:`~cosim.identify.model.IdentifiedModel` on a
:class:`~cosim.data.trajectory.Trajectory`:

* **equation error** - the derivative residual ``(x[k+1] - x[k]) / dt - (f(x[k], u[k]) + f(x[k+1], u[k])) / 2``
  (trapezoidal rule with the input held over the sample), in the unit of ``dx/dt``: what the model's right-hand
  side misses at each sample;
* **one-step prediction error** - ``x[k+1]`` minus the model's step from the measured ``x[k]`` (exact
  zero-order hold for a linear model, RK4 otherwise);
* **free-run simulation error** - the data minus the model run from the first sample with the measured inputs.

And the two tests MATLAB's ``resid`` makes (Ljung, *System Identification*, 2nd ed., sec. 16.6):

* **whiteness** - the normalised autocorrelation of each residual at lags 1..M against the bounds
  ``±z/sqrt(N)`` (z = 2.576 for 99 % confidence), plus the Ljung-Box portmanteau statistic and its p-value; a
  residual is white when the p-value exceeds ``1 - confidence``;
* **independence from the inputs** - the normalised cross-correlation between each residual and each input at
  lags -M..M, against ``±z*sqrt(P)/sqrt(N)`` with ``P = sum_k r_e(k) r_u(k)`` (the bound for a coloured input);
  positive lags mean the input leads the residual (feedback shows at negative lags). The verdict holds the
  confidence for all lags at once (Bonferroni), so an independent pair is flagged 1 % of the time, not 40 %.

The tests apply to the **free-run** error by default: cosim's data carry measurement noise (an output-error
noise model, as in the reference study), for which the model's prediction is its free run, as ``resid`` does
for output-error models. The one-step error of even the true model on such data is ``n[k+1] - A n[k]``, a
moving average that is never white; the equation error likewise. Test those only on noise-free data or with
a process-noise model in mind.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> from cosim.data.trajectory import Trajectory
>>> rng = np.random.default_rng(0)
>>> t = np.arange(2001) * 0.01
>>> u = np.sign(np.sin(2 * np.pi * 0.5 * t))
>>> x = np.zeros_like(t)
>>> for k in range(2000):   # x' = -x + u, exact ZOH step
...     x[k + 1] = np.exp(-0.01) * x[k] + (1 - np.exp(-0.01)) * u[k]
>>> data = Trajectory.from_arrays(t, {"x": x + 1e-4 * rng.standard_normal(t.size), "u": u},
...                               roles={"x": "state", "u": "input"})
>>> good = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 1.0]]))
>>> bad = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 0.8]]))
>>> ok, wrong = residuals(good, data), residuals(bad, data)
>>> ok.white, ok.independent, wrong.white, wrong.independent
(True, True, False, False)
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

# scipy.special's chdtrc and ndtri are scipy.stats's chi2.sf and norm.ppf to the bit, without the 0.4 s that importing
# scipy.stats costs every `cosim` command
from scipy import special

from ..data.trajectory import Trajectory
from ..errors import DataError, UnknownVariableError
from ..identify.model import IdentifiedModel

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = ["RESIDUAL_KINDS", "ResidualAnalysis", "ResidualTests", "correlation_tests", "residuals"]

RESIDUAL_KINDS = ("equation", "one_step", "free_run")
#: Fewest samples the tests accept.
MIN_SAMPLES = 50


@dataclass(frozen=True)
class ResidualTests:
    """Whiteness and input-independence tests of one residual.

    Attributes
    ----------
    lags : numpy.ndarray
        1..M for the autocorrelation.
    autocorrelation : numpy.ndarray
        Normalised autocorrelation at `lags`.
    bound : float
        Its confidence bound ``z/sqrt(N)``.
    ljung_box_p : float
        p-value of the Ljung-Box statistic over `lags`.
    white : bool
        ``ljung_box_p > 1 - confidence``.
    cross_lags : numpy.ndarray
        -M..M for the cross-correlations.
    cross_correlation : dict of str to numpy.ndarray
        Per input, the normalised cross-correlation at `cross_lags`.
    cross_bound : dict of str to float
        Per input, the bound ``z sqrt(P)/sqrt(N)``.
    independent : bool
        For every input, no lag's cross-correlation leaves the bound widened for the 2M+1 lags tested at once
        (Bonferroni: the family of lags holds the `confidence`); the plotted bound is the per-lag one.
    """

    lags: np.ndarray
    autocorrelation: np.ndarray
    bound: float
    ljung_box_p: float
    white: bool
    cross_lags: np.ndarray
    cross_correlation: dict[str, np.ndarray]
    cross_bound: dict[str, float]
    independent: bool

    @property
    def fraction_outside(self) -> float:
        """Fraction of the autocorrelation lags outside the bound (about 1 % for a white residual)."""
        return float(np.mean(np.abs(self.autocorrelation) > self.bound))

    def summary(self) -> dict[str, Any]:
        return {"white": self.white, "ljung_box_p": self.ljung_box_p, "fraction_outside": self.fraction_outside,
                "independent": self.independent,
                "max_cross_over_bound": {name: float(np.max(np.abs(c)) / self.cross_bound[name])
                                         for name, c in self.cross_correlation.items()}}


def _xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """``sum_k a[k+lag] b[k] / N`` for lag = -max_lag..max_lag (a lags b at positive lags), by FFT."""
    n = len(a)
    size = 1 << int(math.ceil(math.log2(2 * n - 1)))
    full = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)[:size]
    lags = np.arange(-max_lag, max_lag + 1)
    return full[lags % size] / n


def correlation_tests(residual: np.ndarray, inputs: np.ndarray | None = None, *, input_names: Sequence[str] = (),
                      max_lag: int = 25, confidence: float = 0.99) -> ResidualTests:
    """Whiteness and input-independence tests of one residual (see the module notes).

    Parameters
    ----------
    residual : array_like, shape (N,)
    inputs : array_like, shape (N, n_inputs), optional
    input_names : sequence of str
    max_lag : int
        M, the largest lag tested.
    confidence : float
        Confidence level of the bounds and of the Ljung-Box test.
    """
    e = np.asarray(residual, dtype=float).reshape(-1)
    if e.size < MIN_SAMPLES or not np.all(np.isfinite(e)):
        raise DataError(f"residual tests need at least {MIN_SAMPLES} finite samples, got {e.size}"
                        + ("" if np.all(np.isfinite(e)) else " with NaN or infinite values"))
    n = e.size
    max_lag = int(min(max_lag, n // 4))
    e = e - e.mean()
    var_e = float(np.dot(e, e) / n)
    z = float(special.ndtri(0.5 + confidence / 2))
    if var_e == 0.0:
        acf_e = np.zeros(2 * max_lag + 1)
        acf_e[max_lag] = 1.0
    else:
        acf_e = _xcorr(e, e, max_lag) / var_e
    acf = acf_e[max_lag + 1:]
    lags = np.arange(1, max_lag + 1)
    q = float(n * (n + 2) * np.sum(acf ** 2 / (n - lags)))
    p_value = float(special.chdtrc(max_lag, q))
    cross, cross_bound = {}, {}
    independent = True
    u = np.zeros((n, 0)) if inputs is None else np.asarray(inputs, dtype=float).reshape(n, -1)
    for j, name in enumerate(list(input_names) or [f"u{j}" for j in range(u.shape[1])]):
        uj = u[:, j] - u[:, j].mean()
        var_u = float(np.dot(uj, uj) / n)
        if var_u == 0.0 or var_e == 0.0:
            cross[name], cross_bound[name] = np.zeros(2 * max_lag + 1), math.inf
            continue
        ccf = _xcorr(e, uj, max_lag) / math.sqrt(var_e * var_u)
        acf_u = _xcorr(uj, uj, max_lag) / var_u
        # P = sum over lags of r_e(k) r_u(k), truncated at M: the variance factor for a coloured input
        p = float(max(np.sum(acf_e * acf_u), 1.0 / n))
        cross[name], cross_bound[name] = ccf, z * math.sqrt(p) / math.sqrt(n)
        # one decision over all 2M+1 lags, Bonferroni-corrected (the lags of a coloured input are correlated,
        # so a chi-square sum over them is not chi-square; a per-lag rule would flag 1 % of independent lags)
        z_all = float(special.ndtri(1.0 - (1.0 - confidence) / (2 * ccf.size)))
        independent &= bool(np.max(np.abs(ccf)) <= z_all * math.sqrt(p) / math.sqrt(n))
    return ResidualTests(lags=lags, autocorrelation=acf, bound=z / math.sqrt(n), ljung_box_p=p_value,
                         white=p_value > 1.0 - confidence, cross_lags=np.arange(-max_lag, max_lag + 1),
                         cross_correlation=cross, cross_bound=cross_bound, independent=independent)


@dataclass(frozen=True)
class ResidualAnalysis:
    """The residuals of a model on data, and their tests.

    Attributes
    ----------
    time : numpy.ndarray
        Sample times of the data (N+1).
    states, inputs : tuple of str
    equation, one_step, free_run : numpy.ndarray
        The three residuals, shape (N, n_states) for the first two (sample k+1 against sample k) and (N+1,
        n_states) for the free run (NaN after a divergence).
    tests : dict of str to ResidualTests
        Per state, the tests of the residual named by `tested`.
    tested : str
        Which residual the tests are on (``"free_run"`` by default).
    free_run_status : str
        ``"ok"`` or ``"diverged"``.
    units : tuple of str
        The unit of each state (of its free-run and one-step residuals); empty where unknown.
    """

    time: np.ndarray
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    equation: np.ndarray
    one_step: np.ndarray
    free_run: np.ndarray
    tests: dict[str, ResidualTests]
    tested: str
    free_run_status: str
    units: tuple[str, ...] = ()

    @property
    def white(self) -> bool:
        """Every state's tested residual is white."""
        return all(t.white for t in self.tests.values())

    @property
    def independent(self) -> bool:
        """No state's tested residual correlates with an input."""
        return all(t.independent for t in self.tests.values())

    def rms(self) -> dict[str, dict[str, float]]:
        """RMS of each residual per state: ``{"equation": {...}, "one_step": {...}, "free_run": {...}}``."""
        out = {}
        for kind in RESIDUAL_KINDS:
            values = getattr(self, kind)
            out[kind] = {name: float(np.sqrt(np.nanmean(values[:, i] ** 2))) for i, name in enumerate(self.states)}
        return out

    def summary(self) -> dict[str, Any]:
        return {"white": self.white, "independent": self.independent, "tested": self.tested,
                "free_run_status": self.free_run_status, "rms": self.rms(),
                "tests": {name: t.summary() for name, t in self.tests.items()}}

    def plot(self, path: str | os.PathLike | None = None, *, title: str | None = None,
             colour: str | None = None) -> matplotlib.figure.Figure:
        """Per state, the free-run and one-step residuals against time, the autocorrelation and the input
        cross-correlation with their confidence bounds (as MATLAB ``resid`` draws them).

        Parameters
        ----------
        path : path-like, optional
            Write the figure there as PNG too.
        title : str, optional
        colour : str, optional
            Colour of the model's residuals (:data:`cosim.figures.COLOURS`: ``"before"`` or ``"after"`` in a
            diagnosis; default ``"model"``); the one-step residual is drawn light grey under the free run.

        Returns
        -------
        matplotlib.figure.Figure
        """
        from ..figures import COLOURS, FONT_SIZE, axis_label, finish, new_figure

        colour = colour or COLOURS["model"]
        n = len(self.states)
        fig = new_figure(figsize=(13, 2.3 * n + 0.9), layout="constrained")
        axes = fig.subplots(n, 3, squeeze=False)
        for i, name in enumerate(self.states):
            unit = self.units[i] if i < len(self.units) else ""
            ax = axes[i, 0]
            ax.plot(self.time[1:], self.one_step[:, i], lw=0.6, color="0.65", label="one step")
            ax.plot(self.time, self.free_run[:, i], lw=0.7, color=colour, label="free run")
            ax.set_ylabel(axis_label(f"{name}\nresidual", unit), fontsize=FONT_SIZE)
            ax.legend(fontsize=FONT_SIZE, loc="upper right")
            tests = self.tests[name]
            ax = axes[i, 1]
            ax.bar(tests.lags, tests.autocorrelation, width=0.6, color=colour)
            for sign in (1, -1):
                ax.axhline(sign * tests.bound, color=COLOURS["limit"], ls=":", lw=0.9)
            ax.set_title(f"autocorrelation ({'white' if tests.white else 'NOT white'}, "
                         f"p={tests.ljung_box_p:.2g})", fontsize=FONT_SIZE)
            ax = axes[i, 2]
            for k, (input_name, ccf) in enumerate(tests.cross_correlation.items()):
                ax.plot(tests.cross_lags, ccf, ".-", lw=0.8, ms=2.5, label=input_name,
                        color=colour if k == 0 else f"C{(k + 4) % 10}")
                bound = tests.cross_bound[input_name]
                if math.isfinite(bound):
                    for sign in (1, -1):
                        ax.axhline(sign * bound, color=COLOURS["limit"], ls=":", lw=0.9)
            ax.set_title(f"cross-correlation with inputs ({'independent' if tests.independent else 'CORRELATED'})",
                         fontsize=FONT_SIZE)
            if tests.cross_correlation:
                ax.legend(fontsize=FONT_SIZE)
        for ax in axes.flat:
            ax.grid(alpha=0.3)
        axes[-1, 0].set_xlabel("time [s]", fontsize=FONT_SIZE + 1)
        axes[-1, 1].set_xlabel("lag [samples]", fontsize=FONT_SIZE + 1)
        axes[-1, 2].set_xlabel("lag [samples] (input leads at > 0)", fontsize=FONT_SIZE + 1)
        fig.suptitle(title or f"Residuals of the model ({self.tested.replace('_', '-')} error tested)",
                     fontsize=FONT_SIZE + 2)
        return finish(fig, path)


def _one_step(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """The model's step from every measured sample (vectorised over the samples)."""
    if model.is_linear:
        ad, bd, cd = model.discretize(dt)
        return x @ ad.T + u @ bd.T + cd
    f = model.predict
    k1 = f(x, u)
    k2 = f(x + 0.5 * dt * k1, u)
    k3 = f(x + 0.5 * dt * k2, u)
    k4 = f(x + dt * k3, u)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def _initial_state(model: IdentifiedModel, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """Least-squares initial state of a linear model's free run on the record (states scaled by their spread)."""
    n = len(model.states)
    forced = model.simulate(np.zeros(n), u[:-1], dt=dt).states
    free = np.stack([model.simulate(np.eye(n)[i], np.zeros_like(u[:-1]), dt=dt).states for i in range(n)], axis=-1)
    if not (np.all(np.isfinite(forced)) and np.all(np.isfinite(free))):
        return x[0]
    scale = np.std(x, axis=0)
    scale[scale == 0] = 1.0
    lhs = (free / scale[None, :, None]).reshape(-1, n)
    rhs = ((x - forced) / scale).reshape(-1)
    solution, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return solution


def residuals(model: IdentifiedModel, data: Trajectory, *, tested: str = "free_run", max_lag: int = 25,
              confidence: float = 0.99, x0: str | Sequence[float] | None = "estimate") -> ResidualAnalysis:
    """Residuals of `model` on `data` and their whiteness and input-correlation tests.

    Parameters
    ----------
    model : IdentifiedModel
    data : Trajectory
        Must hold the model's states and inputs by name, at a uniform step (inputs held between samples).
    tested : {"free_run", "one_step", "equation"}
        The residual the tests are made on (see the module notes for why the free run is the default).
    max_lag, confidence
        See :func:`correlation_tests`.
    x0 : "estimate", sequence of float, or None
        Initial state of the free run. ``"estimate"`` (default): for a linear model, the initial state that
        fits the whole record best (least squares, each state scaled by its spread), since a noisy first
        sample starts a free oscillation and, with an integrator, a drift that are not model error; for a
        nonlinear model, the first sample. None: the first sample.

    Returns
    -------
    ResidualAnalysis
    """
    if tested not in RESIDUAL_KINDS:
        raise DataError(f"tested must be one of {', '.join(RESIDUAL_KINDS)}, got {tested!r}")
    missing = [name for name in (*model.states, *model.inputs) if name not in data.names]
    if missing:
        raise UnknownVariableError(f"the data have no column {missing[0]!r} that the model needs; "
                                   f"columns are {list(data.names)}")
    if len(data) < MIN_SAMPLES + 1:
        raise DataError(f"residual analysis needs at least {MIN_SAMPLES + 1} samples, got {len(data)}")
    dt = data.dt
    times = np.diff(data.time)
    if not np.allclose(times, dt, rtol=1e-6, atol=0.0):
        raise DataError("the data's time step is not uniform; resample it onto a uniform grid first")
    x = np.column_stack([data[name] for name in model.states])
    u = np.column_stack([data[name] for name in model.inputs]) if model.inputs else np.zeros((len(data), 0))
    f_now, f_next = model.predict(x[:-1], u[:-1]), model.predict(x[1:], u[:-1])
    equation = (x[1:] - x[:-1]) / dt - 0.5 * (f_now + f_next)
    one_step = x[1:] - _one_step(model, x[:-1], u[:-1], dt)
    if isinstance(x0, str):
        if x0 != "estimate":
            raise DataError(f"x0 must be 'estimate', None or one value per state, got {x0!r}")
        start = _initial_state(model, x, u, dt) if model.is_linear else x[0]
    else:
        start = x[0] if x0 is None else np.asarray(x0, dtype=float)
    sim = model.simulate(start, u[:-1], dt=dt)
    free_run = x - sim.states
    chosen = {"equation": equation, "one_step": one_step, "free_run": free_run}[tested]
    u_tested = u[:-1] if tested != "free_run" else u
    tests = {}
    for i, name in enumerate(model.states):
        e = chosen[:, i]
        good = np.isfinite(e)
        tests[name] = correlation_tests(e[good], u_tested[good], input_names=model.inputs, max_lag=max_lag,
                                        confidence=confidence)
    return ResidualAnalysis(time=data.time, states=model.states, inputs=model.inputs, equation=equation,
                            one_step=one_step, free_run=free_run, tests=tests, tested=tested,
                            free_run_status=sim.status,
                            units=tuple(data.units[data.names.index(name)] for name in model.states))
