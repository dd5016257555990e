"""Stage 7, corrected: the nominal model extended with the named effects, G and d re-calibrated
under it (:func:`..extended.corrected_calibration`), and that extended layout (``--write-config``).

The named physical effects are re-fitted with G and d (their sigmas marginal over them); named timing
effects with an onset are held.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from taiji2_estimator_pkg.diagnosis.candidates import TIMING_FAMILIES
from taiji2_estimator_pkg.diagnosis.extended import corrected_calibration, extended_layout, named_extension
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_model.config import SimConfig

__all__ = ["Corrected", "correct_calibration"]


@dataclass(frozen=True)
class Corrected:
    """Stage 7's result: the corrected calibration (empty when nothing is named or it is switched
    off) and the extended layout (None unless the nominal model is a simulator layout)."""

    calibration: dict[str, Any] = field(default_factory=dict)
    layout: dict[str, Any] | None = None


def correct_calibration(inp: DiagnosisInput, layout: NominalModel | SimConfig, nominal: Nominal,
                        reports: Sequence[EffectReport], verdict: dict[str, Any], options: DiagnosisOptions,
                        say: Progress) -> Corrected:
    """Re-calibrate G and d under the model extended with the named effects (``layout``: the nominal
    model as given to the diagnosis, for the extended layout)."""
    start = nominal.start
    by_key = {c.key: c for c in nominal.candidates}
    standing = [f for f in verdict.get("families", []) if f["stands"]]
    timing_change, named_fixed, specs = named_extension(reports, by_key, nominal.full.onsets, start.t_mid,
                                                        start.model, standing)
    if not (options.corrected_calibration and (named_fixed or any(timing_change))):
        return Corrected()
    say("corrected calibration: G and d under the model extended with the named effects")
    held = [entry for entry in named_fixed if entry[0].name in TIMING_FAMILIES]
    free = [entry for entry in named_fixed if entry[0].name not in TIMING_FAMILIES]
    corrected = corrected_calibration(inp, start.model, start.settings, timing_change, [*start.fixed, *held],
                                      nominal.calibration, start.t_mid, max(2, options.calibration_iterations), say,
                                      free)
    corrected["effects"] = specs
    extended = None
    if isinstance(layout, SimConfig):
        extended = extended_layout(layout.to_dict(), [s for s in specs if "timing" in s],
                                   [s for s in specs if "timing" not in s])
    return Corrected(corrected, extended)
