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
     2257 Hz (resonance 17.8 Hz, omega*dt = 0.05, a 4 rad initial twist) that is 2e-4 against 3e-8 relative
     coefficient error. Samples of a fixed-step forward Euler (co-simulation FMUs) take the left rectangle,
     exact there, when it fits better (:mod:`cosim.identify._sampler`). Integration also averages the
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
   * with ``refine="output_error"``, equation error cannot judge small terms on noisy data (at 10 % noise the
     servo's damping and input terms are below the equation error's noise), so the dense equation-error fit (the
     BIC one if it leaves <= 1e-4 of each target: noise-free data decide the structure there) is refined by output
     error and then pruned by backward elimination with Wald tests: the coefficient with the smallest |coef| /
     standard error (output-error Jacobian) goes while that t-statistic is below ``sqrt(log(n))`` (the output
     error's BIC drops), the others updated as the constrained fit; then the reduced model is refined again (see
     :func:`cosim.identify._refinement._prune`). BIC removes what the record cannot pin down: on a weakly exciting
     record (the 5 Hz sine, a short record, 50 % noise) that can be the input or a damping term of the servo.
     ``threshold=0`` keeps the whole library (as :func:`~cosim.study.cases.study_case` does, the study's X, U).

   The choice, the candidates and their scores are recorded in ``model_.meta["threshold"]``.
4. **Kinematics** (default ``kinematics="auto"``): rows such as ``d theta_m/dt = omega_m`` are fixed
   (coefficient exactly 1), not regressed nor refined. ``"auto"`` finds them by
   :func:`~cosim.identify.kinematics.detect_kinematics`: name pairs (``theta_m``/``omega_m``, ``x``/``x_dot``)
   the data do not contradict, and pairs the data show (a state equal to the running integral of another);
   a mapping ``{"theta_m": "omega_m"}`` gives them, ``None`` or ``"none"`` fixes none. What was used is in
   ``kinematics_``, ``model_.meta["kinematics"]`` (position -> velocity) and ``["kinematics_found"]`` (how).
5. **Output-error refinement** (``refine="output_error"``, the default): starting from the equation-error fit, the
   non-zero coefficients (sparsity pattern kept; fixed kinematic rows stay fixed) and each record's initial
   state are fitted to minimise the free-run simulation error, see :mod:`cosim.identify.output_error` (exact ZOH
   simulation and exact Jacobian for linear models, horizon continuation). This removes the bias equation
   error has with noisy states. A multi-start (:func:`cosim.identify._refinement._refine`): the
   noise-compensated and the uncompensated equation-error fits are each refined with and without the
   continuation prior, then (with pinned kinematics) once a fit that takes positions from the integrals of
   their velocities (:mod:`cosim.identify._velocity_integral`: a stiff shaft's twist below its position
   noise keeps its spring there); the least free-run cost wins (stopping once one reaches the white-noise
   floor); ``model_.meta["multistart"]`` records every run's cost and the winner.

Positions only: ``velocities={"omega_m": "theta_m"}`` derives the velocity state ``omega_m`` from the
measured position ``theta_m`` (``velocity_method="auto"``: a cubic Savitzky-Golay derivative whose window has
the least estimated mean-square error, :func:`cosim.data.derivatives.savgol_window`, or ``derive_window``
samples; recorded in ``model_.meta["data"]["derive_window"]``) and fixes the kinematic row
``d theta_m/dt = omega_m``.

Errors and warnings: unknown columns raise :class:`~cosim.errors.UnknownVariableError` listing the available
ones; NaN/inf, too few samples for the library (fewer than ``MIN_SAMPLES_PER_TERM`` per term) or records of
different steps raise :class:`~cosim.errors.DataError`; bad settings raise
:class:`~cosim.errors.InvalidSettingError`. A constant input (not persistently exciting) gives an
:class:`IdentificationWarning` naming it and is left out of the model. An unstable identified model raises
:class:`~cosim.errors.UnstableModelError` (its eigenvalues and what to try in the message, the model in its
``model`` attribute); with ``allow_unstable=True`` it gives an :class:`IdentificationWarning` instead and
``model_.meta["stable"] = False`` (with the eigenvalues of a linear model in ``meta["eigenvalues"]`` and a
sentence in ``meta["stability"]``); its simulation returns status ``"diverged"`` once it leaves the range. A
linear model counts as unstable when an eigenvalue's real part
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
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from ..data.trajectory import Trajectory
from ..errors import DataError, IdentificationWarning, InvalidSettingError
from ._differentiation import _derive_velocity
from ._equation_error import _window
from ._library import _kinematic_rows, _library_terms
from ._records import _known_initial_states, _measured, _prepare, _stacked, _warn_constant_inputs
from ._refinement import _analysis_runs, _refine_decimated, _starts
from ._sampler import _equations
from ._settings import _DEFAULTS, DIFFERENTIATION_METHODS, _check_mapping, _check_settings, _kinematics_setting
from ._sparse_regression import AUTO_IF_EXACT, _sparse_fit
from ._stability import _stability, _unstable
from .kinematics import _find_kinematics
from .model import IdentifiedModel, SimulationResult
from .terms import Term

__all__ = ["SINDYc", "IdentificationWarning", "DIFFERENTIATION_METHODS", "MIN_SAMPLES_PER_TERM"]

#: A fit needs at least this many samples per library term.
MIN_SAMPLES_PER_TERM = 10


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
    kinematics : "auto", "none", None or mapping
        Kinematic rows ``d position/dt = velocity``, coefficient exactly 1, not regressed (nor refined):
        ``"auto"`` detects them from the state names and data (module docstring), a mapping position state ->
        velocity state gives them, ``None`` or ``"none"`` fixes none.
    velocities : mapping, optional
        Velocity states to derive from measured positions, velocity name -> position column
        (``{"omega_m": "theta_m"}``); implies the kinematic row. A column of the velocity's name, if the data
        has one, is ignored.
    velocity_method : str
        Differentiator for `velocities`: ``"auto"`` (a cubic Savitzky-Golay derivative, window chosen from the
        data) or a pysindy differentiator name.
    velocity_options : mapping, optional
        Options of a pysindy `velocity_method` (``"smoothed_finite_difference"``: default
        ``{"window_length": 7, "polyorder": 3}``).
    derive_window : int, optional
        Window of the ``"auto"`` derivative in samples (odd, >= 5) instead of the one chosen from the data.
    refine : {"output_error", None}
        Refine the equation-error fit by output error (:mod:`cosim.identify.output_error`; default, as ``cosim
        identify``); None keeps the equation-error fit (faster, biased on noisy states; ``--no-refine``).
    refine_initial_state : bool
        With refinement, also estimate each record's initial state (recorded in ``meta["x0"]``).
    refine_options : mapping, optional
        Passed to :func:`cosim.identify.output_error.refine_output_error`: ``prior`` (default 0.1), ``continuation``
        (default True), ``max_nfev`` (per stage, default 60), ``exact_jacobian`` (default True: a nonlinear
        model's exact sensitivities), ``stability_limit`` (1/s: every refinement kept below that growth).
    allow_unstable : bool
        Keep an unstable identified model with an :class:`IdentificationWarning` instead of raising
        :class:`~cosim.errors.UnstableModelError`.
    prefer_stable : bool, optional
        With refinement, a stable refinement of the multi-start wins over an unstable one that costs less by up
        to a factor 2; if all are unstable, one more from the best with its unstable modes reflected, kept stable.
        Default: when unstable models are refused (``not allow_unstable``).
    decimate : "auto" or int
        With refinement, the multi-start runs on the records decimated by this factor
        (:func:`~cosim.data.decimation.decimate`), and its winner is refined once more on the records as given.
        ``"auto"``: records of more than 4000 samples sampled faster than ten times their band (or the
        equation-error model's fastest mode) are brought down to that rate, never below 4000 samples
        (:func:`~cosim.data.decimation.decimation_factor`); 1: never. Recorded in ``meta["refinement"]``.

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
    kinematics_ : tuple of KinematicPair
        The fixed kinematic rows, each with how it was found (``"name"``, ``"data"``, ``"given"``,
        ``"derived"``).

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
                 noise_compensation: bool = True, kinematics: Mapping[str, str] | str | None = "auto",
                 velocities: Mapping[str, str] | None = None, velocity_method: str = "auto",
                 velocity_options: Mapping[str, Any] | None = None, derive_window: int | None = None,
                 refine: str | None = "output_error", refine_initial_state: bool = True,
                 refine_options: Mapping[str, Any] | None = None, allow_unstable: bool = False,
                 decimate: int | str = "auto", prefer_stable: bool | None = None) -> None:
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
        self.derive_window = derive_window
        self.refine = refine
        self.refine_initial_state = refine_initial_state
        self.refine_options = dict(refine_options or {})
        self.allow_unstable = allow_unstable
        self.decimate = decimate
        self.prefer_stable = prefer_stable
        _check_settings(self)

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
                "noise_compensation": self.noise_compensation,
                "kinematics": (dict(self.kinematics) if isinstance(self.kinematics, Mapping)
                               else _kinematics_setting(self.kinematics)),
                "velocities": dict(self.velocities or {}),
                "velocity_method": self.velocity_method, "velocity_options": dict(self.velocity_options),
                "derive_window": self.derive_window,
                "refine": self.refine, "refine_initial_state": self.refine_initial_state,
                "refine_options": dict(self.refine_options), "allow_unstable": self.allow_unstable,
                "decimate": self.decimate, "prefer_stable": self.prefer_stable}

    # -------------------------------------------------------------------------------------------- fitting
    # one BLAS thread: the same data give the same model on every run (two OpenBLAS threads split sums in an
    # order that varies run to run), and the tall, thin least squares run no slower on 2 cores
    @threadpool_limits.wrap(limits=1, user_api="blas")
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
        UnknownVariableError, DataError, InvalidSettingError, UnstableModelError
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
        _check_settings(self)
        self._windows: dict[str, list[int]] = {}
        records = _prepare(data, states, inputs, _check_mapping("velocities", self.velocities), self._velocity)
        _warn_constant_inputs(records.constant_inputs)
        runs, state_names, input_names, dt = records.runs, records.states, records.inputs, records.dt
        pairs = _find_kinematics(self.kinematics, self.velocities, state_names, runs, dt)
        kin = _kinematic_rows({p.position: p.velocity for p in pairs if p.found != "derived"}, self.velocities,
                              state_names)
        known_x0 = _known_initial_states(x0, state_names, len(runs))
        library = _library_terms(self.library, self.degree, self.include_constant, self.terms, state_names,
                                 input_names, kin)
        n_terms = len(library)
        n_total = sum(len(x) for x, _ in runs)
        needed = MIN_SAMPLES_PER_TERM * n_terms + (len(runs) - 1)
        if n_total < needed:
            raise DataError(f"too few samples for the library: {n_total} samples for {n_terms} terms; at least "
                            f"{needed} are needed ({MIN_SAMPLES_PER_TERM} per term); record longer or use a "
                            "smaller library")
        window = _window(self.differentiation_options) if self.differentiation == "integral" else None
        if window is not None and any(len(x) <= window + 2 for x, _ in runs):
            raise DataError(f"a record has fewer samples than the integration window ({window} + 3); "
                            "record longer or give differentiation_options={'window': ...} smaller")
        parsed = [Term(t) for t in library]
        free_rows = [i for i, s in enumerate(state_names) if s not in kin]
        features, targets, n_eff, ee_meta, noise_var = _equations(
            runs, parsed, state_names, input_names, dt, kin, method=self.differentiation,
            options=self.differentiation_options, noise_compensation=self.noise_compensation)
        coef = np.zeros((len(state_names), n_terms))
        for pos, vel in kin.items():
            coef[state_names.index(pos), library.index(vel)] = 1.0
        ee_threshold = AUTO_IF_EXACT if (self.threshold == "auto" and self.refine) else self.threshold
        sparse = _sparse_fit(features, targets, free_rows, n_eff, noise_var, ee_threshold, self.ridge)
        coef[free_rows] = sparse.coef
        threshold = sparse.threshold
        if free_rows:
            ee_meta["residual_rms_scaled"] = dict(zip([state_names[i] for i in free_rows], sparse.residual_rms,
                                                      strict=True))
        ee_seconds = time.perf_counter() - started
        units = dict(records.units)
        meta: dict[str, Any] = {
            "estimator": "SINDYc", "settings": self.get_params(), "threshold": sparse.meta,
            "data": {"records": len(runs), "samples": [len(x) for x, _ in runs], "dt": dt,
                     "equations": int(features.shape[0]), "independent_equations": float(n_eff),
                     "dropped_inputs": list(records.constant_inputs),
                     "derived_velocities": dict(self.velocities or {}),
                     "derive_window": {v: w[0] if len(set(w)) == 1 else w for v, w in self._windows.items()}},
            "kinematics": kin, "kinematics_found": [p.to_dict() for p in pairs],
            "equation_error": ee_meta, "seconds": {"equation_error": ee_seconds},
        }
        model = IdentifiedModel(states=tuple(state_names), inputs=tuple(input_names), terms=tuple(library),
                                coef=coef, dt=dt, units=units, meta=meta)
        if known_x0 is not None:
            meta["x0_known"] = [v.tolist() for v in known_x0]
        if self.refine == "output_error":
            coarse, factor = _analysis_runs(runs, dt, model, self.decimate)
            starts = _starts(model, features, targets, free_rows, n_eff, noise_var, ee_threshold, self.ridge,
                             sparse.coef_scale, runs=coarse, dt=dt * factor, kin=kin)
            model = _refine_decimated(starts, runs, coarse, factor, dt, kin, sparse.coef_scale, meta, known_x0,
                                      refine_options=self.refine_options,
                                      refine_initial_state=self.refine_initial_state, prune=self.threshold == "auto",
                                      prefer_stable=not self.allow_unstable if self.prefer_stable is None
                                      else self.prefer_stable)
            if self.threshold == "auto":
                threshold = meta["threshold"]["value"]
        meta["seconds"]["total"] = time.perf_counter() - started
        meta.update(_stability(model, runs, dt))
        model = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=model.coef,
                                dt=dt, units=units, meta=meta)
        self.kinematics_ = pairs
        if meta["stable"] is False:
            _unstable(model, allow=self.allow_unstable, refined=self.refine == "output_error")
        self.model_ = model
        self.coef_ = model.coef
        self.terms_ = model.terms
        self.threshold_ = float(threshold)
        self.states_ = model.states
        self.inputs_ = model.inputs
        return self

    # -- data
    def _velocity(self, position: np.ndarray, t: np.ndarray, name: str) -> np.ndarray:
        """The velocity state `name` derived from a measured position, by ``velocity_method`` (the window used
        is recorded for the model's meta)."""
        value, window = _derive_velocity(position, t, name, self.velocity_method, self.velocity_options,
                                         self.derive_window)
        if window is not None and hasattr(self, "_windows"):
            self._windows.setdefault(name, []).append(window)
        return value

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
        values = _measured(trajectory, model.states, model.inputs, velocities, "the trajectory")
        return _stacked(values, trajectory.time, model.states, model.inputs, velocities, self._velocity)

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

