"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it shrinks.

Numerical core (numpy, scipy; matplotlib only for the plots of :mod:`.report`), no middleware.
Entry points:

- :func:`diagnose` (raw arrays in a :class:`DiagnosisInput` + the nominal model) ->
  :class:`DiagnosisResult`;
- :func:`prepare_input` / :func:`align_streams`: raw arrays or separately stamped streams ->
  :class:`DiagnosisInput`;
- :func:`write_report`: ``report.md``, ``report.json`` and PNG plots.

See ``docs/diagnosis.md``.
"""

from taiji2_estimator_pkg.diagnosis.candidates import FAMILIES, Candidate, NoiseCandidate, candidate_catalog
from taiji2_estimator_pkg.diagnosis.engine import diagnose
from taiji2_estimator_pkg.diagnosis.inputs import (
    DiagnosisInput,
    InputError,
    align_streams,
    commands_on_grid,
    prepare_input,
)
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions
from taiji2_estimator_pkg.diagnosis.report import write_report
from taiji2_estimator_pkg.diagnosis.results import DiagnosisResult, EffectReport
from taiji2_estimator_pkg.diagnosis.sensitivities import variant_sensitivities

__all__ = [
    "FAMILIES",
    "Candidate",
    "DiagnosisInput",
    "DiagnosisOptions",
    "DiagnosisResult",
    "EffectReport",
    "InputError",
    "NoiseCandidate",
    "NominalModel",
    "align_streams",
    "candidate_catalog",
    "commands_on_grid",
    "diagnose",
    "prepare_input",
    "variant_sensitivities",
    "write_report",
]
