"""SINDYc identification: a sparse model ``dx/dt = Xi @ theta(x, u)`` from sampled data, scikit-learn style.

:class:`SINDYc` turns one or several :class:`~cosim.data.trajectory.Trajectory` records into an
:class:`~cosim.identify.model.IdentifiedModel`. Its ``__init__`` only stores settings; :meth:`SINDYc.fit` learns
``coef_``, ``terms_``, ``threshold_`` and ``model_``. The library terms are cosim expressions
(:mod:`cosim.identify.terms`), so the model simulates, saves and exports like any other.

The steps of a fit
------------------
1. **Library** ``theta(x, u)``: ``"linear"`` (constant, states, inputs: the reference study's) or
   ``"polynomial"`` of a degree (all monomials of states and inputs, so state-input cross terms: SINDYc), plus
   any user terms (``terms=["sign(omega_m)"]``). The constant is included by default; a constant the
   regression finds is kept in the model, never dropped silently.
2. **Equation error**: targets and features from the data, by the ``differentiation`` method:

   * ``"integral"`` (default): both sides integrated over sliding windows of ``window`` samples (default 30),
     ``x(t_b) - x(t_a) = Xi @ integral(theta)``. This is cosim's own integral formulation, not pysindy's weak
     library, for three reasons: the terms must be cosim expressions (exportable); the inputs are
     zero-order held, so each sample interval is integrated with its input *held* (pysindy's weak form
     integrates smooth test functions on the grid and smears the held input's steps); and accuracy: each
     interval's trapezoid gets its end correction ``-dt^2/12 * (g'(t_k+1 -) - g'(t_k +))``, the derivative of
     each term taken along the fitted model's own vector field with the input held (two fixed-point passes),
     which makes the quadrature O(dt^4) for any input pattern instead of O(dt^2). On the two-mass servo at
     2257 Hz (resonance 17.8 Hz, omega*dt = 0.05, a 4 rad initial twist whose spring torques are 10^4 times
     the input torque) that is the difference between 2e-4 and 3e-8 relative coefficient error; a central
     finite difference gets the input coefficient wrong by percents there. Integration also averages the
     noise a derivative would amplify. With ``noise_compensation`` (default) the estimated white-noise
     variance of the states is removed from the normal equations (bias-compensated least squares) and the
     directions whose signal is below their noise are dropped (minimum-norm coefficients there).
   * ``"zoh"``: exact for a linear model fed zero-order-hold data: the discrete-time map
     ``x[k+1] = Ad x[k] + Bd u[k] + cd`` is fitted by least squares and converted with the matrix logarithm
     (``[[A, B, c], [0, 0, 0]] = logm([[Ad, Bd, cd], [0, I, 0]]) / dt``); the derivatives of that dense model at
     the samples are then the targets of the sparse regression. Noise-free linear data only: a one-step map
     at a high sampling rate is ruined by a little noise (errors in variables), use ``"integral"`` there.
   * pysindy's differentiators by name: ``"finite_difference"`` (``FiniteDifference``, option ``order``),
     ``"smoothed_finite_difference"`` (``SmoothedFiniteDifference``, options ``window_length``,
     ``polyorder``), and the ``derivative`` package's methods through ``SINDyDerivative``:
     ``"savitzky_golay"``, ``"spline"``, ``"kalman"``, ``"trend_filtered"``, ``"spectral"``, ``"kernel"``
     (options as that package names them, e.g. ``{"alpha": 1e-6}`` for ``"kalman"``). Features are evaluated
     on the smoothed states when the method smooths, and with the mean of the inputs held before and after
     each sample (a central derivative at a sample measures the mean of the two one-sided slopes). Their
     truncation error is O(dt^2) (finite differences) or set by the smoothing, so they are the less accurate
     choices for a sampled-data plant with a fast mode.

3. **Sparse regression** with pysindy's ``STLSQ``, scale-aware: each feature column is divided by its RMS
   value and each target by its RMS value, so a coefficient is *the fraction of the target that term
   explains* and one threshold fits states of any unit (angles ~1 rad, speeds ~100 rad/s, torques ~500 N m).
   ``threshold`` is such a dimensionless number, or ``"auto"``:

   * without refinement, every threshold that removes one more coefficient of the dense fit is tried (at
     most 40, log-spaced) and the model with the lowest Bayesian information criterion on the equation error
     wins, ``BIC = sum_i N_eff*log(max(RSS_i/N, floor^2)) + k*log(N_eff)``, with ``k`` the non-zero
     coefficients, ``N_eff`` the number of independent equations (samples / window for ``"integral"``,
     whose windows overlap) and ``floor = 1e-6`` of the target's RMS (below that the residual is the data's
     numerical noise, so noise-free data does not reward spurious terms). Ties go to the sparser model.
   * with ``refine="output_error"``, equation error cannot judge small terms on noisy data (at 10 % noise
     the servo's damping and input terms are below the equation error's noise), so the dense equation-error
     fit is refined by output error and then pruned by backward elimination with Wald tests: the
     coefficient with the smallest ``|coef| / standard error`` (covariance from the output-error Jacobian)
     goes while that t-statistic is below ``sqrt(log(n))`` (the output error's BIC drops), the others
     updated as the constrained fit; then the reduced model is refined again (see ``SINDYc._prune``). BIC
     removes what the record cannot pin down: on a weakly exciting record (the 5 Hz sine, a short record,
     50 % noise) that can be the input or a damping term of the two-mass servo. Give ``threshold=0`` to keep
     the whole library (as :func:`study_case` does, like the study's X, U library).

   The choice, the candidates and their scores are recorded in ``model_.meta["threshold"]``.
4. **Known kinematics** (optional, ``kinematics={"theta_m": "omega_m"}``): rows such as
   ``d theta_m/dt = omega_m`` are fixed (coefficient exactly 1), not regressed.
5. **Output-error refinement** (``refine="output_error"``): starting from the equation-error fit, the
   non-zero coefficients (sparsity pattern kept; fixed kinematic rows stay fixed) and each record's initial
   state are fitted to minimise the free-run simulation error, see :mod:`cosim.identify.output_error` (exact ZOH
   simulation and exact Jacobian for linear models, horizon continuation). This removes the bias equation
   error has with noisy states.

Positions only: ``velocities={"omega_m": "theta_m"}`` derives the velocity state ``omega_m`` from the
measured position ``theta_m`` with a smoothing differentiator (``velocity_method``, default pysindy's
``SmoothedFiniteDifference``: Savitzky-Golay smoothing, then central differences) and fixes the kinematic
row ``d theta_m/dt = omega_m``.

Errors and warnings: unknown columns raise :class:`~cosim.errors.UnknownVariableError` listing the available
ones; NaN/inf, too few samples for the library (fewer than ``MIN_SAMPLES_PER_TERM`` per term) or records of
different steps raise :class:`~cosim.errors.DataError`; bad settings raise
:class:`~cosim.errors.InvalidSettingError`. A constant input (not persistently exciting) gives an
:class:`IdentificationWarning` naming it and is left out of the model. An unstable identified model gives
an :class:`IdentificationWarning` and ``model_.meta["stable"] = False`` (with the eigenvalues of a linear
model in ``meta["eigenvalues"]`` and a sentence in ``meta["stability"]``); its simulation returns status
``"diverged"`` once it leaves the range. A linear model counts as unstable when an eigenvalue's real part
exceeds ``1/T`` (T the record length): a mode growing at most e-fold over the record is reported as
marginal (``stable`` True), since the data cannot tell it from an integrator (the two-mass servo has an
exact integrator, its rigid-body position, which noisy data identifies as a slightly positive or negative
eigenvalue). A nonlinear model is judged by a free run on the longest record.

Examples
--------
>>> import numpy as np
>>> from cosim.identify.model import IdentifiedModel
>>> plant = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("x", "v", "u"),
...                         coef=np.array([[0.0, 1.0, 0.0], [-4.0, -0.4, 2.0]]))
>>> u = np.sign(np.sin(np.arange(4000) * 0.004))[:, None]
>>> data = plant.simulate([1.0, 0.0], u, dt=0.005).to_trajectory()
>>> est = SINDYc().fit(data)
>>> est.equations(precision=4)
["x' = 1 v", "v' = -4 x - 0.4 v + 2 u"]
"""

