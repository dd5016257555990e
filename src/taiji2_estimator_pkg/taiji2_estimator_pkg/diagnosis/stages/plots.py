"""Plot data of the report: PSD overlays before and after the accepted effects, the gap maps."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS
from taiji2_estimator_pkg.diagnosis.locations import Location
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions
from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.final_scan import FinalModel
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_estimator_pkg.diagnosis.stages.where import Where

__all__ = ["plot_data"]


def plot_data(nominal: Nominal, where: Where, final: FinalModel, reports: Sequence[EffectReport],
              options: DiagnosisOptions) -> dict[str, Any]:
    """Arrays for the plots (:mod:`..report`): band-averaged PSDs, gap maps, bands, onsets."""
    full, model, grid = nominal.full, nominal.start.model, where.grid
    bins_all, marginal_all, template_all = grid.bins, grid.marginal, grid.template
    before, after, threshold = where.before.locations, final.after.locations, where.before.threshold
    freq_all = bins_all * model.sample_rate_hz / full.n
    edges = np.logspace(math.log10(freq_all[0]), math.log10(freq_all[-1] * 1.0001), 41)
    centres, psd_before, psd_model = _band_psd(where.before.residual, marginal_all, freq_all, edges)
    final_marginal = marginal_all.copy()
    final_marginal[:, 0:3] += full.kappa * template_all
    _, psd_after, psd_model_after = _band_psd(final.after.residual, final_marginal, freq_all, edges)
    return {"frequency_hz": centres, "psd_before": psd_before, "psd_after": psd_after,
            "psd_model": psd_model, "psd_model_after": psd_model_after,
            "gap_map_before": _gap_map(before, options), "gap_map_after": _gap_map(after, options),
            "bands": list(zip(options.band_edges_hz[:-1], options.band_edges_hz[1:], strict=True)),
            "threshold": threshold, "sample_rate_hz": model.sample_rate_hz, "n": full.n,
            "onsets": [(r.key, r.parameters["onset_s"]["value"], r.parameters["onset_s"]["sigma"])
                       for r in reports if r.accepted and r.parameters.get("onset_s", {}).get("modelled")]}


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
