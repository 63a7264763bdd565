"""The identify room: from a Trajectory to an :class:`IdentifiedModel`.

* :mod:`~cosim.identify.sindyc` - :class:`SINDYc`, the sparse identification estimator (scikit-learn style);
* :mod:`~cosim.identify.terms` - library terms as expressions (:class:`Term`), compiled right-hand sides;
* :mod:`~cosim.identify.output_error` - refinement of a model by its free-run (output) error;
* :mod:`~cosim.identify.model` - :class:`IdentifiedModel`: equations, simulation, JSON files;
* :mod:`~cosim.identify.kinematics` - :func:`detect_kinematics`: which states are positions and velocities;
* :mod:`~cosim.identify.metrics` - fit figures: R², NRMSE fit, maximum deviation, k-step-ahead error.

The steps of a :class:`SINDYc` fit live in private modules, each named for its job: ``_settings`` (checks of
the settings), ``_records`` (records read into arrays), ``_library`` (library terms, kinematic rows),
``_differentiation`` (pysindy differentiators), ``_equation_error`` (features and targets), ``_sampler`` (the
trapezoid or, for forward-Euler samples, the left rectangle), ``_sparse_regression`` (scale-aware STLSQ,
threshold by BIC), ``_refinement`` (output-error refinement and
backward elimination), ``_stability`` (stability judgement); ``_linear_run`` holds the output-error
refinement's linear free run (a blocked scan).

Imports the data and plant rooms and the foundation.
"""

from __future__ import annotations

from .compare import Comparison, compare
from .kinematics import KinematicPair, detect_kinematics
from .metrics import METRICS, k_step_ahead_error, max_deviation_pct, nrmse_fit_pct, r2
from .model import DIVERGENCE_LIMIT, MODEL_FORMAT, MODEL_VERSION, IdentifiedModel, SimulationResult
from .output_error import OutputErrorFit, refine_output_error, simulate_linear_batch
from .sindyc import DIFFERENTIATION_METHODS, MIN_SAMPLES_PER_TERM, IdentificationWarning, SINDYc
from .terms import FUNCTIONS, Term, compile_rhs, compile_rk4, polynomial_terms

__all__ = [
    "Comparison", "DIFFERENTIATION_METHODS", "DIVERGENCE_LIMIT", "FUNCTIONS", "IdentificationWarning",
    "IdentifiedModel", "KinematicPair", "compare", "detect_kinematics",
    "METRICS", "MIN_SAMPLES_PER_TERM", "MODEL_FORMAT", "MODEL_VERSION", "OutputErrorFit", "SINDYc",
    "SimulationResult", "Term", "compile_rhs", "compile_rk4", "k_step_ahead_error", "max_deviation_pct",
    "nrmse_fit_pct", "polynomial_terms", "r2", "refine_output_error", "simulate_linear_batch",
]