from __future__ import annotations

import math
import numbers
import time
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..data.trajectory import Trajectory
from ..errors import DataError, InvalidSettingError, UnknownVariableError
from .model import IdentifiedModel, SimulationResult
from .terms import Term, polynomial_terms

__all__ = ["SINDYc", "IdentificationWarning", "DIFFERENTIATION_METHODS", "MIN_SAMPLES_PER_TERM"]

#: A fit needs at least this many samples per library term.
MIN_SAMPLES_PER_TERM = 10
#: Residual RMS, relative to the target's RMS, below which the "auto" threshold treats a fit as exact.
_BIC_FLOOR = 1e-6
_MAX_CANDIDATES = 40
#: Noise compensation keeps a direction of the normal equations if its signal exceeds this multiple of its noise.
_NOISE_MARGIN = 1.0
_PYSINDY_KINDS = ("savitzky_golay", "spline", "kalman", "trend_filtered", "spectral", "kernel")
#: Names accepted by ``differentiation`` (and ``velocity_method``, except "integral" and "zoh").
DIFFERENTIATION_METHODS = ("integral", "zoh", "finite_difference", "smoothed_finite_difference") + _PYSINDY_KINDS
_LIBRARIES = ("linear", "polynomial")
_REFINE = (None, "output_error")


class IdentificationWarning(UserWarning):
    """Something about the data or the identified model that the user should know (cosim warning)."""


# ---------------------------------------------------------------------------------------------------------
# settings


def _check_number(name: str, value: Any, *, low: float | None = None, integer: bool = False,
                  allow_zero: bool = True) -> None:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))
    if ok and integer:
        ok = float(value).is_integer()
    if ok and low is not None:
        ok = value >= low if allow_zero else value > low
    if not ok:
        kind = "an integer" if integer else "a finite number"
        bound = "" if low is None else f" {'>=' if allow_zero else '>'} {low}"
        raise InvalidSettingError(f"{name} must be {kind}{bound}, got {value!r}")


def _check_mapping(name: str, value: Any) -> dict[str, str]:
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and isinstance(v, str)
                                                 for k, v in value.items()):
        raise InvalidSettingError(f"{name} must map names to names, e.g. {{'theta_m': 'omega_m'}}, got {value!r}")
    return dict(value)


