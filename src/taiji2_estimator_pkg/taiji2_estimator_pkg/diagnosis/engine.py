"""The diagnosis: calibrate the nominal model, locate the gap, name the effect, measure the shrink.

Steps (``docs/diagnosis.md`` explains the choices):

1. *Calibrate* the nominal model on the data: angular scale factors G (linear ones tied by the
   paper's conversion) and c.m. offsets d of both GRS, with the trends and wrap impulses of the
   channels, by Gauss-Newton iterations of the frequency-domain GLS (:mod:`.spectral`).
2. *Where*: residual channels against their exact nominal noise, per channel, band (maneuver
   harmonics and continuum) and time segment (:mod:`.locations`).
3. *Which*: every candidate variant (:mod:`.candidates`) is added to the calibrated model and
   refitted jointly with G, d and the nuisance terms; its likelihood gain is
   ``delta chi^2`` (``2 delta log L`` for the noise candidate), its score ``delta chi^2 - p ln N``
   (BIC). Forward selection accepts the best variant while its score is positive and its gain
   passes a Bonferroni floor over the candidates; the verdict is "unexplained" when, with the
   accepted effects modelled, a fresh scan finds a significant location or a location that was
   significant with the nominal model is still open (stage 2, tested over those locations only).
4. *How far*: the gap at the locations before and after each accepted effect, the fraction of
   the excess power it explains (shrink), and how the calibrated G and d move with it.
5. *Held out*: each effect is fitted on the first part of the run (2/3 by default) and applied,
   fixed, to the rest, recalibrated there: the shrink on the held-out part.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.stats import chi2 as chi2_dist

from taiji2_sim_pkg.core.config import SimConfig

from .candidates import TIMING_FAMILIES, Candidate, NoiseCandidate, candidate_catalog
from .channels import CHANNELS
from .evaluation import (
    accepted_report_data,
    held_out_deterministic,
    held_out_noise,
    how_far,
    noise_report_data,
)
from .extended import corrected_calibration, extend_model, extended_layout, named_extension
from .inputs import DiagnosisInput
from .locations import Location, LocationGrid, scan_locations, time_window
from .model import NominalModel
from .onset import onset_posterior
from .partners import jointly_determined
from .record import Record, RecordSettings, calibrate
from .spectral import dft
from .standing import FAMILY_VARIANTS_MAX, family_group, standing_verdict, subfamily_group

__all__ = ["DiagnosisOptions", "DiagnosisResult", "EffectReport", "diagnose", "variant_sensitivities"]

Progress = Callable[[str], None]


@dataclass(frozen=True)
class DiagnosisOptions:
    """Settings of the diagnosis (defaults are the documented ones).

    Attributes
    ----------
    f_max_hz : float
        Highest frequency used by the fits [Hz] (the location scan uses all bins).
    band_edges_hz : tuple of float
        Band edges of the location scan [Hz].
    harmonic_halfwidth : int
        Bins around each maneuver harmonic that form the "harmonics" kind.
    segments : int
        Equal time segments scanned besides the whole run.
    alpha_locations : float
        Family-wise false-alarm level of the location scan (Bonferroni).
    alpha_recheck : float
        Family-wise level at which a strong gap of the nominal model (whole run, significance at
        least ``recheck_factor`` times the threshold) counts as still open once the accepted effects
        are modelled (Bonferroni over those locations).
    recheck_factor : float
        See ``alpha_recheck``.
    alpha_candidates : float
        Family-wise level of the candidate gain floor (Bonferroni over the variants).
    max_effects : int
        Most physical effects accepted. Timing effects (a timing convention of the data: each
        timing family at most once) do not count: a bag with its own stamp convention and latency
        keeps the full budget for what is physically wrong.
    train_fraction : float
        Part of the run the held-out check fits on (the rest is held out).
    min_duration_s : float or None
        Shortest run diagnosed [s]; default ``max(3 maneuver periods, 600 s)``.
    max_relative_sigma_g : float
        Calibration must determine every scale factor to this relative sigma, else "insufficient
        data".
    calibration_iterations : int
        Gauss-Newton iterations of the calibration.
    orbit_period_s : float
        Orbit period assumed by the gravity-gradient candidate [s] (mission knowledge).
    suspension_hz, damping : float
        Suspension natural frequency [Hz] and damping of the tm_stiffness candidate.
    st_corner_hz : float
        Corner of the star-tracker low-frequency noise candidate [Hz].
    candidates : tuple of str or None
        Effect families considered (default: the whole catalog).
    alias_correlation : float
        Variants whose signatures correlate at least this much (after the nominal model) are
        reported as aliases (indistinguishable with these data).
    max_locations : int
        Locations listed in the report.
    onsets : bool
        Estimate when each accepted effect starts (:mod:`.onset`); model the onset when its GLR
        statistic exceeds ``onset_penalty`` x ln N (BIC of one more parameter).
    onset_penalty : float
        See ``onsets``.
    corrected_calibration : bool
        Re-calibrate G and d under the nominal model extended with the named effects.
    """

    f_max_hz: float = 0.2
    band_edges_hz: tuple[float, ...] = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0, 5.0)
    harmonic_halfwidth: int = 1
    segments: int = 3
    alpha_locations: float = 0.01
    alpha_recheck: float = 0.05
    recheck_factor: float = 2.0
    alpha_candidates: float = 0.01
    max_effects: int = 4
    train_fraction: float = 2.0 / 3.0
    min_duration_s: float | None = None
    max_relative_sigma_g: float = 0.01
    calibration_iterations: int = 4
    orbit_period_s: float = 86164.1
    suspension_hz: float = 0.01
    damping: float = 0.7
    st_corner_hz: float = 1e-5
    candidates: tuple[str, ...] | None = None
    alias_correlation: float = 0.95
    max_locations: int = 25
    onsets: bool = True
    onset_penalty: float = 1.0
    corrected_calibration: bool = True


@dataclass
class EffectReport:
    """One effect family in the report (its best variant, or the accepted one).

    Attributes
    ----------
    name, variant : str
        Family and variant.
    magnitude, sigma : float
        Fitted magnitude and 1-sigma (SI, ``unit``) in the final model.
    unit : str
    score : float
        ``delta chi^2 - p ln N`` (BIC gain) in the final model: drop-one for an accepted effect,
        add-one otherwise.
    delta_chi2 : float
        Likelihood gain (``2 delta log L``).
    n_params : int
    accepted : bool
    shrink : float or None
        Fraction of the excess residual power at the effect's locations it removes (whole run).
    shrink_heldout : float or None
        The same on the held-out part, with the magnitude fitted on the training part.
    heldout_delta_chi2, heldout_delta_chi2_best : float or None
        Chi-square gain on the held-out part with the trained magnitude, and with its own best fit.
    heldout_z : float or None
        Held-out gain against "no effect", in sigma (deterministic effects).
    magnitude_train, sigma_train : float or None
        Fit on the training part.
    parameters : dict
        Every parameter (value, sigma).
    aliases : list of str
        Variants with (nearly) the same signature.
    partners : list of str
        Other accepted effects fitted jointly with this one whose magnitudes the data determine
        only together (:mod:`.partners`): its gain, shrink and held-out check are those of the group.
    g_shift, d_shift : dict or None
        Change of the calibrated G (relative) and d [m] once the effect is modelled, with sigmas.
    cells : list of dict
        Locations (channel, band) where its signature lies, with the gap before and after.
    injection : dict
        Catalog effect that reproduces the fitted variant.
    rejected : str or None
        Why a selected effect is not named (:mod:`.standing`).
    """

    name: str
    variant: str
    magnitude: float
    sigma: float
    unit: str
    score: float
    delta_chi2: float
    n_params: int
    accepted: bool
    shrink: float | None = None
    shrink_heldout: float | None = None
    heldout_delta_chi2: float | None = None
    heldout_delta_chi2_best: float | None = None
    heldout_z: float | None = None
    magnitude_train: float | None = None
    sigma_train: float | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    aliases: list[str] = field(default_factory=list)
    partners: list[str] = field(default_factory=list)
    g_shift: dict[str, Any] | None = None
    d_shift: dict[str, Any] | None = None
    cells: list[dict[str, Any]] = field(default_factory=list)
    injection: dict[str, Any] = field(default_factory=dict)
    rejected: str | None = None

    @property
    def key(self) -> str:
        """``name[variant]``."""
        return f"{self.name}[{self.variant}]" if self.variant else self.name

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "name": self.name, "variant": self.variant, "magnitude": _num(self.magnitude),
            "sigma": _num(self.sigma), "unit": self.unit, "score": _num(self.score),
            "delta_chi2": _num(self.delta_chi2), "n_params": self.n_params, "accepted": self.accepted,
            "shrink": _num(self.shrink), "shrink_heldout": _num(self.shrink_heldout),
            "heldout_delta_chi2": _num(self.heldout_delta_chi2),
            "heldout_delta_chi2_best": _num(self.heldout_delta_chi2_best), "heldout_z": _num(self.heldout_z),
            "magnitude_train": _num(self.magnitude_train), "sigma_train": _num(self.sigma_train),
            "parameters": self.parameters, "aliases": self.aliases, "partners": self.partners, "g_shift": self.g_shift,
            "d_shift": self.d_shift, "cells": self.cells, "injection": self.injection,
            "rejected": self.rejected, "timing": self.name in TIMING_FAMILIES,
        }


def _num(value: float | None) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


@dataclass
class DiagnosisResult:
    """Everything the diagnosis found (``report.json`` is :meth:`to_json_dict`).

    Attributes
    ----------
    status : str
        ``"ok"`` or ``"insufficient data"``.
    reason : str
        Why the data were insufficient (empty otherwise).
    verdict : dict
        ``{"effects": accepted names, "unexplained": bool, "summary": str, ...}``.
    locations : list of Location
        Nominal-model locations, most significant first.
    locations_after : list of Location
        Locations with the accepted effects modelled.
    effects : list of EffectReport
        One per family, accepted first, then by score.
    steps : list of dict
        Forward-selection trace.
    calibration : dict
        Calibrated G and d (nominal model and final model) with sigmas.
    how_far : list of dict
        Gap at the top nominal locations before and after each accepted effect.
    inputs : dict
        Samples used, duration, rejections.
    plots : dict
        Arrays for the plots (PSD overlays, gap map).
    timing_s : dict
        Wall-clock time per stage.
    corrected : dict
        G and d re-calibrated under the nominal model extended with the named effects
        (:func:`.extended.corrected_calibration`), with their covariance and shift from the nominal
        calibration in sigmas; empty when nothing is named.
    extended_layout : dict or None
        The nominal layout extended with the named effects (``--write-config``).
    """

    status: str
    reason: str = ""
    verdict: dict[str, Any] = field(default_factory=dict)
    locations: list[Location] = field(default_factory=list)
    locations_after: list[Location] = field(default_factory=list)
    location_tests: int = 0
    location_threshold: float = 0.0
    effects: list[EffectReport] = field(default_factory=list)
    steps: list[dict[str, Any]] = field(default_factory=list)
    calibration: dict[str, Any] = field(default_factory=dict)
    how_far: list[dict[str, Any]] = field(default_factory=list)
    inputs: dict[str, Any] = field(default_factory=dict)
    plots: dict[str, Any] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
    model: dict[str, Any] = field(default_factory=dict)
    corrected: dict[str, Any] = field(default_factory=dict)
    extended_layout: dict[str, Any] | None = None

    def to_json_dict(self, max_locations: int = 25) -> dict[str, Any]:
        """The ``report.json`` content (keys ``locations``, ``effects``, ``verdict`` and more)."""
        return {
            "status": self.status,
            "reason": self.reason,
            "verdict": self.verdict,
            "locations": [loc.to_dict() for loc in self.locations[:max_locations]],
            "locations_after": [loc.to_dict() for loc in self.locations_after[:max_locations]],
            "location_tests": self.location_tests,
            "location_threshold": self.location_threshold,
            "effects": [effect.to_dict() for effect in self.effects],
            "steps": self.steps,
            "calibration": self.calibration,
            "corrected_calibration": self.corrected,
            "how_far": self.how_far,
            "inputs": self.inputs,
            "model": self.model,
            "timing_s": self.timing_s,
        }


# ------------------------------------------------------------------------------------------------
# the diagnosis
# ------------------------------------------------------------------------------------------------


def _settings(options: DiagnosisOptions) -> RecordSettings:
    return RecordSettings(options.f_max_hz, options.orbit_period_s, options.suspension_hz, options.damping,
                          options.st_corner_hz)


def _insufficient(result: DiagnosisResult, reason: str) -> DiagnosisResult:
    result.status = "insufficient data"
    result.reason = reason
    result.verdict = {"effects": [], "unexplained": False, "summary": "insufficient data", "reason": reason}
    return result


def _gap_map(locations: Sequence[Location], options: DiagnosisOptions) -> np.ndarray:
    """(15, bands) largest significance over kinds and segments."""
    bands = list(zip(options.band_edges_hz[:-1], options.band_edges_hz[1:], strict=True))
    out = np.zeros((len(CHANNELS), len(bands)))
    index = {band: i for i, band in enumerate(bands)}
    for loc in locations:
        i = index.get(tuple(loc.band_hz))
        if i is not None:
            c = CHANNELS.index(loc.channel)
            out[c, i] = max(out[c, i], loc.significance)
    return out


def _band_psd(residual_fft: np.ndarray, marginal: np.ndarray, freq: np.ndarray, edges: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Log-band averages of |Y|^2 and of the model spectrum (plot data, per-bin units)."""
    centres, data, model = [], [], []
    power = np.abs(residual_fft) ** 2
    for lo, hi in itertools.pairwise(edges):
        mask = (freq >= lo) & (freq < hi)
        if not np.any(mask):
            continue
        centres.append(math.sqrt(lo * hi))
        data.append(power[mask].mean(axis=0))
        model.append(marginal[mask].mean(axis=0))
    return np.array(centres), np.array(data), np.array(model)


