"""Stage 4, final scan: the final model with every accepted effect, its residual scanned, the verdict.

The final magnitudes of second-order signatures are refitted with every effect in, an accepted
thruster lag and delay fitted jointly (:mod:`..joint_timing`); the verdict is "unexplained" when,
with the accepted effects modelled, a fresh scan finds a significant location or a strong location
of the nominal model is still open (tested over those locations only).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.dynamics import ResponseFit
from taiji2_estimator_pkg.diagnosis.family_completion import complete_families
from taiji2_estimator_pkg.diagnosis.impulses import Impulses, detect_impulses, impulse_candidate, search_input
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.joint_timing import (
    LAG_FAMILY,
    apply_joint_timing,
    fit_joint_timing,
    joint_partner,
)
from taiji2_estimator_pkg.diagnosis.locations import Location
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.record import Record
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_estimator_pkg.diagnosis.stages.selection import Selection
from taiji2_estimator_pkg.diagnosis.stages.where import Scan, Where, scan

__all__ = ["FinalModel", "describe_locations", "final_scan"]


@dataclass(frozen=True)
class FinalModel:
    """Stage 4's result.

    Attributes
    ----------
    current : list of str
        The columns of the final joint fit: ``selection.current``, then the found impulses' columns.
    theta, cov, chi2 : ndarray, ndarray, float
        The final joint fit (columns ``current``).
    impulses : Impulses
        Impulsive events found in the final residual (:mod:`..impulses`), fitted in the final model.
    readout_response : dict
        Readout-response fit of the final model.
    after : Scan
        The scan of its residual.
    remaining : list of Location
        Locations still open (significant after, or strong before and not closed), most significant first.
    verdict : dict
        ``effects``, ``unexplained``, ``summary`` and the counts behind them (before the naming rule).
    """

    current: list[str]
    theta: np.ndarray
    cov: np.ndarray
    chi2: float
    impulses: Impulses
    readout_response: dict[str, Any]
    after: Scan
    remaining: list[Location]
    verdict: dict[str, Any]


def final_scan(inp: DiagnosisInput, nominal: Nominal, where: Where, selection: Selection, options: DiagnosisOptions,
               say: Progress) -> FinalModel:
    """Fit the final model (refining its signatures in ``nominal.full``), scan it, state the verdict."""
    full, accepted, current = nominal.full, selection.accepted, selection.current
    lag = next((c for c in accepted if isinstance(c, Candidate) and c.name == LAG_FAMILY), None)
    pair = None if lag is None else joint_partner(lag, accepted, full)
    for candidate in accepted:  # the final magnitudes of second-order signatures, with every effect in
        if isinstance(candidate, Candidate) and candidate.series is not None and candidate not in (pair or ()):
            names = candidate.column_names()
            full.refine(candidate, [name for name in current if name not in names])
    if pair is not None:  # the thruster lag and a delay: their exact joint signature (..joint_timing)
        apply_joint_timing(full, fit_joint_timing(full, *pair, current))
    theta_final, cov_final, chi2_final = full.fit(current)
    current, impulses, response = _impulses(inp, full, current, theta_final, say)
    theta_scan = theta_final
    if impulses.events:  # refitted with the impulses' columns: the chain's response too
        theta_final, cov_final, chi2_final = full.fit(current)
        theta_scan = _with_detected(current, theta_final, impulses, full.model)
        response = full.response(current, theta_scan)[1]
    completed = complete_families(full, nominal.candidates, accepted, current, nominal.log_n)
    scanned = current
    if completed:  # the scan sees each completed family whole (..family_completion)
        scanned = current + [name for keys in completed.values() for key in keys
                             for name in full.candidates[key].column_names()]
        theta_scan = _with_detected(scanned, full.fit(scanned)[0], impulses, full.model)
        say("completed for the scan: " + ", ".join(f"{group} (+{len(keys)})" for group, keys in completed.items()))
    say("scanning the residual with the accepted effects")
    readout_response = response.to_dict()
    after = scan(full, where.grid, inp.t_s, scanned, theta_scan, full.kappa, options)
    remaining, verdict = _verdict(where.before, after, accepted, options)
    verdict.update({"chi2_nominal": nominal.chi2, "chi2_final": chi2_final})
    if completed:
        verdict["completed_families"] = completed
    return FinalModel(current, theta_final, cov_final, chi2_final, impulses, readout_response, after, remaining,
                      verdict)


def _impulses(inp: DiagnosisInput, full: Record, current: Sequence[str], theta: np.ndarray, say: Progress
              ) -> tuple[list[str], Impulses, ResponseFit]:
    """Search the final residual for impulsive events; the columns of the final fit with theirs added, and the
    chain's response fitted with the residual searched."""
    residual, response = full.response(current, theta)
    steps = [onset for key, onset in full.onsets.items()
             if key in full.candidates and full.candidates[key].onset_kind == "step"]
    searched, keep = search_input(residual, inp.torque_cmd_n_m, full.lin.torque_edges, inp.filled, full.model.dt_s,
                                  inp.t_s, steps)
    impulses = detect_impulses(searched, response, full.model, inp.t_s, keep)
    columns = list(current)
    for event in impulses.events:
        columns += full.add_candidate(impulse_candidate(event, full.model))
    if impulses.events:
        say(f"impulses: {len(impulses.events)} above SNR {impulses.threshold_snr:.2f} at "
            + ", ".join(f"{e.time_s:.1f} s" for e in impulses.events[:5]))
    return columns, impulses, response


