"""The diagnosis: calibrate the nominal model, locate the gap, name the effect, measure the shrink.

:func:`diagnose` runs the stages in order (:mod:`.stages`, one module each; ``docs/diagnosis.md``
explains the choices), each a function of typed values (:mod:`.stages` dataclasses) into the
result types of :mod:`.results`:

1. *Nominal calibration* (:mod:`.stages.nominal`): admit the data, calibrate G and d with the
   nuisance terms by Gauss-Newton GLS, build every candidate's signature (:class:`.stages.nominal.Nominal`).
2. *Where* (:mod:`.stages.where`): scan the residual channels against their nominal noise per
   channel, band and time segment (:class:`.stages.where.Where`).
3. *Selection* (:mod:`.stages.selection`): forward selection of candidate variants by BIC score
   over a Bonferroni gain floor, with onsets (:class:`.stages.selection.Selection`).
   Where the selected effects moved G or d far from the record's point (a large effect), the record is
   rebuilt at the selected model's G and d and the selection runs again (:mod:`.stages.relinearize`).
4. *Final scan* (:mod:`.stages.final_scan`): the final joint fit, its residual scanned, the
   verdict explained / unexplained (:class:`.stages.final_scan.FinalModel`).
5. *How far* (:mod:`.stages.how_far`): each effect's report (magnitude, shrink, G and d shifts,
   aliases) and the gap before and after (:class:`.stages.how_far.HowFar`).
6. *Held out* (:mod:`.stages.held_out`): each effect fitted on the first part of the run, applied
   fixed to the rest; then the naming rule (:mod:`.stages.naming`) names what stands.
7. *Corrected* (:mod:`.stages.corrected`): G and d re-calibrated under the model extended with the
   named effects, and that extended layout (:class:`.stages.corrected.Corrected`).

The plot data (:mod:`.stages.plots`) close the result. The candidate record built in stage 1
(``Nominal.full``) is the fitting workspace of stages 3 and 4, which refine its signatures in place.
"""

from __future__ import annotations

import time

from taiji2_estimator_pkg.diagnosis.blind_spots import blind_spots
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.results import DiagnosisResult, EffectReport, insufficient
from taiji2_estimator_pkg.diagnosis.sensitivities import variant_sensitivities
from taiji2_estimator_pkg.diagnosis.stages.corrected import correct_calibration
from taiji2_estimator_pkg.diagnosis.stages.final_scan import final_scan
from taiji2_estimator_pkg.diagnosis.stages.held_out import check_held_out
from taiji2_estimator_pkg.diagnosis.stages.how_far import measure_how_far
from taiji2_estimator_pkg.diagnosis.stages.naming import name_effects
from taiji2_estimator_pkg.diagnosis.stages.nominal import (
    InsufficientData,
    admit,
    calibrate_start,
    fit_nominal,
    input_summary,
    with_stamp_phases,
)
from taiji2_estimator_pkg.diagnosis.stages.plots import plot_data
from taiji2_estimator_pkg.diagnosis.stages.relinearize import relinearize
from taiji2_estimator_pkg.diagnosis.stages.selection import select_effects
from taiji2_estimator_pkg.diagnosis.stages.where import locate
from taiji2_model.config import SimConfig

# the settings, result types and variant_sensitivities stay importable from here (their homes: .options,
# .results, .sensitivities)
__all__ = ["DiagnosisOptions", "DiagnosisResult", "EffectReport", "diagnose", "variant_sensitivities"]


def diagnose(inp: DiagnosisInput, nominal: NominalModel | SimConfig, options: DiagnosisOptions | None = None,
             progress: Progress | None = None) -> DiagnosisResult:
    """Diagnose the gap between raw data and the nominal model.

    Parameters
    ----------
    inp : DiagnosisInput
        Raw data on one grid (:func:`.inputs.prepare_input`, :func:`.inputs.align_streams`).
    nominal : NominalModel or SimConfig
        The nominal model (a simulator layout).
    options : DiagnosisOptions, optional
        Settings.
    progress : callable, optional
        Receives one-line progress messages.

    Returns
    -------
    DiagnosisResult
        ``status == "insufficient data"`` (with ``reason``) when the run is too short or does not
        determine the nominal calibration; never a guess.
    """
    options = options or DiagnosisOptions()
    model = with_stamp_phases(nominal if isinstance(nominal, NominalModel) else NominalModel.from_config(nominal),
                              inp)
    say = progress or _silent
    lap = _Laps()
    result = DiagnosisResult(status="ok", model=model.summary(), inputs=input_summary(inp))
    try:
        admit(inp, model, options)
        start = calibrate_start(inp, model, options, say)
    except InsufficientData as exc:
        return insufficient(result, str(exc))
    lap("calibration")
    calibrated = fit_nominal(inp, start, options, say)
    lap("signatures")
    where = locate(inp, calibrated, options, say)
    lap("locations")
    selection = select_effects(calibrated, options, say)
    lap("selection")
    relinearized = relinearize(inp, calibrated, selection, options, say)
    if relinearized is not None:  # a large effect: selected again on a record built at its model's G and d
        calibrated, relinearized_info = relinearized
        selection = select_effects(calibrated, options, say)
        lap("relinearized selection")
    final = final_scan(inp, calibrated, where, selection, options, say)
    lap("final scan")
    spots = blind_spots(calibrated.full, calibrated.candidates, final.current, calibrated.floor, calibrated.log_n)
    lap("blind spots")
    how_far = measure_how_far(calibrated, where, selection, final, options, say)
    lap("how_far")
    reports = check_held_out(inp, calibrated, selection, how_far.reports, options, say)
    lap("held_out")
    reports, verdict = name_effects(calibrated, selection, final, reports)
    corrected = correct_calibration(inp, nominal, calibrated, reports, verdict, options, say, final.impulses,
                                    selection.steps)
    lap("corrected")

    result.calibration = {**calibrated.calibration, "readout_response": where.readout_response,
                          "readout_response_final": final.readout_response}
    if relinearized is not None:
        result.calibration["relinearized"] = relinearized_info
    result.locations, result.location_tests = where.before.locations, where.before.tests
    result.location_threshold, result.locations_after = where.before.threshold, final.after.locations
    result.steps, result.effects, result.verdict, result.how_far = selection.steps, reports, verdict, how_far.how_far
    result.corrected, result.extended_layout = corrected.calibration, corrected.layout
    result.corrected_withheld = corrected.withheld
    result.impulses = final.impulses.to_dict()
    result.blind_spots = [spot.to_dict() for spot in spots]
    result.plots = plot_data(calibrated, where, final, reports, options)
    result.timing_s = lap.total()
    say(f"done in {result.timing_s['total']:.1f} s: {verdict['summary']}")
    return result


def _silent(message: str) -> None:
    """No progress messages."""


class _Laps:
    """Wall-clock time per stage: ``lap(stage)`` records the time since the previous lap."""

    def __init__(self) -> None:
        self.clock = time.perf_counter()
        self.timing: dict[str, float] = {}

    def __call__(self, stage: str) -> None:
        now = time.perf_counter()
        self.timing[stage] = round(now - self.clock, 3)
        self.clock = now

    def total(self) -> dict[str, float]:
        """The laps and their sum (``total``)."""
        self.timing["total"] = round(sum(self.timing.values()), 3)
        return self.timing