class SINDYc:
    """Sparse identification of a controlled dynamical model (SINDYc), scikit-learn style.

    Parameters
    ----------
    library : {"linear", "polynomial"}
        ``"linear"``: constant, states and inputs (the reference study's library). ``"polynomial"``: all
        monomials of the states and inputs up to `degree`, state-input cross terms included.
    degree : int
        Degree of the polynomial library (ignored for ``"linear"``).
    terms : sequence of str
        Extra user terms added to the library, as expressions of state and input names
        (``"sign(omega_m)"``, ``"omega_m*Tm"``, see :mod:`cosim.identify.terms`).
    include_constant : bool
        Include the constant term ``"1"``. A constant the regression finds is kept in the model.
    threshold : float or "auto"
        STLSQ threshold on the scaled coefficients (a term whose RMS contribution is below this fraction of
        its target's RMS is dropped), or ``"auto"``: chosen by BIC, on the equation error along the threshold
        path, or with ``refine="output_error"`` by backward elimination on the output error (module
        docstring). 0 keeps every term.
    ridge : float
        L2 weight in STLSQ's thresholding iterations, relative to the scaled features' mean square
        (pysindy's ``alpha = ridge * number of equations``); the final coefficients are refit by plain least
        squares on the support (pysindy's ``unbias``).
    differentiation : str
        How the equation-error targets are formed: ``"integral"``, ``"zoh"``, or a pysindy differentiator
        name (see :data:`DIFFERENTIATION_METHODS` and the module docstring).
    differentiation_options : mapping, optional
        Options of that method: ``{"window": 30}`` (samples, ``"integral"``, the default; keep
        ``window*dt*omega_max`` below about 1.5), ``{"order": 4}`` (``"finite_difference"``, default 2),
        ``{"window_length": 21, "polyorder": 3}`` (``"smoothed_finite_difference"``, the defaults), the
        ``derivative`` package's keywords for the others (e.g. ``{"left": 0.005, "right": 0.005,
        "order": 3}`` for ``"savitzky_golay"``).
    noise_compensation : bool
        With ``"integral"``: estimate the variance of white measurement noise on each state (fourth
        differences, robust), subtract its share from the normal equations (bias-compensated least squares)
        and drop the directions of the normal equations whose signal does not exceed their noise (their
        coefficients take the minimum-norm value). Removes most of the errors-in-variables bias of equation
        error with noisy states; no effect on clean data.
    kinematics : mapping, optional
        Known kinematic rows, position state -> velocity state: ``d position/dt = velocity`` with coefficient
        exactly 1, not regressed (and not refined).
    velocities : mapping, optional
        Velocity states to derive from measured positions, velocity name -> position column
        (``{"omega_m": "theta_m"}``); implies the kinematic row. A column of the velocity's name, if the data
        has one, is ignored.
    velocity_method : str
        Smoothing differentiator for `velocities` (a pysindy differentiator name).
    velocity_options : mapping, optional
        Its options (default ``{"window_length": 7, "polyorder": 3}`` for the default method: accurate on clean
        data; widen the window for noisy positions).
    refine : {None, "output_error"}
        Refine the equation-error fit by output error (:mod:`cosim.identify.output_error`).
    refine_initial_state : bool
        With refinement, also estimate each record's initial state (recorded in ``meta["x0"]``).
    refine_options : mapping, optional
        Passed to :func:`cosim.identify.output_error.refine_output_error`: ``prior`` (default 0.1), ``continuation``
        (default True), ``max_nfev`` (per stage, default 60).

    Attributes
    ----------
    coef_ : ndarray, shape (n_states, n_terms)
    terms_ : tuple of str
    threshold_ : float
        The threshold used: the given one, the chosen STLSQ threshold for ``"auto"``, or with ``"auto"`` and
        refinement the t-statistic limit ``sqrt(log(n))`` of the backward elimination.
    model_ : IdentifiedModel
        The model; ``model_.meta`` records every setting, how the threshold was chosen, the data sizes,
        the equation-error and refinement results, stability and timing.
    states_, inputs_ : tuple of str
        The model's states and inputs (constant inputs are left out).

    Examples
    --------
    >>> import numpy as np
    >>> from cosim.identify.model import IdentifiedModel
    >>> plant = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-2.0, 1.0]]))
    >>> data = plant.simulate([0.0], np.sign(np.sin(np.arange(3000) * 0.01))[:, None], dt=0.01).to_trajectory()
    >>> est = SINDYc(threshold=0.01).fit(data)
    >>> est.terms_, np.round(est.coef_, 5).tolist()
    (('1', 'x', 'u'), [[0.0, -2.0, 1.0]])
    >>> round(est.score(data), 9)
    1.0
    """

    def __init__(self, *, library: str = "linear", degree: int = 2, terms: Sequence[str] = (),
                 include_constant: bool = True, threshold: float | str = "auto", ridge: float = 0.0,
                 differentiation: str = "integral", differentiation_options: Mapping[str, Any] | None = None,
                 noise_compensation: bool = True, kinematics: Mapping[str, str] | None = None,
                 velocities: Mapping[str, str] | None = None,
                 velocity_method: str = "smoothed_finite_difference",
                 velocity_options: Mapping[str, Any] | None = None, refine: str | None = None,
                 refine_initial_state: bool = True, refine_options: Mapping[str, Any] | None = None) -> None:
        self.library = library
        self.degree = degree
        self.terms = tuple(terms) if not isinstance(terms, str) else (terms,)
        self.include_constant = include_constant
        self.threshold = threshold
        self.ridge = ridge
        self.differentiation = differentiation
        self.differentiation_options = dict(differentiation_options or {})
        self.noise_compensation = noise_compensation
        self.kinematics = kinematics
        self.velocities = velocities
        self.velocity_method = velocity_method
        self.velocity_options = dict(velocity_options or {})
        self.refine = refine
        self.refine_initial_state = refine_initial_state
        self.refine_options = dict(refine_options or {})
        self._check_settings()

    # -------------------------------------------------------------------------------------------- settings
    def get_params(self) -> dict[str, Any]:
        """The settings, as given to ``__init__``.

        Examples
        --------
        >>> SINDYc(threshold=0.1).get_params()["threshold"]
        0.1
        """
        return {"library": self.library, "degree": self.degree, "terms": list(self.terms),
                "include_constant": self.include_constant, "threshold": self.threshold, "ridge": self.ridge,
                "differentiation": self.differentiation,
                "differentiation_options": dict(self.differentiation_options),
                "noise_compensation": self.noise_compensation, "kinematics": dict(self.kinematics or {}),
                "velocities": dict(self.velocities or {}),
                "velocity_method": self.velocity_method, "velocity_options": dict(self.velocity_options),
                "refine": self.refine, "refine_initial_state": self.refine_initial_state,
                "refine_options": dict(self.refine_options)}

    def _check_settings(self) -> None:
        if self.library not in _LIBRARIES:
            raise InvalidSettingError(f"library must be one of {', '.join(_LIBRARIES)}, got {self.library!r}")
        _check_number("degree", self.degree, low=1, integer=True)
        for term in self.terms:
            if not isinstance(term, str):
                raise InvalidSettingError(f"terms must be expression strings such as 'omega_m*Tm', got {term!r}")
            Term(term)  # raises InvalidSettingError with the reason
        if not isinstance(self.include_constant, bool):
            raise InvalidSettingError(f"include_constant must be True or False, got {self.include_constant!r}")
        if self.threshold != "auto":
            if isinstance(self.threshold, str):
                raise InvalidSettingError(f"threshold must be a number >= 0 or 'auto', got {self.threshold!r}")
            _check_number("threshold", self.threshold, low=0.0)
        _check_number("ridge", self.ridge, low=0.0)
        if self.differentiation not in DIFFERENTIATION_METHODS:
            raise InvalidSettingError(f"unknown differentiation {self.differentiation!r}; choose one of "
                                      f"{', '.join(DIFFERENTIATION_METHODS)}")
        if self.differentiation == "integral":
            extra = set(self.differentiation_options) - {"window"}
            if extra:
                raise InvalidSettingError(f"differentiation 'integral' takes the option 'window' only, got "
                                          f"{', '.join(sorted(extra))}")
            _check_number("window", self.differentiation_options.get("window", 30), low=3, integer=True)
        elif self.differentiation == "zoh" and self.differentiation_options:
            raise InvalidSettingError("differentiation 'zoh' takes no options")
        if not isinstance(self.noise_compensation, bool):
            raise InvalidSettingError(f"noise_compensation must be True or False, got {self.noise_compensation!r}")
        _check_mapping("kinematics", self.kinematics)
        _check_mapping("velocities", self.velocities)
        if self.velocity_method not in DIFFERENTIATION_METHODS[2:]:
            raise InvalidSettingError(f"velocity_method must be a differentiator, one of "
                                      f"{', '.join(DIFFERENTIATION_METHODS[2:])}; got {self.velocity_method!r}")
        if self.refine not in _REFINE:
            raise InvalidSettingError(f"refine must be None or 'output_error', got {self.refine!r}")
        if not isinstance(self.refine_initial_state, bool):
            raise InvalidSettingError("refine_initial_state must be True or False")
        extra = set(self.refine_options) - {"prior", "continuation", "max_nfev"}
        if extra:
            raise InvalidSettingError(f"unknown refine_options {', '.join(sorted(extra))}; valid: prior, "
                                      "continuation, max_nfev")

    # -------------------------------------------------------------------------------------------- fitting
    def fit(self, data: Trajectory | Sequence[Trajectory], *, states: Sequence[str] | None = None,
            inputs: Sequence[str] | None = None, x0: Any = None) -> SINDYc:
        """Identify the model from one record or several records with the same step.

        Parameters
        ----------
        data : Trajectory or sequence of Trajectory
            Uniformly sampled records; inputs are zero-order held (row k over step k).
        states, inputs : sequence of str, optional
            Columns to use as states and inputs; default the trajectory's ``state`` and ``input`` roles
            (plus derived `velocities`).
        x0 : mapping or sequence, optional
            Known initial state of each record (state name -> value, or values in state order; a list of them
            for several records). The output-error refinement then keeps it fixed instead of estimating it.

        Returns
        -------
        SINDYc
            self, fitted.

        Raises
        ------
        UnknownVariableError, DataError, InvalidSettingError
            See the module docstring.

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.identify.model import IdentifiedModel
        >>> plant = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 3.0]]))
        >>> runs = [plant.simulate([x0], np.full((500, 1), u0), dt=0.01).to_trajectory()
        ...         for x0, u0 in ((0.0, 1.0), (2.0, -1.0))]
        >>> SINDYc(include_constant=False).fit(runs).equations()
        ["x' = -1 x + 3 u"]
        """
        started = time.perf_counter()
        self._check_settings()
        runs, state_names, input_names, dt, dropped = self._prepare(data, states, inputs)
        kin = self._kinematics(state_names)
        known_x0 = _known_initial_states(x0, state_names, len(runs))
        library = self._library(state_names, input_names)
        n_terms = len(library)
        n_total = sum(len(x) for x, _ in runs)
        needed = MIN_SAMPLES_PER_TERM * n_terms + (len(runs) - 1)
        if n_total < needed:
            raise DataError(f"too few samples for the library: {n_total} samples for {n_terms} terms; at least "
                            f"{needed} are needed ({MIN_SAMPLES_PER_TERM} per term); record longer or use a "
                            "smaller library")
        if self.differentiation == "integral" and any(len(x) <= self._window() + 2 for x, _ in runs):
            raise DataError(f"a record has fewer samples than the integration window ({self._window()} + 3); "
                            "record longer or give differentiation_options={'window': ...} smaller")
        parsed = [Term(t) for t in library]
        free_rows = [i for i, s in enumerate(state_names) if s not in kin]
        features, targets, n_eff, ee_meta, noise_var = self._equations(runs, parsed, state_names, input_names, dt,
                                                                       kin)
        coef = np.zeros((len(state_names), n_terms))
        for pos, vel in kin.items():
            coef[state_names.index(pos), library.index(vel)] = 1.0
        feat_scale = np.sqrt(np.mean(features ** 2, axis=0))
        usable = feat_scale > 0
        targ_scale = np.sqrt(np.mean(targets ** 2, axis=0))
        targ_scale = np.where(targ_scale > 0, targ_scale, 1.0)
        threshold_meta: dict[str, Any]
        if free_rows:
            theta_s = features[:, usable] / feat_scale[usable]
            y_s = targets[:, free_rows] / targ_scale[free_rows]
            noise_s = None if noise_var is None else noise_var[usable] * len(features) / feat_scale[usable] ** 2
            ee_threshold = 0.0 if (self.threshold == "auto" and self.refine) else self.threshold
            xi, threshold, threshold_meta = self._sparse(theta_s, y_s, n_eff, noise_s, ee_threshold)
            coef[np.ix_(free_rows, np.flatnonzero(usable))] = xi * targ_scale[free_rows, None] / feat_scale[usable]
            residual = y_s - theta_s @ xi.T
            ee_meta["residual_rms_scaled"] = dict(zip([state_names[i] for i in free_rows],
                                                      np.sqrt(np.mean(residual ** 2, axis=0)).tolist(),
                                                      strict=True))
        else:
            threshold = 0.0 if self.threshold == "auto" else float(self.threshold)
            threshold_meta = {"method": "none: every row is a fixed kinematic row", "value": threshold}
        ee_seconds = time.perf_counter() - started
        coef_scale = np.ones_like(coef)
        coef_scale[:, usable] = feat_scale[usable][None, :] / targ_scale[:, None]
        units = dict(ee_meta.pop("units"))
        meta: dict[str, Any] = {
            "estimator": "SINDYc", "settings": self.get_params(), "threshold": threshold_meta,
            "data": {"records": len(runs), "samples": [len(x) for x, _ in runs], "dt": dt,
                     "equations": int(features.shape[0]), "independent_equations": float(n_eff),
                     "dropped_inputs": dropped, "derived_velocities": dict(self.velocities or {})},
            "kinematics": kin, "equation_error": ee_meta, "seconds": {"equation_error": ee_seconds},
        }
        model = IdentifiedModel(states=tuple(state_names), inputs=tuple(input_names), terms=tuple(library),
                                coef=coef, dt=dt, units=units, meta=meta)
        if known_x0 is not None:
            meta["x0_known"] = [v.tolist() for v in known_x0]
        if self.refine == "output_error":
            model = self._refine(model, runs, dt, kin, coef_scale, meta, known_x0)
            if self.threshold == "auto":
                threshold = meta["threshold"]["value"]
        meta["seconds"]["total"] = time.perf_counter() - started
        meta.update(self._stability(model, runs, dt))
        model = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=model.coef,
                                dt=dt, units=units, meta=meta)
        if meta["stable"] is False:
            warnings.warn(f"the identified model is unstable ({meta['stability']}); its free-run simulation "
                          "diverges: add data that excites the slow modes, use refine='output_error', or fix "
                          "known rows with kinematics=", IdentificationWarning, stacklevel=2)
        self.model_ = model
        self.coef_ = model.coef
        self.terms_ = model.terms
        self.threshold_ = float(threshold)
        self.states_ = model.states
        self.inputs_ = model.inputs
        return self

    # -- data
    def _prepare(self, data: Trajectory | Sequence[Trajectory], states: Sequence[str] | None,
                 inputs: Sequence[str] | None):
        records = [data] if isinstance(data, Trajectory) else list(data) if isinstance(data, Sequence) else None
        if not records or not all(isinstance(r, Trajectory) for r in records):
            raise InvalidSettingError("data must be a Trajectory or a non-empty list of Trajectories")
        velocities = _check_mapping("velocities", self.velocities)
        first = records[0]
        if states is None:
            state_names = [s for s in first.states if s not in velocities]
            state_names += [v for v in velocities if v not in state_names]
        else:
            state_names = [states] if isinstance(states, str) else list(states)
        input_names = list(first.inputs) if inputs is None else ([inputs] if isinstance(inputs, str)
                                                                 else list(inputs))
        if not state_names:
            raise InvalidSettingError(f"no states to identify: the data has no signal with role 'state'; pass "
                                      f"states=[...] (available: {', '.join(first.names)})")
        both = state_names + input_names
        repeated = sorted({n for n in both if both.count(n) > 1})
        if repeated:
            raise InvalidSettingError(f"{', '.join(repeated)} named more than once among states and inputs")
        for pos in velocities.values():
            if pos not in state_names and pos not in input_names:
                raise InvalidSettingError(f"velocities derives from {pos!r}, which is not among the states "
                                          f"{state_names}; add it to states")
        for vel in velocities:
            if vel not in state_names:
                raise InvalidSettingError(f"derived velocity {vel!r} is not among the states {state_names}")
        dt = None
        runs = []
        for number, record in enumerate(records):
            label = f"record {number}" if len(records) > 1 else "the data"
            measured = [n for n in state_names if n not in velocities] + input_names
            missing = [n for n in measured if n not in record.names]
            if missing:
                raise UnknownVariableError(f"{label} has no column {', '.join(map(repr, missing))}; available: "
                                           f"{', '.join(record.names)}")
            if len(record) < 3:
                raise DataError(f"{label} has {len(record)} samples; identification needs a longer record")
            if not record.is_uniform():
                raise DataError(f"{label} is not uniformly sampled (steps vary by more than 1e-6 relative); "
                                "resample it to one step")
            step = record.dt
            if dt is None:
                dt = step
            elif abs(step - dt) > 1e-9 * dt:
                raise DataError(f"{label} has step {step:g} s but record 0 has {dt:g} s; all records must "
                                "have the same step (resample them)")
            values = {n: np.asarray(record[n], dtype=float) for n in measured}
            for name, column in values.items():
                bad = ~np.isfinite(column)
                if bad.any():
                    k = int(np.argmax(bad))
                    raise DataError(f"signal {name!r} of {label} is {column[k]} at t={record.time[k]:.9g} s; "
                                    "expected finite values; drop or fill the bad samples")
            for vel, pos in velocities.items():
                values[vel] = self._derive_velocity(values[pos], record.time, vel)
            x = np.column_stack([values[n] for n in state_names])
            u = np.column_stack([values[n] for n in input_names]) if input_names else np.zeros((len(x), 0))
            runs.append((x, u, record))
        dropped = []
        for j, name in enumerate(input_names):
            column = np.concatenate([u[:-1, j] for _, u, _ in runs])
            if np.ptp(column) <= 1e-12 * max(1.0, float(np.max(np.abs(column)))):
                dropped.append(name)
                warnings.warn(f"input {name!r} is constant ({column[0]:g}) in the data: it is not persistently "
                              "exciting, so its effect cannot be identified; it is left out of the model "
                              "(excite it, or pass inputs=[...] without it)", IdentificationWarning, stacklevel=3)
        keep = [j for j, n in enumerate(input_names) if n not in dropped]
        input_names = [input_names[j] for j in keep]
        units = {}
        for n in state_names + input_names:
            if n in first.names:
                units[n] = first.units[first.names.index(n)]
        for vel, pos in velocities.items():
            units[vel] = f"{units.get(pos, '')}/s" if units.get(pos) else ""
        self._units = units
        return [(x, u[:, keep]) for x, u, _ in runs], state_names, input_names, float(dt), dropped

    def _derive_velocity(self, position: np.ndarray, t: np.ndarray, name: str) -> np.ndarray:
        options = dict(self.velocity_options)
        if self.velocity_method == "smoothed_finite_difference" and not options:
            options = {"window_length": 7, "polyorder": 3}
        try:
            diff = _differentiator(self.velocity_method, options, len(position))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                value = np.asarray(diff(position[:, None], t), dtype=float).ravel()
        except (ValueError, TypeError, KeyError, np.linalg.LinAlgError) as exc:
            raise InvalidSettingError(f"deriving {name!r} with {self.velocity_method} failed ({exc}); check "
                                      "velocity_options") from None
        if not np.all(np.isfinite(value)):
            raise DataError(f"deriving {name!r} with {self.velocity_method} gave non-finite values; "
                            "check velocity_options")
        return value

    def _kinematics(self, state_names: list[str]) -> dict[str, str]:
        kin = _check_mapping("kinematics", self.kinematics)
        for vel, pos in (self.velocities or {}).items():
            if kin.get(pos, vel) != vel:
                raise InvalidSettingError(f"kinematics says d{pos}/dt = {kin[pos]} but velocities derives {vel} "
                                          f"from {pos}; make them agree")
            kin[pos] = vel
        for pos, vel in kin.items():
            for name in (pos, vel):
                if name not in state_names:
                    raise UnknownVariableError(f"kinematics names {name!r}, which is not a state; states: "
                                               f"{', '.join(state_names)}")
        return kin

    def _library(self, state_names: list[str], input_names: list[str]) -> list[str]:
        names = state_names + input_names
        if self.library == "linear":
            library = (["1"] if self.include_constant else []) + names
        else:
            library = polynomial_terms(names, int(self.degree), include_bias=self.include_constant)
        for text in self.terms:
            term = Term(text)
            term.check_names(names)
            if term.text not in library:
                library.append(term.text)
        if not library:
            raise InvalidSettingError("the library is empty: include the constant or add states, inputs, terms")
        kin = self._kinematics(state_names)
        for pos, vel in kin.items():
            if vel not in library:
                raise InvalidSettingError(f"kinematic row {pos}' = {vel} needs the term {vel!r} in the library")
        return library

    def _window(self) -> int:
        return int(self.differentiation_options.get("window", 30))

    # -- equation error
    def _equations(self, runs, parsed, state_names, input_names, dt, kin):
        """Stack features and targets of every record: (features, targets, N_eff, meta)."""
        method = self.differentiation
        meta: dict[str, Any] = {"method": method, "units": self._units}
        feats, targs = [], []
        noise_var = None
        if method == "zoh":
            allowed = {"1", *state_names, *input_names}
            nonlinear = [t.text for t in parsed if t.text not in allowed]
            if nonlinear:
                raise InvalidSettingError(f"differentiation='zoh' is exact for linear libraries only; the library "
                                          f"has {', '.join(nonlinear)}; use differentiation='integral'")
            dense = _zoh_dense(runs, parsed, state_names, input_names, dt)
            meta["dense_continuous_coef"] = dense.tolist()
            for x, u in runs:
                theta = _evaluate(parsed, state_names, input_names, x[:-1], u[:-1])
                feats.append(theta)
                targs.append(theta @ dense.T)
            n_eff = sum(len(x) - 1 for x, _ in runs)
        elif method == "integral":
            window = self._window()
            meta["window"] = window
            systems = [_IntegralEquations(parsed, state_names, input_names, x, u, dt, window) for x, u in runs]
            targets = np.vstack([s.targets for s in systems])
            coef = None
            for _ in range(3):  # trapezoid, then two passes of the end correction along the fitted field
                features = np.vstack([s.features(coef) for s in systems])
                coef = self._dense_field(features, targets, parsed, state_names, kin)
            feats, targs = [features], [targets]
            n_eff = sum((len(x) - 1) / window for x, _ in runs)
            if self.noise_compensation:
                sigma2 = _white_noise_variance(runs, len(state_names))
                meta["noise_std"] = dict(zip(state_names, np.sqrt(sigma2).tolist(), strict=True))
                # a window's trapezoid weights are dt*(1/2, 1, ..., 1, 1/2): noise variance dt^2*(window - 1/2)
                noise_var = np.array([sigma2[state_names.index(t.text)] * dt ** 2 * (window - 0.5)
                                      if t.text in state_names else 0.0 for t in parsed])
        else:
            options = dict(self.differentiation_options)
            meta["options"] = options
            for x, u in runs:
                t = dt * np.arange(len(x))
                try:
                    diff = _differentiator(method, options, len(x))
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        xdot = np.asarray(diff(x, t), dtype=float)
                except (ValueError, TypeError, KeyError, np.linalg.LinAlgError) as exc:
                    raise InvalidSettingError(f"differentiation {method!r} failed ({exc}); check "
                                              "differentiation_options") from None
                smooth = getattr(diff, "smoothed_x_", None)
                xs = np.asarray(smooth, dtype=float) if smooth is not None and np.shape(smooth) == x.shape else x
                good = np.all(np.isfinite(xdot), axis=1) & np.all(np.isfinite(xs), axis=1)
                if good.sum() < 2:
                    raise InvalidSettingError(f"differentiation {method!r} gave no finite derivatives; check "
                                              "differentiation_options")
                # a central derivative at t_k measures the mean of the slopes before and after the sample,
                # where the inputs u[k-1] and u[k] are held: evaluate the library the same way
                before = np.vstack([u[:1], u[:-1]])
                theta = 0.5 * (_evaluate(parsed, state_names, input_names, xs, before)
                               + _evaluate(parsed, state_names, input_names, xs, u))
                feats.append(theta[good])
                targs.append(xdot[good])
            n_eff = sum(len(f) for f in feats)
        features, targets = np.vstack(feats), np.vstack(targs)
        if not (np.all(np.isfinite(features)) and np.all(np.isfinite(targets))):
            bad = [term.text for term, ok in zip(parsed, np.all(np.isfinite(features), axis=0), strict=True)
                   if not ok]
            raise DataError(f"the library is not finite on the data (terms {', '.join(bad) or '?'}); "
                            "remove terms such as log or 1/x that the data makes infinite")
        return features, targets, max(float(n_eff), 1.0), meta, noise_var

    @staticmethod
    def _dense_field(features: np.ndarray, targets: np.ndarray, parsed, state_names, kin) -> np.ndarray:
        """Least-squares coefficients of every row (kinematic rows exact): the field for the end correction."""
        scale = np.sqrt(np.mean(features ** 2, axis=0))
        scale = np.where(scale > 0, scale, 1.0)
        sol, *_ = np.linalg.lstsq(features / scale, targets, rcond=None)
        coef = (sol / scale[:, None]).T
        names = [t.text for t in parsed]
        for pos, vel in kin.items():
            row = state_names.index(pos)
            coef[row] = 0.0
            coef[row, names.index(vel)] = 1.0
        return np.where(np.isfinite(coef), coef, 0.0)

    # -- sparse regression
    def _stlsq(self, r: np.ndarray, qy: np.ndarray, threshold: float, n: int) -> np.ndarray:
        """pysindy STLSQ on the compressed problem ``(R, Q^T y)`` of ``theta = Q R``: the same solution as on
        ``(theta, y)`` (the two least-squares objectives differ by a constant), at a fraction of the cost."""
        from pysindy.optimizers import STLSQ

        opt = STLSQ(threshold=float(threshold), alpha=float(self.ridge) * n, max_iter=50, normalize_columns=False,
                    unbias=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            opt.fit(r, qy)
        coef = np.asarray(opt.coef_, dtype=float).reshape(qy.shape[1], r.shape[1])
        return np.where(np.isfinite(coef), coef, 0.0)

    def _sparse(self, theta: np.ndarray, y: np.ndarray, n_eff: float, noise: np.ndarray | None,
                threshold: float | str):
        """STLSQ (given or "auto" threshold) on the scaled problem; `noise` is the noise part of each column's
        sum of squares (noise compensation), or None."""
        n = theta.shape[0]
        q, r = np.linalg.qr(theta)
        qy = q.T @ y
        gram = r.T @ r
        cross = theta.T @ y
        y2 = np.sum(y ** 2, axis=0)
        compensation: dict[str, Any] = {"applied": False}
        if noise is not None and np.any(noise > 0):
            # bias-compensated normal equations, truncated to the directions whose signal exceeds the noise
            noise_gram = np.diag(noise)
            ev, vec = np.linalg.eigh(gram - noise_gram)
            noise_level = np.einsum("ij,ik,kj->j", vec, noise_gram, vec)
            keep = ev > _NOISE_MARGIN * noise_level + 1e-12 * max(float(ev.max()), 1e-300)
            r = np.sqrt(ev[keep])[:, None] * vec[:, keep].T
            qy = (vec[:, keep].T @ cross) / np.sqrt(ev[keep])[:, None]
            compensation = {"applied": True, "dropped_directions": int((~keep).sum()),
                            "method": "bias-compensated least squares, directions with signal below "
                                      f"{_NOISE_MARGIN:g} x noise dropped"}

        def rss(xi: np.ndarray) -> np.ndarray:  # plain (uncompensated) residual sum of squares / n
            return np.maximum(y2 - 2.0 * np.einsum("ij,ji->i", xi, cross) + np.einsum("ij,jk,ik->i", xi, gram, xi),
                              0.0) / n

        if threshold != "auto":
            value = float(threshold)
            return self._stlsq(r, qy, value, n), value, {"method": "given", "value": value,
                                                         "noise_compensation": compensation}
        dense = self._stlsq(r, qy, 0.0, n)
        mags = np.unique(np.abs(dense[dense != 0.0]))
        cuts = [0.0] + [math.sqrt(a * b) for a, b in zip(mags[:-1], mags[1:], strict=True)]
        if len(cuts) > _MAX_CANDIDATES:
            cuts = [0.0] + list(np.geomspace(cuts[1], cuts[-1], _MAX_CANDIDATES - 1))
        candidates, best = [], None
        for cut in cuts:
            xi = dense if cut == 0.0 else self._stlsq(r, qy, cut, n)
            k = int(np.count_nonzero(xi))
            score = float(np.sum(n_eff * np.log(np.maximum(rss(xi), _BIC_FLOOR ** 2))) + k * math.log(n_eff))
            candidates.append({"threshold": float(cut), "nonzero": k, "bic": score})
            if best is None or score <= best[0] + 1e-9 * abs(best[0]):
                best = (score, cut, xi)
        assert best is not None
        meta = {"method": "auto: BIC on the scaled equation error along the STLSQ threshold path",
                "value": float(best[1]), "floor": _BIC_FLOOR, "n_eff": n_eff, "samples": n,
                "noise_compensation": compensation, "candidates": candidates}
        return best[2], float(best[1]), meta

    # -- refinement
    def _refine(self, model: IdentifiedModel, runs, dt: float, kin: dict[str, str], coef_scale: np.ndarray,
                meta: dict[str, Any], known_x0: list[np.ndarray] | None) -> IdentifiedModel:
        from .output_error import refine_output_error

        support = model.coef != 0.0
        for pos in kin:
            support[model.states.index(pos)] = False
        options = {"prior": 0.1, "continuation": True, "max_nfev": 60, **self.refine_options}
        fit = refine_output_error(model, [(x, u[:-1]) for x, u in runs], dt=dt, support=support,
                                  estimate_x0=self.refine_initial_state and known_x0 is None, x0=known_x0,
                                  coef_scale=coef_scale, **options)
        meta["refinement"] = {"method": "output_error", "status": fit.status, "cost": fit.cost,
                              "cost_start": fit.cost_start, "stages": fit.stages, "options": options,
                              "refined_coefficients": int(support.sum()),
                              "std_error": fit.std_error.tolist() if fit.std_error is not None else None}
        if self.threshold == "auto":
            fit, support = self._prune(model, runs, dt, fit, support, known_x0, coef_scale, meta)
            meta["refinement"].update(status=fit.status, cost=fit.cost, refined_coefficients=int(support.sum()),
                                      std_error=fit.std_error.tolist() if fit.std_error is not None else None)
        meta["x0"] = [v.tolist() for v in fit.x0]
        meta["seconds"]["refinement"] = fit.seconds
        return IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=fit.coef, dt=dt)

    def _prune(self, model: IdentifiedModel, runs, dt: float, fit, support: np.ndarray,
               known_x0: list[np.ndarray] | None, coef_scale: np.ndarray, meta: dict[str, Any]):
        """threshold="auto" with refinement: backward elimination on the output-error fit (Wald tests, BIC).

        The least significant refined coefficient (smallest ``t = |coef| / standard error``, from the
        covariance of the output-error fit) is removed while ``t < sqrt(log(n))`` (``n`` the number of
        residuals: removing it lowers the output error's BIC, to second order). One at a time, the others and
        their covariance updated after each removal as the constrained least-squares solution
        (``theta -= C[:, j] theta_j / C[j, j]``, ``C -= C[:, j] C[j, :] / C[j, j]``), because collinear terms
        are each insignificant while jointly needed. The reduced model is refined again and kept if the
        output error's BIC ``n*log(cost) + k*log(n)`` went down; otherwise only the single least significant
        coefficient is tried. Rounds repeat on the new fit until nothing is removed.
        """
        from .output_error import refine_output_error

        n_obs = sum(len(x) for x, _ in runs) * len(model.states)
        limit = math.sqrt(math.log(n_obs))
        removed: list[dict[str, Any]] = []
        runs_oe = [(x, u[:-1]) for x, u in runs]
        seconds = fit.seconds

        def bic(f, sup: np.ndarray) -> float:
            return n_obs * math.log(max(f.cost, 1e-300)) + float(sup.sum()) * math.log(n_obs)

        for _ in range(int(support.sum())):
            if fit.covariance is None:
                break
            index = [tuple(ij) for ij in np.argwhere(support)]
            theta = np.array([fit.coef[ij] for ij in index])
            cov = np.array(fit.covariance, dtype=float)
            alive = list(range(len(index)))
            proposal: list[tuple[int, float, np.ndarray]] = []  # (index, t, theta after removing it)
            while len(alive) > 1:
                var = np.array([cov[j, j] for j in alive])
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = np.where(var > 0, np.abs(theta[alive]) / np.sqrt(var), np.inf)
                pos = int(np.argmin(t))
                if not t[pos] < limit:
                    break
                j = alive.pop(pos)
                theta = theta - cov[:, j] * theta[j] / cov[j, j]
                cov = cov - np.outer(cov[:, j], cov[j, :]) / cov[j, j]
                theta[j] = 0.0
                proposal.append((j, float(t[pos]), theta.copy()))
            if not proposal:
                break
            accepted = None
            for step in (proposal, proposal[:1]):  # all Wald removals; failing that, the least significant one
                coef = fit.coef.copy()
                new_support = support.copy()
                for j, ij in enumerate(index):
                    coef[ij] = step[-1][2][j] if len(step) == len(proposal) else fit.coef[ij]
                for j, _, _ in step:
                    new_support[index[j]] = False
                    coef[index[j]] = 0.0
                start = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=coef,
                                        dt=dt)
                trial = refine_output_error(start, runs_oe, dt=dt, support=new_support,
                                            estimate_x0=self.refine_initial_state and known_x0 is None,
                                            x0=known_x0 if known_x0 is not None else fit.x0,
                                            coef_scale=coef_scale, continuation=False,
                                            max_nfev=int(self.refine_options.get("max_nfev", 60)))
                seconds += trial.seconds
                if trial.status == "ok" and bic(trial, new_support) <= bic(fit, support):
                    accepted = (trial, new_support, step)
                    break
                if len(proposal) == 1:
                    break
            if accepted is None:
                break
            fit, support, step = accepted
            for j, t_value, _ in step:
                i, k = index[j]
                removed.append({"state": model.states[i], "term": model.terms[k], "t": t_value})
        meta["threshold"] = {"method": "auto with refinement: dense equation-error fit, refined by output error, "
                                       "then backward elimination (Wald) of coefficients with |coef|/std_error "
                                       "below sqrt(log(n)), n the number of residuals, kept when the output "
                                       "error's BIC drops",
                             "value": limit, "residuals": n_obs, "removed": removed,
                             "equation_error": meta["threshold"]}
        object.__setattr__(fit, "seconds", seconds)
        return fit, support

    # -- stability
    @staticmethod
    def _stability(model: IdentifiedModel, runs, dt: float) -> dict[str, Any]:
        span = max(len(x) - 1 for x, _ in runs) * dt
        out: dict[str, Any] = {}
        if model.is_linear:
            a = model.linear_matrices()[0]
            eig = np.linalg.eigvals(a)
            worst = float(np.max(eig.real))
            # a mode that grows at most e-fold over the record cannot be told from an integrator by this data
            limit = 1.0 / span
            out["eigenvalues"] = [[float(v.real), float(v.imag)] for v in eig]
            out["stable"] = bool(worst <= limit)
            kind = "stable" if worst < 0 else "marginal" if worst <= limit else "unstable"
            out["stability"] = (f"{kind}: largest real part of the eigenvalues {worst:.6g} 1/s (marginal up to "
                                f"{limit:.3g} 1/s: at most e-fold growth over the {span:.6g} s record)")
            return out
        x, u = max(runs, key=lambda r: len(r[0]))
        sim = model.simulate(x[0], u[:-1], dt=dt)
        out["stable"] = bool(sim.ok)
        out["stability"] = ("the free run on the longest record " + ("stays in range" if sim.ok else
                            f"diverges: {sim.message}"))
        return out

    # -------------------------------------------------------------------------------------------- use
    def _fitted(self) -> IdentifiedModel:
        model = getattr(self, "model_", None)
        if model is None:
            raise InvalidSettingError("this SINDYc is not fitted yet; call fit(data) first")
        return model

    def equations(self, precision: int = 6) -> list[str]:
        """The identified equations, one line per state (zero terms omitted).

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.identify.model import IdentifiedModel
        >>> plant = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-0.5]]))
        >>> SINDYc(include_constant=False).fit(plant.simulate([1.0], n_steps=200, dt=0.01).to_trajectory()).equations()
        ["x' = -0.5 x"]
        """
        return self._fitted().equations(precision)

    def _arrays(self, trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray]:
        model = self._fitted()
        if not isinstance(trajectory, Trajectory):
            raise InvalidSettingError(f"expected a Trajectory, got {type(trajectory).__name__}")
        velocities = dict(self.velocities or {})
        measured = [n for n in model.states if n not in velocities] + list(model.inputs)
        missing = [n for n in measured if n not in trajectory.names]
        if missing:
            raise UnknownVariableError(f"the trajectory has no column {', '.join(map(repr, missing))}; "
                                       f"available: {', '.join(trajectory.names)}")
        values = {n: np.asarray(trajectory[n], dtype=float) for n in measured}
        for vel, pos in velocities.items():
            values[vel] = self._derive_velocity(values[pos], trajectory.time, vel)
        x = np.column_stack([values[n] for n in model.states])
        u = np.column_stack([values[n] for n in model.inputs]) if model.inputs else np.zeros((len(x), 0))
        return x, u

    def predict(self, trajectory: Trajectory) -> np.ndarray:
        """Time derivatives ``dx/dt`` the model gives at every sample of `trajectory`.

        Returns
        -------
        ndarray, shape (n_samples, n_states)

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.identify.model import IdentifiedModel
        >>> plant = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-0.5]]))
        >>> data = plant.simulate([1.0], n_steps=200, dt=0.01).to_trajectory()
        >>> est = SINDYc(include_constant=False).fit(data)
        >>> round(float(est.predict(data)[0, 0]), 9)
        -0.5
        """
        x, u = self._arrays(trajectory)
        return self._fitted().predict(x, u)

    def simulate(self, x0: Sequence[float], inputs: np.ndarray | None = None, *,
                 dt: float | None = None, n_steps: int | None = None) -> SimulationResult:
        """Free-run simulation of the identified model with zero-order-hold inputs (see
        :meth:`IdentifiedModel.simulate`); status ``"diverged"`` if it leaves the range.

        Parameters
        ----------
        x0 : sequence of float
            Initial state, in the order of ``states_``.
        inputs : ndarray, shape (n_steps, n_inputs), optional
            Row k held over step k, in the order of ``inputs_``.
        dt : float, optional
            Step; default the data's.
        n_steps : int, optional
            For a model without inputs.

        Raises
        ------
        DataError
            NaN or inf in `x0` or `inputs`.

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.identify.model import IdentifiedModel
        >>> plant = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-0.5]]))
        >>> est = SINDYc(include_constant=False).fit(plant.simulate([1.0], n_steps=200, dt=0.01).to_trajectory())
        >>> sim = est.simulate([2.0], n_steps=100)
        >>> sim.status, round(float(sim.states[-1, 0]), 6)   # 2*exp(-0.5)
        ('ok', 1.213061)
        """
        model = self._fitted()
        x0 = np.asarray(x0, dtype=float).ravel()
        if not np.all(np.isfinite(x0)):
            k = int(np.argmax(~np.isfinite(x0)))
            name = model.states[k] if k < len(model.states) else str(k)
            raise DataError(f"x0 holds {x0[k]} for {name!r}; give a finite initial state")
        if inputs is not None:
            u = np.asarray(inputs, dtype=float)
            if u.size and not np.all(np.isfinite(u)):
                row, col = np.argwhere(~np.isfinite(u.reshape(len(u), -1)))[0]
                name = model.inputs[col] if col < len(model.inputs) else str(col)
                t = (dt or model.dt or 0.0) * row
                raise DataError(f"input {name!r} is {u.reshape(len(u), -1)[row, col]} at step {row} "
                                f"(t={t:.9g} s); give finite inputs")
            inputs = u
        return model.simulate(x0, inputs, dt=dt, n_steps=n_steps)

    def score(self, trajectory: Trajectory, *, metric: str = "r2") -> float:
        """Free-run accuracy on `trajectory`: simulate from its first state with its inputs and compare the
        states, averaged over the states.

        Parameters
        ----------
        trajectory : Trajectory
            Data with the model's states and inputs.
        metric : {"r2", "nrmse", "max_deviation"}
            See :mod:`cosim.identify.metrics` (``"nrmse"`` is the MATLAB fit in %, ``"max_deviation"`` in % of the
            amplitude; lower is better for that one).

        Returns
        -------
        float
            The mean over states; ``-inf`` (``inf`` for max_deviation) when the simulation diverges.

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.identify.model import IdentifiedModel
        >>> plant = IdentifiedModel(states=("x",), inputs=(), terms=("x",), coef=np.array([[-0.5]]))
        >>> data = plant.simulate([1.0], n_steps=200, dt=0.01).to_trajectory()
        >>> round(SINDYc(include_constant=False).fit(data).score(data, metric="nrmse"), 6)
        100.0
        """
        from .metrics import METRICS

        if metric not in METRICS:
            raise InvalidSettingError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")
        func, higher_better = METRICS[metric]
        model = self._fitted()
        x, u = self._arrays(trajectory)
        sim = model.simulate(x[0], u[:-1], dt=trajectory.dt)
        if not sim.ok:
            return -math.inf if higher_better else math.inf
        return float(np.mean(func(x, sim.states)))

    def to_statespace(self, **kw: Any) -> Any:
        """The model as a python-control ``StateSpace``: ``cosim.export.to_statespace(self.model_, **kw)``.

        Parameters
        ----------
        **kw
            Options of :func:`cosim.export.to_statespace` (``dt`` for the discrete-time system,
            ``operating_point``, ``constant``, ``name``).

        Examples
        --------
        >>> import numpy as np
        >>> from cosim.identify.model import IdentifiedModel
        >>> plant = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-2.0, 1.0]]))
        >>> u = np.sign(np.sin(np.arange(1000) * 0.01))[:, None]
        >>> est = SINDYc(include_constant=False).fit(plant.simulate([0.0], u, dt=0.01).to_trajectory())
        >>> sys = est.to_statespace()
        >>> np.round(sys.A, 6).tolist(), np.round(sys.B, 6).tolist()
        ([[-2.0]], [[1.0]])
        """
        from .. import export  # written separately; imported when needed

        return export.to_statespace(self._fitted(), **kw)

    def __repr__(self) -> str:
        changed = {k: v for k, v in self.get_params().items() if v != _DEFAULTS.get(k)}
        return f"SINDYc({', '.join(f'{k}={v!r}' for k, v in changed.items())})"


