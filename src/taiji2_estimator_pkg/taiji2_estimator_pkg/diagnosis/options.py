"""Settings of the diagnosis (:class:`DiagnosisOptions`) and the subset a record needs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from taiji2_estimator_pkg.diagnosis.record import RecordSettings

__all__ = ["DiagnosisOptions", "Progress", "record_settings"]

Progress = Callable[[str], None]
"""Receives one-line progress messages."""


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



def record_settings(options: DiagnosisOptions) -> RecordSettings:
    """The options a :class:`.record.Record` needs."""
    return RecordSettings(options.f_max_hz, options.orbit_period_s, options.suspension_hz, options.damping,
                          options.st_corner_hz)
