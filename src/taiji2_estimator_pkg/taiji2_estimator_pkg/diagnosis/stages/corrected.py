"""Stage 7, corrected: the nominal model extended with the named effects, G and d re-calibrated
under it (:func:`..extended.corrected_calibration`), and that extended layout (``--write-config``).

The named physical effects are re-fitted with G and d (their sigmas marginal over them); named timing
effects with an onset are held. Where a gap stays unexplained beside a named cross-coupling, the
re-fit frees the whole cross-talk of that GRS (misalignment about three axes, imbalance of three
pairs; :func:`complete_cross_talk`): the part selection did not name is then still in the data, and
the named terms, fitted without it, absorb it (an imbalance of pair e moves G of its angular readout
by ``eta d / r``, six times eta on the Type-1 layout), which moved G further from the truth than the
nominal calibration.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import TIMING_FAMILIES, Candidate
from taiji2_estimator_pkg.diagnosis.extended import Fixed, corrected_calibration, extended_layout, named_extension
from taiji2_estimator_pkg.diagnosis.impulses import Impulses, impulse_candidate
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_model.config import SimConfig

__all__ = ["Corrected", "complete_cross_talk", "correct_calibration"]


@dataclass(frozen=True)
class Corrected:
    """Stage 7's result: the corrected calibration (empty when nothing is named or it is switched
    off) and the extended layout (None unless the nominal model is a simulator layout)."""

    calibration: dict[str, Any] = field(default_factory=dict)
    layout: dict[str, Any] | None = None


def correct_calibration(inp: DiagnosisInput, layout: NominalModel | SimConfig, nominal: Nominal,
                        reports: Sequence[EffectReport], verdict: dict[str, Any], options: DiagnosisOptions,
                        say: Progress, impulses: Impulses | None = None) -> Corrected:
    """Re-calibrate G and d under the model extended with the named effects (``layout``: the nominal
    model as given to the diagnosis, for the extended layout) and the found impulses (re-fitted with them;
    not written into the extended layout: they belong to this record, not to the instrument)."""
    start = nominal.start
    by_key = {c.key: c for c in nominal.candidates}
    standing = [f for f in verdict.get("families", []) if f["stands"]]
    timing_change, named_fixed, specs = named_extension(reports, by_key, nominal.full.onsets, start.t_mid,
                                                        start.model, standing)
    events = impulses.events if impulses is not None else []
    if not (options.corrected_calibration and (named_fixed or any(timing_change) or events)):
        return Corrected()
    say("corrected calibration: G and d under the model extended with the named effects")
    held = [entry for entry in named_fixed if entry[0].name in TIMING_FAMILIES]
    free = [entry for entry in named_fixed if entry[0].name not in TIMING_FAMILIES]
    if verdict.get("unexplained"):
        free = complete_cross_talk(free, by_key)
    free += [(impulse_candidate(event, start.model),
              np.concatenate((event.angular_momentum_n_m_s, event.linear_impulse_n_s)), None, None)
             for event in events]
    corrected = corrected_calibration(inp, start.model, start.settings, timing_change, [*start.fixed, *held],
                                      nominal.calibration, start.t_mid, max(2, options.calibration_iterations), say,
                                      free)
    corrected["effects"] = specs
    extended = None
    if isinstance(layout, SimConfig):
        extended = extended_layout(layout.to_dict(), [s for s in specs if "timing" in s],
                                   [s for s in specs if "timing" not in s])
    return Corrected(corrected, extended)


def complete_cross_talk(free: Sequence[Fixed], candidates: dict[str, Candidate]) -> list[Fixed]:
    """``free`` with every cross-coupling variant (three misalignments, three imbalances) of each GRS
    that has a named one, the unnamed ones starting at zero (from the onset of that GRS's first named one)."""
    out = list(free)
    present = {entry[0].key for entry in free}
    for entry in free:
        candidate, _, onset, _ = entry
        if candidate.name != "cross_coupling":
            continue
        grs = candidate.variant.split(".")[0]
        for key, other in candidates.items():
            if other.name == "cross_coupling" and other.variant.split(".")[0] == grs and key not in present:
                out.append((other, np.zeros(len(other.params)), onset, None))
                present.add(key)
    return out
