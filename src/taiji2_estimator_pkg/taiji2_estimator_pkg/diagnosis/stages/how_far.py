"""Stage 5, how far: the reports of the accepted effects and of the best variant of every other family.

For each accepted effect (final joint fit, drop-one gain: dropped with its partners, :mod:`..partners`)
and the best other variant per family (add-one): magnitude, score, the fraction of the excess power
at its locations it explains (shrink), how the calibrated G and d move with it, its aliases; then
the gap at the top nominal locations before and after each accepted effect (:func:`..evaluation.how_far`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.evaluation import accepted_report_data, how_far, noise_report_data
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.partners import jointly_determined
from taiji2_estimator_pkg.diagnosis.record import Record
from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.aliases import Aliases
from taiji2_estimator_pkg.diagnosis.stages.final_scan import FinalModel
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_estimator_pkg.diagnosis.stages.selection import Selection
from taiji2_estimator_pkg.diagnosis.stages.where import Where

__all__ = ["HowFar", "measure_how_far"]

_ONSET_KEYS = ("value", "sigma", "mle", "delta_chi2", "interval", "resolution_s", "kind", "modelled")


@dataclass(frozen=True)
class HowFar:
    """Stage 5's result.

    Attributes
    ----------
    reports : list of EffectReport
        One per family, accepted first, then by score (before the held-out check and the naming rule).
    how_far : list of dict
        Gap at the top nominal locations before and after each accepted effect.
    """

    reports: list[EffectReport]
    how_far: list[dict[str, Any]]


def measure_how_far(nominal: Nominal, where: Where, selection: Selection, final: FinalModel,
                    options: DiagnosisOptions, say: Progress) -> HowFar:
    """Reports of the accepted effects and of the best variant of every other family; the gap before and after."""
    full, candidates, noise, accepted = nominal.full, nominal.candidates, nominal.noise, selection.accepted
    say("how far: gaps, shrink and calibration shifts")
    aliases = Aliases(full, candidates, options.alias_correlation, nominal.floor[1])
    deterministic = [c for c in accepted if isinstance(c, Candidate)]
    partners = jointly_determined([c.column_names() for c in deterministic], [c.key for c in deterministic],
                                  final.current, final.cov, options.alias_correlation)
    reports = _reports(full, candidates, noise, accepted, selection.noise_fit, final.current, final.theta,
                       final.cov, final.chi2, nominal.log_n, options, nominal.start.model, aliases, nominal.floor[1],
                       partners)
    for report in reports:
        info = selection.onsets.get(report.key)
        if info is not None:
            report.parameters["onset_s"] = {key: info[key] for key in _ONSET_KEYS}
    gaps = how_far(full, [loc for loc in where.before.locations if loc.segment == "all"][:8], accepted,
                   {noise.key: selection.noise_fit.get("kappa", 0.0)} if noise is not None else {}, where.grid.grid,
                   where.grid.bins, where.grid.template)
    return HowFar(reports, gaps)


def _reports(full: Record, candidates: Sequence[Candidate], noise: NoiseCandidate | None,
             accepted: Sequence[Candidate | NoiseCandidate], noise_fit: dict[str, float], current: list[str],
             theta_final: np.ndarray, cov_final: np.ndarray, chi2_final: float, log_n: float,
             options: DiagnosisOptions, model: NominalModel, aliases: Aliases, floor: float,
             partners: dict[str, list[str]]) -> list[EffectReport]:
    """Accepted effects (final joint fit, drop-one gain: dropped with their partners) and the best other
    variant per family (add-one)."""
    columns_of = {c.key: c.column_names() for c in accepted if isinstance(c, Candidate)}
    edges, period, halfwidth = options.band_edges_hz, model.maneuver_period_s, options.harmonic_halfwidth
    position = {name: i for i, name in enumerate(current)}
    reports: list[EffectReport] = []
    residual_final = full.residual_fft(current, theta_final)
    for candidate in accepted:
        if isinstance(candidate, NoiseCandidate):
            kappa, gain, sigma_kappa = noise_fit["kappa"], noise_fit["gain"], noise_fit["sigma"]
            knee, sigma_knee = candidate.magnitude(kappa, sigma_kappa)
            shrink, cells = noise_report_data(full, kappa, residual_final, gain, 0.0, edges, period, halfwidth, floor)
            reports.append(EffectReport(
                candidate.name, "", knee, sigma_knee, candidate.unit, gain - log_n, gain, 1, True, shrink,
                parameters={"knee_hz_squared": {"value": kappa, "sigma": sigma_kappa}}, cells=cells,
                injection=candidate.inject(np.array([kappa]), model)))
            continue
        names = candidate.column_names()
        index = [position[name] for name in names]
        theta, cov = theta_final[index], cov_final[np.ix_(index, index)]
        magnitude, sigma = candidate.magnitude(theta, cov)
        n_params = candidate.n_params_at(full.onsets.get(candidate.key))
        dropped = set(names).union(*(columns_of[key] for key in partners.get(candidate.key, [])))
        others = [name for name in current if name not in dropped]
        theta_o, _, chi2_o = full.fit(others)
        gain = chi2_o - chi2_final
        g_shift, d_shift = _shifts(theta_final, theta_o, cov_final)
        shrink, cells = accepted_report_data(full, names, theta, full.residual_fft(others, theta_o), residual_final,
                                             gain, edges, period, halfwidth, floor)
        reports.append(EffectReport(
            candidate.name, candidate.variant, magnitude, sigma, candidate.unit, gain - n_params * log_n,
            gain, n_params, True, shrink,
            parameters={p: {"value": float(v), "sigma": float(math.sqrt(max(cov[i, i], 0.0)))}
                        for i, (p, v) in enumerate(zip(candidate.params, theta, strict=True))
                        if i < n_params},
            aliases=aliases.of(candidate), partners=partners.get(candidate.key, []), g_shift=g_shift,
            d_shift=d_shift, cells=cells, injection=candidate.inject(theta, model)))
    accepted_families = {c.name for c in accepted}
    best: dict[str, tuple[float, float, Candidate]] = {}
    for candidate in candidates:
        if candidate.name in accepted_families:
            continue
        names = candidate.column_names()
        chi2_new = full.chi2(current + names)
        gain = chi2_final - chi2_new
        score = gain - candidate.n_params * log_n
        if candidate.name not in best or score > best[candidate.name][0]:
            best[candidate.name] = (score, gain, candidate)
    for score, gain, candidate in best.values():
        names = candidate.column_names()
        p = len(names)
        theta_all, cov_all, _ = full.fit(current + names)
        q = candidate.n_params  # from the start: a step-only parameter's column is zero
        theta, cov = theta_all[-p:], cov_all[-p:, -p:]
        magnitude, sigma = candidate.magnitude(theta, cov)
        shrink, cells = accepted_report_data(full, names, theta, residual_final,
                                             full.residual_fft(current + names, theta_all), gain, edges, period,
                                             halfwidth, floor)
        g_shift, d_shift = _shifts(theta_all, theta_final, cov_all)
        reports.append(EffectReport(
            candidate.name, candidate.variant, magnitude, sigma, candidate.unit, score, gain, q, False, shrink,
            parameters={name: {"value": float(v), "sigma": float(math.sqrt(max(cov[i, i], 0.0)))}
                        for i, (name, v) in enumerate(zip(candidate.params[:q], theta, strict=False))},
            aliases=aliases.of(candidate), g_shift=g_shift, d_shift=d_shift, cells=cells,
            injection=candidate.inject(theta, model)))
    if noise is not None and noise.name not in accepted_families:
        kappa, gain, sigma_kappa = full.noise_gain(residual_final)
        knee, sigma_knee = noise.magnitude(kappa, sigma_kappa)
        shrink, cells = noise_report_data(full, max(kappa, sigma_kappa), residual_final, gain, full.kappa, edges,
                                          period, halfwidth, floor)
        reports.append(EffectReport(noise.name, "", knee, sigma_knee, noise.unit, gain - log_n, gain, 1, False,
                                    shrink if kappa > 0 else 0.0,
                                    parameters={"knee_hz_squared": {"value": kappa, "sigma": sigma_kappa}},
                                    cells=cells, injection=noise.inject(np.array([kappa]), model)))
    first = [r for r in reports if r.accepted]
    rest = sorted((r for r in reports if not r.accepted), key=lambda r: -r.score)
    return first + rest


def _shifts(theta_with: np.ndarray, theta_without: np.ndarray, cov: np.ndarray) -> tuple[dict, dict]:
    """G (relative) and d [m] moves between two fits that start with the nuisance columns."""
    delta = theta_with[:12] - theta_without[:12]
    sigma = np.sqrt(np.maximum(np.diag(cov)[:12], 0.0))
    return ({"relative": delta[:6].reshape(2, 3).tolist(), "sigma_relative": sigma[:6].reshape(2, 3).tolist(),
             "max_abs_in_sigma": float(np.max(np.abs(delta[:6]) / np.maximum(sigma[:6], 1e-300)))},
            {"m": delta[6:12].reshape(2, 3).tolist(), "sigma_m": sigma[6:12].reshape(2, 3).tolist(),
             "max_abs_in_sigma": float(np.max(np.abs(delta[6:12]) / np.maximum(sigma[6:12], 1e-300)))})