_DEFAULTS = {"library": "linear", "degree": 2, "terms": [], "include_constant": True, "threshold": "auto",
             "ridge": 0.0, "differentiation": "integral", "differentiation_options": {}, "noise_compensation": True,
             "kinematics": {},
             "velocities": {}, "velocity_method": "smoothed_finite_difference", "velocity_options": {},
             "refine": None, "refine_initial_state": True, "refine_options": {}}


# ---------------------------------------------------------------------------------------------------------
# features


def _evaluate(parsed: Sequence[Term], state_names: Sequence[str], input_names: Sequence[str], x: np.ndarray,
              u: np.ndarray) -> np.ndarray:
    values = {n: x[:, i] for i, n in enumerate(state_names)}
    values.update({n: u[:, j] for j, n in enumerate(input_names)})
    with np.errstate(all="ignore"):
        return np.column_stack([t.evaluate(values) for t in parsed])


class _IntegralEquations:
    """Sliding windows ``[a, a + window]`` of one record: targets ``x_b - x_a``, features ``integral theta``.

    Interval k (input held at ``u[k]``) is integrated by the trapezoid on ``theta(x_k, u_k)`` and
    ``theta(x_{k+1}, u_k)`` plus its end correction ``-dt^2/12 * (g'(t_{k+1}-) - g'(t_k+))``, which makes
    it exact to O(dt^5) per interval (O(dt^4) per window) for any input pattern, because inside an interval
    the integrand is smooth. The derivative ``g'`` of each term along the trajectory is taken along the
    model's own vector field, ``grad g . (coef @ theta)``, with the input held: :meth:`features` takes the
    current coefficient estimate, and the fit iterates (the correction is ~(omega*dt)^2/12 of the feature, so
    two passes reach the O(dt^4) floor).
    """

    def __init__(self, parsed, state_names, input_names, x: np.ndarray, u: np.ndarray, dt: float, window: int):
        self.parsed, self.state_names, self.input_names = parsed, state_names, input_names
        self.x, self.u, self.dt = x, u[:len(x) - 1], dt
        n = len(x) - 1
        self.g0 = _evaluate(parsed, state_names, input_names, x[:-1], self.u)  # theta(x_k, u_k)
        self.g1 = _evaluate(parsed, state_names, input_names, x[1:], self.u)   # theta(x_{k+1}, u_k)
        self.trapezoid = np.vstack([np.zeros((1, self.g0.shape[1])),
                                    np.cumsum(0.5 * dt * (self.g0 + self.g1), axis=0)])
        self.a = np.arange(0, n - window + 1)
        self.b = self.a + window
        self.targets = x[self.b] - x[self.a]

    def _slope(self, points: np.ndarray, theta: np.ndarray, coef: np.ndarray) -> np.ndarray:
        """d theta/dt at `points` (inputs held) along the field ``coef @ theta``: central difference."""
        velocity = theta @ coef.T
        size = np.max(np.abs(velocity), axis=0)
        scale = np.max(np.abs(self.x), axis=0)
        h = 1e-6 * float(np.min(np.where(size > 0, np.maximum(scale, 1e-300) / np.where(size > 0, size, 1.0),
                                          np.inf)))
        if not math.isfinite(h) or h <= 0:
            return np.zeros_like(theta)
        plus = _evaluate(self.parsed, self.state_names, self.input_names, points + h * velocity, self.u)
        minus = _evaluate(self.parsed, self.state_names, self.input_names, points - h * velocity, self.u)
        return (plus - minus) / (2.0 * h)

    def features(self, coef: np.ndarray | None) -> np.ndarray:
        cum = self.trapezoid
        if coef is not None:
            d0 = self._slope(self.x[:-1], self.g0, coef)
            d1 = self._slope(self.x[1:], self.g1, coef)
            correction = np.vstack([np.zeros((1, d0.shape[1])), np.cumsum(d1 - d0, axis=0)])
            cum = cum - self.dt ** 2 / 12.0 * correction
        return cum[self.b] - cum[self.a]


