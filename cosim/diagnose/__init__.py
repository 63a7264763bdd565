"""The diagnose room: the residual of a model traced to the physical effect it lacks.

* :mod:`~cosim.diagnose.residuals` - equation, one-step and free-run residuals with whiteness and
  cross-correlation tests (:func:`residuals`);
* :mod:`~cosim.diagnose.effects` - the catalogue of effects (friction, backlash, cogging...) and where each
  attaches to a model's equations;
* :mod:`~cosim.diagnose.screening` - the output-error score test and fit of candidate effects;
* :mod:`~cosim.diagnose.candidates` - :class:`EffectCandidate`, one effect at one place with its evidence and
  physical parameters;
* :mod:`~cosim.diagnose.diagnosis` - :func:`diagnose`: screen, fit, judge, add, repeat (one screening round in
  ``_ranking``, the trial fits in ``_trials``);
* :mod:`~cosim.diagnose.diagnosis_report` - the :class:`DiagnosisReport`;
* :mod:`~cosim.diagnose.ambiguity` - readings the data cannot tell apart (``ambiguous``) and the experiment
  that would, run on an FMU of the plant when one is given;
* :mod:`~cosim.diagnose.user_candidates` - :func:`candidate`: an effect a user brings, an expression of the
  signals with named parameters (``"orifice: -a*sqrt(abs(h1))"``) or a Python callable.

Imports the identify room and below (not export).
"""

from __future__ import annotations

from . import effects_flow  # noqa: F401  (registers sqrt_outflow and hard_stop with the catalogue)
from .candidates import EffectCandidate
from .diagnosis import diagnose
from .diagnosis_report import DiagnosisReport
from .effects import EFFECTS, Attachment, Effect, Roles, register_effect
from .residuals import RESIDUAL_KINDS, ResidualAnalysis, ResidualTests, correlation_tests, residuals
from .screening import Nuisance, OutputErrorScreen, output_error_fit
from .user_candidates import candidate

__all__ = [
    "Attachment", "DiagnosisReport", "EFFECTS", "Effect", "EffectCandidate", "Nuisance", "OutputErrorScreen",
    "RESIDUAL_KINDS", "ResidualAnalysis", "ResidualTests", "Roles", "candidate", "correlation_tests", "diagnose",
    "output_error_fit", "register_effect", "residuals",
]
