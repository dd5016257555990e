"""What the diagnosis reports: :class:`EffectReport` (one effect family) and :class:`DiagnosisResult`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from taiji2_estimator_pkg.diagnosis.candidates import TIMING_FAMILIES
from taiji2_estimator_pkg.diagnosis.locations import Location

__all__ = ["DiagnosisResult", "EffectReport", "insufficient"]


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
    heldout_expected_z : float or None
        ``heldout_z`` expected with the effect present at its trained magnitude (sqrt of its held-out power):
        below ``HELDOUT_Z_MIN + 2`` the held-out part cannot confirm it (:mod:`.standing`).
    heldout_z_sd : float or None
        Standard deviation of ``heldout_z`` with the effect present, the training error of its magnitude
        included (1 where that error is negligible; :mod:`.evaluation`).
    magnitude_train, sigma_train : float or None
        Fit on the training part.
    family_heldout : dict
        Family stack (naming rule 3, :mod:`.standing`) -> its held-out check as one (``heldout_z``,
        ``heldout_expected_z``, ``heldout_z_sd``, ``heldout_delta_chi2``) and its in-sample ``delta_chi2`` and
        ``n_params``: a member of a standing family is judged by these.
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
    heldout_expected_z: float | None = None
    heldout_z_sd: float | None = None
    magnitude_train: float | None = None
    sigma_train: float | None = None
    family_heldout: dict[str, dict[str, float]] = field(default_factory=dict)
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
            "heldout_expected_z": _num(self.heldout_expected_z), "heldout_z_sd": _num(self.heldout_z_sd),
            "magnitude_train": _num(self.magnitude_train), "sigma_train": _num(self.sigma_train),
            "family_heldout": {group: {key: _num(value) for key, value in data.items()}
                               for group, data in self.family_heldout.items()},
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
        calibration in sigmas; empty when nothing is named or when it is withheld.
    corrected_withheld : str
        Why the corrected calibration is withheld although effects are named (not converged, or an effect
        beyond the range of its model: :func:`.stages.corrected.untrusted`); empty otherwise.
    extended_layout : dict or None
        The nominal layout extended with the named effects (``--write-config``).
    impulses : dict
        Impulsive events found in the final residual (:mod:`.impulses`): their times, angular momenta and
        linear impulses with sigmas, the detection threshold (matched-filter SNR) and the samples searched.
    blind_spots : list of dict
        Per effect family not named, how far one at the detection threshold would move G or d, in sigma
        (:mod:`.blind_spots`), largest first.
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
    corrected_withheld: str = ""
    extended_layout: dict[str, Any] | None = None
    impulses: dict[str, Any] = field(default_factory=dict)
    blind_spots: list[dict[str, Any]] = field(default_factory=list)

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
            "corrected_calibration_withheld": self.corrected_withheld,
            "impulses": self.impulses,
            "blind_spots": self.blind_spots,
            "how_far": self.how_far,
            "inputs": self.inputs,
            "model": self.model,
            "timing_s": self.timing_s,
        }


def insufficient(result: DiagnosisResult, reason: str) -> DiagnosisResult:
    """``result`` marked "insufficient data" (why: ``reason``); never a guess."""
    result.status = "insufficient data"
    result.reason = reason
    result.verdict = {"effects": [], "unexplained": False, "summary": "insufficient data", "reason": reason}
    return result