def _with_detected(current: Sequence[str], theta: np.ndarray, impulses: Impulses, model: NominalModel) -> np.ndarray:
    """``theta`` with each impulse's L and p at its detected (full-band) values. The joint fit uses the bins
    below ``f_max`` only (~4 % of the band at 10 Hz), where one sample's impulse is weakly determined; the
    chain's response and the residual scan read every bin, and a value off by several of the full band's
    sigmas left a spike at its sample that moved the response (b1 on z from -0.003 to -0.52) and read as a
    1-5 Hz gap of the torque channel (a 5-s torque pulse read as five impulses, one at a command change)."""
    out = np.array(theta, dtype=np.float64, copy=True)
    position = {name: i for i, name in enumerate(current)}
    for event in impulses.events:
        names = impulse_candidate(event, model).column_names()
        values = np.concatenate((event.angular_momentum_n_m_s, event.linear_impulse_n_s))
        for name, value in zip(names, values, strict=True):
            out[position[name]] = value
    return out


def _verdict(before_scan: Scan, after_scan: Scan, accepted: Sequence[Candidate | NoiseCandidate],
             options: DiagnosisOptions) -> tuple[list[Location], dict[str, Any]]:
    """Locations still open and the verdict (without the chi-square entries)."""
    before, after, threshold = before_scan.locations, after_scan.locations, before_scan.threshold
    significant_before = [loc for loc in before if loc.significant]
    # stage 2: every strong gap found with the nominal model must be closed by the accepted effects;
    # tested at the Bonferroni level over those locations only (far more sensitive than a new scan).
    # Strong (signal-dominated) gaps only: a location selected near the threshold owes part of its
    # excess to the noise, which stays after any explanation. Not for the channels of an accepted
    # noise effect, whose own fluctuations are what made those locations stand out.
    noise_channels = {"st_x", "st_y", "st_z"} if any(isinstance(c, NoiseCandidate) for c in accepted) else set()
    strong = [loc for loc in significant_before if loc.segment == "all" and loc.channel not in noise_channels
              and loc.significance >= options.recheck_factor * threshold]
    by_key = {(loc.channel, loc.view, loc.band_hz, loc.kind, loc.segment): loc for loc in after}
    recheck = -math.log10(options.alpha_recheck / max(len(strong), 1))
    unresolved = [by_key[key] for key in ((loc.channel, loc.view, loc.band_hz, loc.kind, loc.segment)
                                          for loc in strong)
                  if key in by_key and by_key[key].significance >= recheck]
    remaining = list({id(loc): loc for loc in [*[loc for loc in after if loc.significant], *unresolved]}.values())
    remaining.sort(key=lambda loc: -loc.significance)
    accepted_names = list(dict.fromkeys(c.name for c in accepted))
    unexplained = bool(remaining)
    if not accepted and not significant_before:
        summary = "no significant gap"
    elif unexplained:
        summary = f"unexplained gap at {describe_locations(remaining)}" + (
            f"; also found: {', '.join(accepted_names)}" if accepted_names else "")
    else:
        summary = "explained by " + ", ".join(accepted_names)
    verdict = {"effects": accepted_names, "unexplained": unexplained, "summary": summary,
               "accepted_variants": [c.key for c in accepted],
               "significant_locations_before": len(significant_before),
               "significant_locations_after": len([loc for loc in after if loc.significant]),
               "unresolved_locations": len(unresolved), "recheck_threshold": recheck,
               "remaining": [loc.to_dict() for loc in remaining[:5]]}
    return remaining, verdict


def describe_locations(locations: Sequence[Location] | Sequence[dict[str, Any]]) -> str:
    """The first three locations in words (channel, band, kind, segment, view; when, if localised)."""
    parts = []
    for loc in locations[:3]:
        item = loc if isinstance(loc, dict) else loc.to_dict()
        lo, hi = item["band_hz"]
        window = ""
        if "window_s" in item and "segment_s" in item:
            start, end = item["window_s"]
            run = item["segment_s"][1] - item["segment_s"][0] if item["segment"] == "all" else float("inf")
            if end - start < 0.5 * run:  # a localised gap: say when
                window = f", {start:.0f}-{end:.0f} s +- {item['window_resolution_s']:.2g} s"
        parts.append(f"{item['channel']} {lo:.2g}-{hi:.2g} Hz ({item['kind']}"
                     + (f", {item['segment']}, {item['view']}" if "segment" in item else "") + window + ")")
    return "; ".join(parts)
