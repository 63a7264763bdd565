"""The study room: many runs at once, and the reference study.

* :mod:`~cosim.study.sweep` - :func:`run_sweep`: cases in local processes or on a Dask cluster (the back-ends in
  :mod:`~cosim.study._sweep_backends`);
* :mod:`~cosim.study.sweep_result` - :class:`SweepResult`: each case's result or :class:`SweepError`, as tables
  and versioned JSON files;
* :mod:`~cosim.study.robustness` - :func:`robustness`: a validation repeated over perturbed plants;
* :mod:`~cosim.study.paper` - the published study: its initial state, sampling, noise levels, Table 1, and
  the two-mass servo's linear model (:func:`two_mass_matrices`);
* :mod:`~cosim.study.cases` - :func:`study_case`: one cell of the study's Table 1;
* :mod:`~cosim.study.reproduce` - :func:`reproduce_paper`: the whole study, beside its published numbers.

Imports the loop room and below.
"""

from __future__ import annotations

from .cases import STUDY_SETTINGS, study_case
from .paper import (
    INPUTS,
    STATES,
    STUDY_DT,
    STUDY_NOISE_LEVELS,
    STUDY_TABLE1,
    STUDY_X0,
    TWO_MASS_DEFAULTS,
    two_mass_matrices,
)
from .reproduce import EXCITATIONS, PaperReproduction, reproduce_paper
from .robustness import DEFAULT_UNCERTAIN, RobustnessResult, robustness
from .sweep import run_sweep
from .sweep_result import SWEEP_FORMAT, SWEEP_VERSION, CaseFailedError, SweepError, SweepResult

__all__ = [
    "CaseFailedError", "DEFAULT_UNCERTAIN", "EXCITATIONS", "INPUTS", "PaperReproduction", "RobustnessResult",
    "STATES", "STUDY_DT", "STUDY_NOISE_LEVELS", "STUDY_SETTINGS", "STUDY_TABLE1", "STUDY_X0", "SWEEP_FORMAT",
    "SWEEP_VERSION", "SweepError", "SweepResult", "TWO_MASS_DEFAULTS", "reproduce_paper", "robustness", "run_sweep",
    "study_case", "two_mass_matrices",
]