def _known_initial_states(x0: Any, state_names: Sequence[str], n_runs: int) -> list[np.ndarray] | None:
    if x0 is None:
        return None
    items = [x0] if isinstance(x0, Mapping) or (np.ndim(x0) == 1 and n_runs == 1) else list(x0)
    if len(items) != n_runs:
        raise InvalidSettingError(f"x0 gives {len(items)} initial states for {n_runs} records; give one per record")
    out = []
    for item in items:
        if isinstance(item, Mapping):
            missing = [s for s in state_names if s not in item]
            if missing:
                raise UnknownVariableError(f"x0 lacks {', '.join(missing)}; give a value for every state "
                                           f"({', '.join(state_names)})")
            item = [item[s] for s in state_names]
        try:
            vec = np.asarray(item, dtype=float).ravel()
        except (TypeError, ValueError):
            raise InvalidSettingError(f"x0 must hold numbers, got {item!r}") from None
        if vec.shape != (len(state_names),) or not np.all(np.isfinite(vec)):
            raise DataError(f"x0 must hold {len(state_names)} finite values ({', '.join(state_names)}), "
                            f"got {vec.tolist()}")
        out.append(vec)
    return out


def _white_noise_variance(runs, n_states: int) -> np.ndarray:
    """Variance of white measurement noise on each state, from fourth differences of the samples.

    A fourth difference of a smooth signal sampled fast is tiny, of white noise it has variance
    ``70*sigma^2``; the median absolute deviation (x 1.4826) makes steps and kinks in the signal (square-wave
    edges) count as outliers, not as noise.
    """
    d = np.vstack([np.diff(x, n=4, axis=0) for x, _ in runs if len(x) > 8] or [np.zeros((1, n_states))])
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return (1.4826 * mad) ** 2 / 70.0


