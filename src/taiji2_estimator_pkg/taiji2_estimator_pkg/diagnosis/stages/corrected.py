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

__all__ = ["Corrected", "complete_cross_talk", "correct_calibration", "untrusted"]


@dataclass(frozen=True)
class Corrected:
    """Stage 7's result: the corrected calibration (empty when nothing is named or it is switched
    off) and the extended layout (None unless the nominal model is a simulator layout)."""

    calibration: dict[str, Any] = field(default_factory=dict)
    layout: dict[str, Any] | None = None
    withheld: str = ""
    """Why no corrected calibration is given although effects are named (empty: none withheld)."""


#: the corrected calibration is withheld when the Gauss-Newton's last update moves a parameter by more than
#: this many of its sigmas (not converged: the extended model is too far from linear there)
CONVERGED_UPDATE_SIGMA = 0.5

#: Gauss-Newton iterations of the corrected calibration at least (it stops once the updates are below 0.05 sigma)
CORRECTED_ITERATIONS = 8


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
    iterations = max(CORRECTED_ITERATIONS, options.calibration_iterations)
    corrected = corrected_calibration(inp, start.model, start.settings, timing_change, [*start.fixed, *held],
                                      nominal.calibration, start.t_mid, iterations, say, free)
    corrected["effects"] = specs
    extended = None
    if isinstance(layout, SimConfig):
        extended = extended_layout(layout.to_dict(), [s for s in specs if "timing" in s],
                                   [s for s in specs if "timing" not in s])
    withheld = untrusted(corrected, iterations)
    if withheld:
        say(f"corrected calibration withheld: {withheld}")
        return Corrected({}, extended, withheld)
    corrected.update(_alias_alternatives(inp, start, reports, by_key, [*start.fixed, *held], free, timing_change,
                                         nominal.calibration, corrected, iterations, say))
    return Corrected(corrected, extended)


def untrusted(corrected: dict[str, Any], iterations: int) -> str:
    """Why a corrected calibration cannot be given (empty: it can): its Gauss-Newton has not converged, or a
    re-fitted effect left the range where its series form holds. Either way its G and d are those of a
    model that does not describe the data; a large readout nonlinearity named from its onset moved G by
    ~85 of its sigmas from the truth while the nominal one was 4-7 sigma off (bench_corrected_calibration.py)."""
    last = corrected.get("last_update_sigma")
    if last is not None and last > CONVERGED_UPDATE_SIGMA:
        return (f"the re-fit of G and d with the named effects did not converge (last update {last:.3g} sigma after "
                f"{iterations} iterations): the named effects are too large for the extended model's linearisation")
    if corrected.get("beyond_series_bound"):
        return ("re-fitted beyond the range where their model holds: " + ", ".join(corrected["beyond_series_bound"]))
    return ""


#: aliases of one named effect whose corrected calibration is computed (the strongest first)
ALIASES_PER_EFFECT = 2

#: a parameter whose corrected value moves by more than this many of its sigmas between aliases is left
#: uncertain by the alias
ALIAS_UNCERTAIN_SIGMA = 1.0


def _alias_alternatives(inp: DiagnosisInput, start: Any, reports: Sequence[EffectReport],
                        by_key: dict[str, Candidate], held: Sequence[Fixed], free: Sequence[Fixed],
                        timing_change: tuple[float, float, float], nominal: dict[str, Any],
                        corrected: dict[str, Any], iterations: int, say: Progress) -> dict[str, Any]:
    """The corrected calibration with each named physical effect replaced by each of its physical aliases (the
    data cannot tell them apart: a torque gain and an inertia error on one axis), and which G and d the choice
    moves by more than :data:`ALIAS_UNCERTAIN_SIGMA` of their sigma (``alias_uncertain``): there the corrected
    value holds for the named alias only, and the spread says by how much the others differ."""
    alternatives = []
    sigma = np.concatenate((np.ravel(corrected["g_angular_sigma_relative"]), np.ravel(corrected["com_offset_sigma_m"])))
    base_g, base_d = np.asarray(corrected["g_angular"]), np.asarray(corrected["com_offset_m"])
    for report in reports:
        if not report.accepted or report.name in TIMING_FAMILIES:
            continue
        index = next((i for i, entry in enumerate(free) if entry[0].key == report.key), None)
        if index is None:
            continue
        aliases = [key for key in report.aliases if key in by_key and by_key[key].name not in TIMING_FAMILIES
                   and key not in {entry[0].key for entry in free}][:ALIASES_PER_EFFECT]
        for alias in aliases:
            _, _, onset, t_ref = free[index]
            other = by_key[alias]
            swapped = list(free)
            swapped[index] = (other, np.zeros(len(other.params)), onset, t_ref if other.onset_kind == "ramp" else None)
            say(f"corrected calibration with {alias} in place of {report.key} (aliases)")
            result = corrected_calibration(inp, start.model, start.settings, timing_change, held, nominal,
                                           start.t_mid, iterations, say, swapped)
            reason = untrusted(result, iterations)
            if reason:
                say(f"  with {alias}: {reason}; not reported")
                continue
            g, d = np.asarray(result["g_angular"]), np.asarray(result["com_offset_m"])
            shift = np.concatenate(((g / base_g - 1.0).ravel(), (d - base_d).ravel())) / sigma
            alternatives.append({"named": report.key, "alias": alias, "g_angular": result["g_angular"],
                                 "com_offset_m": result["com_offset_m"],
                                 "shift_from_corrected_sigma": shift.tolist()})
    if not alternatives:
        return {}
    names = corrected["covariance_order"]
    spread = np.max(np.abs([a["shift_from_corrected_sigma"] for a in alternatives]), axis=0)
    return {"alias_alternatives": alternatives, "alias_spread_sigma": spread.tolist(),
            "alias_uncertain": [name.split(" ")[0] for name, value in zip(names, spread, strict=True)
                                if value > ALIAS_UNCERTAIN_SIGMA]}


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