def _shifts(theta_with: np.ndarray, theta_without: np.ndarray, cov: np.ndarray) -> tuple[dict, dict]:
    """G (relative) and d [m] moves between two fits that start with the nuisance columns."""
    delta = theta_with[:12] - theta_without[:12]
    sigma = np.sqrt(np.maximum(np.diag(cov)[:12], 0.0))
    return ({"relative": delta[:6].reshape(2, 3).tolist(), "sigma_relative": sigma[:6].reshape(2, 3).tolist(),
             "max_abs_in_sigma": float(np.max(np.abs(delta[:6]) / np.maximum(sigma[:6], 1e-300)))},
            {"m": delta[6:12].reshape(2, 3).tolist(), "sigma_m": sigma[6:12].reshape(2, 3).tolist(),
             "max_abs_in_sigma": float(np.max(np.abs(delta[6:12]) / np.maximum(sigma[6:12], 1e-300)))})


class _Aliases:
    """Correlation of the one-parameter signatures after the nominal model.

    Exact-scan (timing) signatures are correlated at first order (a short lag looks like a delay)
    but told apart by their exact shapes: a pair involving one is an alias only if the exact fits
    differ by less than the gain floor.
    """

    def __init__(self, record: Record, candidates: Sequence[Candidate], threshold: float,
                 floor: float = 0.0) -> None:
        self.threshold = threshold
        self.record = record
        self.floor = floor
        self._exact: dict[str, float] = {}
        self.single = [c for c in candidates if c.n_params == 1]
        self.position = {c.key: i for i, c in enumerate(self.single)}
        if not self.single:
            self.correlation = np.zeros((0, 0))
            return
        gram = record.design.gram
        n_idx = record.indices(record.nuisance)
        s_idx = record.indices([c.column_names()[0] for c in self.single])
        g_nn = gram[np.ix_(n_idx, n_idx)]
        g_ns = gram[np.ix_(n_idx, s_idx)]
        scale = np.sqrt(np.maximum(np.diag(g_nn), 1e-300))
        solved = np.linalg.solve(g_nn / np.outer(scale, scale) + 1e-12 * np.eye(scale.size), g_ns / scale[:, None])
        projected = gram[np.ix_(s_idx, s_idx)] - g_ns.T @ (solved / scale[:, None])
        norm = np.sqrt(np.maximum(np.diag(projected), 1e-300))
        self.correlation = projected / np.outer(norm, norm)

    def of(self, candidate: Candidate | NoiseCandidate) -> list[str]:
        """Variants (other than itself) whose signature correlates above the threshold.

        A candidate with a modelled onset is compared with the other variants started at the same onset
        (a torque gain from t0 and an inertia error from t0 are as alike as from the start); the timing
        variants, whose aliasing is decided by their exact scans from the start, are left out there.
        """
        i = self.position.get(candidate.key)
        if i is None:
            return []
        onset = self.record.onsets.get(candidate.key)
        if onset is not None:
            return self._of_at_onset(candidate, onset)
        row = self.correlation[i]
        out = []
        for j in np.flatnonzero(np.abs(row) >= self.threshold):
            other = self.single[j]
            if j == i:
                continue
            if (candidate.grid is not None or other.grid is not None) and \
                    abs(self._exact_chi2(other) - self._exact_chi2(candidate)) >= self.floor:
                continue
            out.append(other.key)
        return out

    def _of_at_onset(self, candidate: Candidate, onset_s: float) -> list[str]:
        record = self.record
        others = [c for c in self.single if c.key != candidate.key and c.grid is None]
        fixed = record.design.conditioned(record.indices(record.nuisance))
        own = record.column_ffts(candidate)
        own_power = float(fixed.projected_gram(record.whitener, own)[0, 0])
        out = []
        for start in range(0, len(others), ALIAS_CHUNK):  # the other variants from the same onset
            chunk = others[start:start + ALIAS_CHUNK]
            ffts = [record.column_ffts(c, onset_s)[0] for c in chunk]
            gram = fixed.projected_gram(record.whitener, [*own, *ffts])
            norm = np.sqrt(np.maximum(np.diag(gram)[1:] * own_power, 1e-300))
            correlation = gram[0, 1:] / norm
            out += [c.key for c, rho in zip(chunk, correlation, strict=True) if abs(rho) >= self.threshold]
        return out

    def _exact_chi2(self, candidate: Candidate) -> float:
        """chi2 of the nominal model plus the candidate, by its exact scan where it has one."""
        if candidate.key not in self._exact:
            if candidate.series is not None:
                self._exact[candidate.key] = self.record.series_fit(candidate, self.record.nuisance)[1]
            else:
                self._exact[candidate.key] = self.record.chi2(self.record.nuisance + candidate.column_names())
        return self._exact[candidate.key]


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
    model = _with_stamp_phases(nominal if isinstance(nominal, NominalModel) else NominalModel.from_config(nominal),
                               inp)
    say = progress or (lambda message: None)
    settings = _settings(options)
    clock = time.perf_counter()
    timing: dict[str, float] = {}

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timing[stage] = round(now - clock, 3)
        clock = now

    result = DiagnosisResult(status="ok", model=model.summary(), inputs={
        "samples": inp.n, "duration_s": inp.duration_s, "rejected": dict(inp.rejected),
        "rejected_total": int(sum(inp.rejected.values())), "t0_s": float(inp.t_s[0]) if inp.n else None,
        "stamp_phase_s": dict(inp.stamp_phase_s), "bridged": dict(inp.bridged)})
    minimum = options.min_duration_s if options.min_duration_s is not None else max(3 * model.maneuver_period_s, 600.0)
    if abs(inp.sample_rate_hz - model.sample_rate_hz) > 1e-9 * model.sample_rate_hz:
        return _insufficient(result, f"sample rate {inp.sample_rate_hz} Hz differs from the model's "
                                     f"{model.sample_rate_hz} Hz")
    if inp.duration_s < minimum:
        return _insufficient(result, f"{inp.duration_s:.0f} s of usable data, at least {minimum:.0f} s needed "
                                     "(three maneuver periods and two held-out parts)")
    if not np.any(inp.torque_cmd_n_m):
        return _insufficient(result, "no maneuver in the data (all commanded torques zero)")

    # 1. calibrate the nominal model ------------------------------------------------------------
    # one Gauss-Newton step on the nuisance columns alone, then the candidate record at that point;
    # its own nuisance fit checks the convergence (and the point moves again if needed)
    say(f"calibrating the nominal model on {inp.n} samples ({inp.duration_s / 3600:.2f} h)")
    t_mid = float(0.5 * (inp.t_s[0] + inp.t_s[-1]))
    model, fixed = extend_model(model, settings)  # a layout's known effects (its effects section)
    g, d, sigma_g, _sigma_d = calibrate(inp, model, settings, 1, say, fixed, t_mid)
    lap("calibration")
    if not np.all(np.isfinite(sigma_g)) or float(np.max(sigma_g)) > options.max_relative_sigma_g:
        return _insufficient(result, f"the data determine the scale factors only to {np.max(sigma_g):.2g} "
                                     f"(relative, 1 sigma); {options.max_relative_sigma_g:g} needed")
    candidates, noise = candidate_catalog(options.candidates, options.orbit_period_s, options.suspension_hz,
                                          options.damping, options.st_corner_hz, model)
    for iteration in range(max(1, options.calibration_iterations)):
        say(f"building the signatures of {len(candidates)} candidate variants")
        full = Record(inp, model, g, d, settings, candidates, t_mid, fixed=fixed)
        theta_check, cov_check, _ = full.fit(full.nuisance)
        sigma_check = np.sqrt(np.maximum(np.diag(cov_check)[:12], 1e-300))
        change = float(np.max(np.abs(theta_check[:12]) / sigma_check))
        say(f"calibration check {iteration + 2}: largest update {change:.3g} sigma")
        if change < 0.05:
            break
        g = g * (1.0 + theta_check[:6].reshape(2, 3))
        d = d + theta_check[6:12].reshape(2, 3)
    lap("signatures")
    nuisance = full.nuisance
    log_n = math.log(full.n_rows)
    n_candidates = len(candidates) + (noise is not None)
    floor = {p: float(chi2_dist.isf(options.alpha_candidates / max(n_candidates, 1), p)) for p in (1, 2)}
    theta_n, cov_n, chi2_n = full.fit(nuisance)
    dof = full.n_rows - len(nuisance)
    sig_n = np.sqrt(np.maximum(np.diag(cov_n), 0.0))
    result.calibration = {
        "g_angular": (g * (1.0 + theta_n[:6].reshape(2, 3))).tolist(),
        "g_angular_sigma_relative": sig_n[:6].reshape(2, 3).tolist(),
        "g_angular_nominal": model.g_angular.tolist(),
        "com_offset_m": (d + theta_n[6:12].reshape(2, 3)).tolist(),
        "com_offset_sigma_m": sig_n[6:12].reshape(2, 3).tolist(),
        "com_offset_nominal_m": model.com_offset_m.tolist(),
        "chi2": chi2_n, "dof": dof, "chi2_z": (chi2_n - dof) / math.sqrt(2.0 * dof),
        "f_max_hz": options.f_max_hz,
    }

    # 2. where --------------------------------------------------------------------------------------
    grid = LocationGrid(full.n, model.sample_rate_hz, tuple(options.band_edges_hz), model.maneuver_period_s,
                        options.harmonic_halfwidth)
    bins_all = np.arange(1, (full.n - 1) // 2 + 1)
    marginal_all = full.spectrum.marginal(bins_all)
    template_all = full.spectrum.st_template(bins_all, options.st_corner_hz)

    cells_by_band = {(band, kind): mask for band, kind, mask in grid.cells()}

    def scan(names: Sequence[str], theta: np.ndarray, kappa: float) -> tuple[list[Location], int, float, np.ndarray]:
        residual = dft(full.residual_time(names, theta))
        extra = kappa * template_all if kappa > 0 else None
        marginal_view, conditional_view = full.spectrum.normalised(residual, bins_all, extra)
        views = {"marginal": marginal_view, "conditional": conditional_view}
        locations, count, threshold = scan_locations(views, grid, inp.t_s, options.segments, options.alpha_locations)
        # where in time: the window of the significant locations (the first ones)
        for i, loc in enumerate(locations[:options.max_locations]):
            if not loc.significant:
                break
            window, resolution = time_window(views[loc.view][:, CHANNELS.index(loc.channel)],
                                             cells_by_band[(loc.band_hz, loc.kind)], inp.t_s)
            locations[i] = replace(loc, window_s=window, window_resolution_s=resolution)
        return locations, count, threshold, residual

    say("scanning the residual channels (where)")
    result.calibration["readout_response"] = full.response(nuisance, theta_n)[1].to_dict()
    before, tests, threshold, residual_before = scan(nuisance, theta_n, 0.0)
    result.locations, result.location_tests, result.location_threshold = before, tests, threshold
    lap("locations")

    # 3. which: forward selection -----------------------------------------------------------------
    say(f"forward selection over {n_candidates} candidates (which)")
    accepted: list[Candidate | NoiseCandidate] = []
    onsets: dict[str, dict[str, Any]] = {}
    noise_fit: dict[str, float] = {}
    current = list(nuisance)
    _, _, chi2_current = full.fit(current)
    steps: list[dict[str, Any]] = []
    def physical_count() -> int:
        return sum(not (isinstance(c, Candidate) and c.is_timing) for c in accepted)

    for step in range(options.max_effects + len(TIMING_FAMILIES)):
        evaluations: list[tuple[float, float, Candidate | NoiseCandidate]] = []
        physical_full = physical_count() >= options.max_effects
        for candidate in candidates:
            if candidate in accepted or (physical_full and not candidate.is_timing):
                continue
            if candidate.series is not None:  # polynomial signature: its exact (series) gain
                _, chi2_new = full.series_fit(candidate, current)
            else:
                chi2_new = full.chi2(current + candidate.column_names())
            gain = chi2_current - chi2_new
            evaluations.append((gain - candidate.n_params * log_n, gain, candidate))
        noise_step = None
        if noise is not None and noise not in accepted and not physical_full:
            theta_cur, _, _ = full.fit(current)
            noise_step = full.noise_gain(full.residual_fft(current, theta_cur))
            evaluations.append((noise_step[1] - log_n, noise_step[1], noise))
        evaluations.sort(key=lambda item: -item[0])
        top = [{"candidate": item[2].key, "delta_chi2": round(item[1], 2), "score": round(item[0], 2)}
               for item in evaluations[:5]]
        passing = [item for item in evaluations if item[0] > 0 and item[1] > floor[item[2].n_params]]
        if not passing:
            steps.append({"step": step + 1, "accepted": None, "top": top})
            break
        score, gain, best = passing[0]
        accepted.append(best)
        steps.append({"step": step + 1, "accepted": best.key, "delta_chi2": round(gain, 2), "score": round(score, 2),
                      "top": top})
        say(f"step {step + 1}: accepted {best.key} (delta chi2 {gain:.1f}, score {score:.1f})")
        if isinstance(best, NoiseCandidate) and noise_step is not None:
            noise_fit = {"kappa": noise_step[0], "gain": noise_step[1], "sigma": noise_step[2]}
            full.rebuild(noise_step[0])
        elif isinstance(best, Candidate):
            full.refine(best, current)  # second-order signatures: relinearise at the fitted magnitude
            if options.onsets:  # does it start mid-run? (profile likelihood over its onset, .onset)
                info = onset_posterior(full, best, current)
                info["modelled"] = bool(info["delta_chi2"] > options.onset_penalty * log_n)
                if info["modelled"]:
                    full.set_onset(best, info["value"])
                    full.refine(best, current)
                    say(f"  {best.key} starts at {info['value']:.0f} +- {info['sigma']:.0f} s "
                        f"({info['kind']}; GLR delta chi2 {info['delta_chi2']:.1f})")
                onsets[best.key] = info
                steps[-1]["onset_s"] = {"value": info["value"], "sigma": info["sigma"], "modelled": info["modelled"]}
            current = current + best.column_names()
        _, _, chi2_current = full.fit(current)
    result.steps = steps
    lap("selection")

    # final model and the remaining gap ---------------------------------------------------------
    for candidate in accepted:  # the final magnitudes of second-order signatures, with every effect in
        if isinstance(candidate, Candidate) and candidate.series is not None:
            names = candidate.column_names()
            full.refine(candidate, [name for name in current if name not in names])
    _joint_timing(full, [c for c in accepted if isinstance(c, Candidate)], current)
    theta_final, cov_final, chi2_final = full.fit(current)
    say("scanning the residual with the accepted effects")
    result.calibration["readout_response_final"] = full.response(current, theta_final)[1].to_dict()
    after, _, _, residual_after = scan(current, theta_final, full.kappa)
    result.locations_after = after
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
        summary = f"unexplained gap at {_where(remaining)}" + (
            f"; also found: {', '.join(accepted_names)}" if accepted_names else "")
    else:
        summary = "explained by " + ", ".join(accepted_names)
    result.verdict = {"effects": accepted_names, "unexplained": unexplained, "summary": summary,
                      "accepted_variants": [c.key for c in accepted],
                      "significant_locations_before": len(significant_before),
                      "significant_locations_after": len([loc for loc in after if loc.significant]),
                      "unresolved_locations": len(unresolved), "recheck_threshold": recheck,
                      "remaining": [loc.to_dict() for loc in remaining[:5]],
                      "chi2_nominal": chi2_n, "chi2_final": chi2_final}
    lap("final scan")

    # 4. how far: reports of the accepted effects and of the best variant of every other family ---
    say("how far: gaps, shrink and calibration shifts")
    aliases = _Aliases(full, candidates, options.alias_correlation, floor[1])
    deterministic = [c for c in accepted if isinstance(c, Candidate)]
    partners = jointly_determined([c.column_names() for c in deterministic], [c.key for c in deterministic],
                                  current, cov_final, options.alias_correlation)
    reports = _reports(full, candidates, noise, accepted, noise_fit, current, theta_final, cov_final, chi2_final,
                       log_n, options, model, aliases, floor[1], partners)
    for report in reports:
        info = onsets.get(report.key)
        if info is not None:
            report.parameters["onset_s"] = {key: info[key] for key in (
                "value", "sigma", "mle", "delta_chi2", "interval", "resolution_s", "kind", "modelled")}
    result.how_far = how_far(full, [loc for loc in before if loc.segment == "all"][:8], accepted,
                             {noise.key: noise_fit.get("kappa", 0.0)} if noise is not None else {}, grid,
                             bins_all, template_all)
    lap("how_far")

    # 5. held out -----------------------------------------------------------------------------------
    # an effect that starts mid-run is held out within its own span: train on the first part after the
    # latest modelled onset (and all before it), hold out the rest
    start = max([int(np.searchsorted(inp.t_s, full.onsets[c.key])) for c in accepted if c.key in full.onsets],
                default=0)
    split = start + round(options.train_fraction * (inp.n - start))
    if min(split, inp.n - split) * model.dt_s >= model.maneuver_period_s:
        say(f"held-out check: fit on the first {split * model.dt_s:.0f} s, apply to the last "
            f"{(inp.n - split) * model.dt_s:.0f} s")
        _held_out(inp, split, model, g, d, settings, options, candidates, noise, accepted, noise_fit, reports, t_mid,
                  floor[1], full.onsets, fixed)
    lap("held_out")
    result.effects = reports
    families = _families(full, candidates, accepted, current, chi2_final, log_n)
    if families:
        result.verdict["families"] = families
    _apply_naming_rule(result, reports, remaining)
    summary = result.verdict["summary"]

    # 6. the corrected calibration: the model extended with the named effects, G and d re-calibrated --
    by_key = {c.key: c for c in candidates}
    standing = [f for f in result.verdict.get("families", []) if f["stands"]]
    timing_change, named_fixed, specs = named_extension(reports, by_key, full.onsets, t_mid, model, standing)
    if options.corrected_calibration and (named_fixed or any(timing_change)):
        say("corrected calibration: G and d under the model extended with the named effects")
        result.corrected = corrected_calibration(inp, model, settings, timing_change, [*fixed, *named_fixed],
                                                 result.calibration, t_mid, max(2, options.calibration_iterations),
                                                 say)
        result.corrected["effects"] = specs
        if isinstance(nominal, SimConfig):
            result.extended_layout = extended_layout(nominal.to_dict(), [s for s in specs if "timing" in s],
                                                     [s for s in specs if "timing" not in s])
    lap("corrected")

    # plot data ------------------------------------------------------------------------------------
    freq_all = bins_all * model.sample_rate_hz / full.n
    edges = np.logspace(math.log10(freq_all[0]), math.log10(freq_all[-1] * 1.0001), 41)
    centres, psd_before, psd_model = _band_psd(residual_before, marginal_all, freq_all, edges)
    final_marginal = marginal_all.copy()
    final_marginal[:, 0:3] += full.kappa * template_all
    _, psd_after, psd_model_after = _band_psd(residual_after, final_marginal, freq_all, edges)
    result.plots = {"frequency_hz": centres, "psd_before": psd_before, "psd_after": psd_after,
                    "psd_model": psd_model, "psd_model_after": psd_model_after,
                    "gap_map_before": _gap_map(before, options), "gap_map_after": _gap_map(after, options),
                    "bands": list(zip(options.band_edges_hz[:-1], options.band_edges_hz[1:], strict=True)),
                    "threshold": threshold, "sample_rate_hz": model.sample_rate_hz, "n": full.n,
                    "onsets": [(r.key, r.parameters["onset_s"]["value"], r.parameters["onset_s"]["sigma"])
                               for r in reports if r.accepted and r.parameters.get("onset_s", {}).get("modelled")]}
    timing["total"] = round(sum(timing.values()), 3)
    result.timing_s = timing
    say(f"done in {timing['total']:.1f} s: {summary}")
    return result


def _with_stamp_phases(model: NominalModel, inp: DiagnosisInput) -> NominalModel:
    """The model's timing with the stamp phases the grid alignment removed (docs/interfaces.md).

    GRS stamps moved earlier by p_g name an interval ending p_g later than the model's convention
    says (grs_stamp - p_g), commands moved earlier by p_c act p_c later (latency + p_c): the
    command-to-GRS delay changes by p_c - p_g, the star-tracker offset against the GRS by + p_g.
    """
    phase_grs = inp.stamp_phase_s.get("grs", 0.0)
    phase_command = inp.stamp_phase_s.get("command", 0.0)
    if phase_grs == 0.0 and phase_command == 0.0:
        return model
    return replace(model, delay_s=model.delay_s + phase_command - phase_grs,
                   st_offset_s=model.st_offset_s + phase_grs)


def _where(locations: Sequence[Location] | Sequence[dict[str, Any]]) -> str:
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


def _families(full: Record, candidates: Sequence[Candidate], accepted: Sequence[Candidate | NoiseCandidate],
              current: Sequence[str], chi2_final: float, log_n: float) -> list[dict[str, Any]]:
    """Stacks of variants of one physical family, tested as one candidate (naming rule 3).

    The family (every variant of it: one GRS's cross-coupling, the three axes of a torque gain) is
    one candidate with its whole parameter count p in the BIC penalty. A stack of k accepted
    variants stands as that family when the family is complete (k = p), or when the p - k variants
    it lacks gain more than ``(p - k) ln N`` in the final model; it is then named once, with its
    vector of magnitudes and their covariance (the fit with every variant of the family).
    """
    out = []
    for grouping in (family_group, subfamily_group):  # the whole family, then its parts of one physics
        groups: dict[str, list[Candidate]] = {}
        for candidate in accepted:
            if isinstance(candidate, Candidate) and not candidate.is_timing and candidate.variant:
                groups.setdefault(grouping(candidate.name, candidate.variant), []).append(candidate)
        standing = {f["family"] for f in out if f["stands"]}
        for group, members in groups.items():
            if len(members) <= FAMILY_VARIANTS_MAX or group in {f["family"] for f in out}:
                continue
            if grouping is subfamily_group and family_group(members[0].name, members[0].variant) in standing:
                continue
            out.append(_family_fit(full, candidates, grouping, group, members, current, chi2_final, log_n))
    return out


def _family_fit(full: Record, candidates: Sequence[Candidate], grouping: Callable[[str, str], str], group: str,
                members: Sequence[Candidate], current: Sequence[str], chi2_final: float, log_n: float
                ) -> dict[str, Any]:
    """One family as one candidate: its fit with every variant, and whether it stands (:func:`_families`)."""
    family = [c for c in candidates if grouping(c.name, c.variant) == group]
    missing = [c for c in family if c not in members]
    extra = [name for c in missing for name in c.column_names()]
    names = list(current) + extra
    theta, cov, chi2_family = full.fit(names)
    member_names = [name for c in family for name in c.column_names()]
    index = [names.index(name) for name in member_names]
    without = [name for name in current if name not in member_names]
    gain = full.chi2(without) - chi2_family
    p = len(member_names)
    extra_gain = chi2_final - chi2_family
    stands = not missing or extra_gain > len(extra) * log_n
    return {"family": group, "variants": [c.key for c in family], "accepted_variants": [c.key for c in members],
            "magnitudes": theta[index].tolist(), "covariance": cov[np.ix_(index, index)].tolist(),
            "sigmas": np.sqrt(np.maximum(np.diag(cov)[index], 0.0)).tolist(), "n_params": p,
            "delta_chi2": float(gain), "score": float(gain - p * log_n),
            "delta_chi2_of_the_missing_variants": float(extra_gain), "stands": bool(stands)}


def _apply_naming_rule(result: DiagnosisResult, reports: Sequence[EffectReport], remaining: Sequence[Location]
                       ) -> None:
    """Name only the effects that stand on their own; say first where an unexplained gap sits."""
    verdict = result.verdict
    families = [f["family"] for f in verdict.get("families", []) if f["stands"]]
    named, rejected = standing_verdict(reports, bool(verdict["unexplained"]), families)
    if not rejected:
        return
    names = list(dict.fromkeys(report.name for report in named))
    cells = [cell for report in reports if report.key in rejected for cell in report.cells]
    where = _where(remaining) if remaining else _where(cells)
    summary = f"unexplained gap at {where}"
    summary += f"; also found: {', '.join(names)}" if names else "; no catalog effect explains it"
    verdict.update({"effects": names, "unexplained": True, "summary": summary,
                    "accepted_variants": [report.key for report in named], "rejected": rejected})


def _reports(full: Record, candidates: Sequence[Candidate], noise: NoiseCandidate | None,
             accepted: Sequence[Candidate | NoiseCandidate], noise_fit: dict[str, float], current: list[str],
             theta_final: np.ndarray, cov_final: np.ndarray, chi2_final: float, log_n: float,
             options: DiagnosisOptions, model: NominalModel, aliases: _Aliases, floor: float,
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
        dropped = set(names).union(*(columns_of[key] for key in partners.get(candidate.key, [])))
        others = [name for name in current if name not in dropped]
        theta_o, _, chi2_o = full.fit(others)
        gain = chi2_o - chi2_final
        g_shift, d_shift = _shifts(theta_final, theta_o, cov_final)
        shrink, cells = accepted_report_data(full, names, theta, full.residual_fft(others, theta_o), residual_final,
                                             gain, edges, period, halfwidth, floor)
        reports.append(EffectReport(
            candidate.name, candidate.variant, magnitude, sigma, candidate.unit, gain - candidate.n_params * log_n,
            gain, candidate.n_params, True, shrink,
            parameters={p: {"value": float(v), "sigma": float(math.sqrt(max(cov[i, i], 0.0)))}
                        for i, (p, v) in enumerate(zip(candidate.params, theta, strict=True))},
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
        theta, cov = theta_all[-p:], cov_all[-p:, -p:]
        magnitude, sigma = candidate.magnitude(theta, cov)
        shrink, cells = accepted_report_data(full, names, theta, residual_final,
                                             full.residual_fft(current + names, theta_all), gain, edges, period,
                                             halfwidth, floor)
        g_shift, d_shift = _shifts(theta_all, theta_final, cov_all)
        reports.append(EffectReport(
            candidate.name, candidate.variant, magnitude, sigma, candidate.unit, score, gain, p, False, shrink,
            parameters={q: {"value": float(v), "sigma": float(math.sqrt(max(cov[i, i], 0.0)))}
                        for i, (q, v) in enumerate(zip(candidate.params, theta, strict=True))},
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


ALIAS_CHUNK = 16
"""Variants whose onset signatures are whitened at once in the alias check (memory: 16 design columns)."""

_DELAY_FAMILIES = ("actuation_delay", "grs_time_offset")
_RIDGE_LAGS_S = (0.0, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3)  # starting splits of the group delay [s]


def _joint_timing(full: Record, accepted: Sequence[Candidate], current: Sequence[str]) -> None:
    """Fit an accepted thruster lag and an accepted delay jointly, with their exact joint signature.

    The thrust under a delay and a lag together is not the sum of the thrust under each, and the
    data fix their sum (the group delay) to a fraction of a millisecond but their split only to
    ~20 ms: fitted side by side, each signature exact only at the other's model value, a
    second-order residual stays where the thrust changes (torque channels, 0.3-5 Hz), and
    alternating one-parameter fits crawl along the ridge. So (delay, lag) are fitted together by
    a simplex over the exact channel change ``tau_act(D0 + delay, T0 + lag) - tau_act(D0, T0)``
    (every other column refitted linearly), started from the best of a few splits of the fitted
    group delay. Then the lag's column is its exact secant at the fitted lag and the delay's its
    exact secant conditioned on that lag: the two sum exactly to the joint change at the fitted pair.
    """
    lag = next((c for c in accepted if c.name == "thruster_response"), None)
    delays = [c for c in accepted if c.name in _DELAY_FAMILIES]
    if lag is None or not delays or lag.exact is None:
        return
    delay = max(delays, key=lambda c: abs(full.secant.get(c.key, 0.0)))
    if delay.exact is None or lag.key in full.onsets or delay.key in full.onsets:
        return  # an onset: the joint signature from the start does not apply (each is fitted alone)
    free = [name for name in current if name not in delay.column_names() + lag.column_names()]
    ctx, t0 = full.ctx, full.model.time_constant_s

    def changes(delay_s: float, lag_s: float) -> tuple[np.ndarray, np.ndarray]:
        lag_s = max(lag_s, -t0)
        ctx.timing_base.clear()
        lag_change = lag.exact(ctx, lag_s)
        ctx.timing_base["time_constant_s"] = lag_s
        delay_change = delay.exact(ctx, delay_s)
        ctx.timing_base.clear()
        return delay_change, lag_change

    def chi2(x: np.ndarray) -> float:
        delay_change, lag_change = changes(float(x[0]), float(x[1]))
        return full.chi2_with_column(free, delay_change + lag_change)

    group = full.secant.get(delay.key, 0.0) + full.secant.get(lag.key, 0.0)
    starts = [np.array([group - t, t]) for t in sorted({*_RIDGE_LAGS_S, full.secant.get(lag.key, 0.0)})
              if t + t0 >= 0.0]
    start = min(starts, key=chi2)
    simplex = start + np.array([[0.0, 0.0], [0.01, 0.0], [-0.01, 0.01]])
    best = minimize(chi2, start, method="Nelder-Mead",
                    options={"initial_simplex": simplex, "xatol": 2e-5, "fatol": 1e-3, "maxfev": 120})
    delay_s, lag_s = float(best.x[0]), max(float(best.x[1]), -t0)
    delay_change, lag_change = changes(delay_s, lag_s)
    full.set_exact_secant(lag, lag_s, lag_change)
    full.set_exact_secant(delay, delay_s, delay_change)


def _held_out(inp: DiagnosisInput, split: int, model: NominalModel, g: np.ndarray, d: np.ndarray,
              settings: RecordSettings, options: DiagnosisOptions, candidates: Sequence[Candidate],
              noise: NoiseCandidate | None, accepted: Sequence[Candidate | NoiseCandidate],
              noise_fit: dict[str, float], reports: list[EffectReport], t_mid: float, floor: float,
              onsets: dict[str, float] | None = None, fixed: Sequence[Any] = ()) -> None:
    """Fit every reported effect on the training part and apply it to the held-out part."""
    wanted = {r.key for r in reports}
    chosen = [c for c in candidates if c.key in wanted or c in accepted]
    train = Record(inp.slice(0, split), model, g, d, settings, chosen, t_mid, onsets, fixed)
    test = Record(inp.slice(split, inp.n), model, g, d, settings, chosen, t_mid, onsets, fixed)
    accepted_det = [c for c in accepted if isinstance(c, Candidate)]
    edges, period, halfwidth = options.band_edges_hz, model.maneuver_period_s, options.harmonic_halfwidth
    base = list(train.nuisance) + [name for c in accepted_det for name in c.column_names()]
    by_key = {c.key: c for c in chosen}
    noise_report = next((r for r in reports if noise is not None and r.name == noise.name), None)
    if noise_report is not None:  # both parts whitened without the noise under test
        data = held_out_noise(train, test, base, edges, period, halfwidth, floor)
        for key, value in data.items():
            setattr(noise_report, key, value)
    kappa = noise_fit.get("kappa", 0.0)
    if kappa > 0:
        train.rebuild(kappa)
        test.rebuild(kappa)
    for report in reports:
        candidate = by_key.get(report.key)
        if candidate is None:
            continue
        group = {candidate.key, *report.partners}  # judged with its partners left out (.partners)
        others = list(train.nuisance) + [name for c in accepted_det if c.key not in group
                                         for name in c.column_names()]
        data = held_out_deterministic(train, test, candidate, others, edges, period, halfwidth, floor)
        for key, value in data.items():
            setattr(report, key, value)

def variant_sensitivities(inp: DiagnosisInput, nominal: NominalModel | SimConfig,
                          options: DiagnosisOptions | None = None) -> dict[str, float]:
    """1-sigma of every candidate variant's magnitude on these data, jointly with the nominal model.

    The detection limit of a variant is about ``sqrt(floor)`` sigma (the candidate gain floor,
    3.8 sigma for one parameter with the defaults). Used to set benchmark magnitudes.

    Parameters
    ----------
    inp : DiagnosisInput
        Data (typically clean).
    nominal : NominalModel or SimConfig
        Nominal model.
    options : DiagnosisOptions, optional
        Settings.

    Returns
    -------
    dict of str to float
        Variant key -> sigma of its magnitude (SI); for the star-tracker noise, sigma of f_knee^2.
    """
    options = options or DiagnosisOptions()
    model = nominal if isinstance(nominal, NominalModel) else NominalModel.from_config(nominal)
    settings = _settings(options)
    g, d, _, _ = calibrate(inp, model, settings, max(2, options.calibration_iterations), lambda message: None)
    candidates, noise = candidate_catalog(options.candidates, options.orbit_period_s, options.suspension_hz,
                                          options.damping, options.st_corner_hz, model)
    t_mid = float(0.5 * (inp.t_s[0] + inp.t_s[-1]))
    record = Record(inp, model, g, d, settings, candidates, t_mid)
    out: dict[str, float] = {}
    for candidate in candidates:
        names = candidate.column_names()
        theta, cov, _ = record.fit(record.nuisance + names)
        zero = np.zeros(len(names))
        _, sigma = candidate.magnitude(zero, cov[-len(names):, -len(names):])
        out[candidate.key] = sigma
    if noise is not None:
        theta, _, _ = record.fit(record.nuisance)
        _, _, sigma_kappa = record.noise_gain(record.residual_fft(record.nuisance, theta))
        out[noise.key] = sigma_kappa
    return out