def _zoh_dense(runs, parsed, state_names, input_names, dt: float) -> np.ndarray:
    """Dense continuous coefficients from the least-squares discrete map and the matrix logarithm."""
    from scipy.linalg import logm

    n, m = len(state_names), len(input_names)
    names = [t.text for t in parsed]
    has_const = "1" in names
    q = n + m + (1 if has_const else 0)
    order = list(state_names) + list(input_names) + (["1"] if has_const else [])
    z = np.vstack([np.column_stack([x[:-1], u[:-1]] + ([np.ones((len(x) - 1, 1))] if has_const else []))
                   for x, u in runs])
    target = np.vstack([x[1:] for x, _ in runs])
    g, *_ = np.linalg.lstsq(z, target, rcond=None)
    big = np.eye(q)
    big[:n, :] = g.T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log = logm(big)
    log = np.asarray(log)
    if np.iscomplexobj(log):
        if np.max(np.abs(log.imag)) > 1e-6 * max(np.max(np.abs(log.real)), 1e-300):
            raise DataError("the fitted discrete-time map has no real matrix logarithm (eigenvalues on the negative "
                            "real axis: noisy data or too coarse a sampling); use differentiation='integral'")
        log = log.real
    cont = log[:n] / dt
    if not np.all(np.isfinite(cont)):
        raise DataError("the discrete-time map is singular (is every state and input excited?); use "
                        "differentiation='integral'")
    dense = np.zeros((n, len(names)))
    for k, name in enumerate(names):
        dense[:, k] = cont[:, order.index(name)]
    return dense


def _differentiator(method: str, options: Mapping[str, Any], n: int):
    """A pysindy differentiation object for `method` with user `options` (defaults where needed)."""
    import pysindy as ps

    opts = dict(options)
    if method == "finite_difference":
        return ps.FiniteDifference(order=int(opts.pop("order", 2)), **opts)
    if method == "smoothed_finite_difference":
        kws = {"window_length": int(opts.pop("window_length", 21)), "polyorder": int(opts.pop("polyorder", 3))}
        if kws["window_length"] > n:
            raise ValueError(f"window_length {kws['window_length']} is longer than the {n} samples")
        return ps.SmoothedFiniteDifference(smoother_kws=kws, **opts)
    return ps.SINDyDerivative(kind=method, **opts)
