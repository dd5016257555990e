"""How far each effect closes the gap: cells, shrink, calibration shifts, held-out check.

Definitions (``docs/diagnosis.md``):

- *cells* of an effect: the (channel, band, kind) locations holding most of the whitened power of
  the net change it makes to the residual (its signature minus what the recalibration of G and d
  takes back; at least 20 % of the largest cell, at most 4);
- *gain* G: ``delta chi^2`` (``2 delta log L``) of adding the effect to the final model;
- *shrink* = ``G / max(G + R+, F)``, R+ the excess power that remains at its cells once it is
  modelled (``sum (|Y|^2 / S) - K``, floored at 0), F the candidate gain floor (a gap smaller than
  the detection threshold is not "explained"): 1 when the gap at its locations is gone, smaller
  when part of it remains or when there was no significant gap to explain;
- *held-out shrink*: the magnitude is fitted on the training part and applied, fixed, to the
  held-out part (recalibrated there): ``G_ho / max(G_best + R+, F)`` with G_ho the held-out gain of
  the trained magnitude, G_best that of the held-out part's own fit; ``heldout_z`` tests G_ho
  against "no effect" (G_ho ~ N(-P, 4P), P the held-out power of the trained signature; for the
  star-tracker noise, the mean and std of G_ho with no extra noise, ``Record.noise_gain_null``); with the
  effect present at its trained magnitude G_ho ~ N(P, 4P), so ``heldout_z`` ~ N(sqrt(P), 1):
  ``heldout_expected_z = sqrt(P)`` says how strongly the held-out part could confirm it at all. That
  expectation holds for the trained magnitude taken as exact; its training error e ~ N(0, C_tr) moves
  ``heldout_z`` by ``-e^T M theta / sqrt(P)`` (M the held-out information on the effect's values, the
  others fitted there), so with the effect present ``heldout_z`` ~ N(sqrt(P), s^2),
  ``heldout_z_sd = s = sqrt(1 + theta^T M C_tr M theta / P)``: large where the held-out part is an
  extrapolation of a poorly trained signature (a gravity gradient, a quarter of its 2n period in 3 h).
  "No effect" (the confirmation) stays exact: G_ho ~ N(-P, 4P) whatever the trained magnitude.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.channels import CHANNELS
from taiji2_estimator_pkg.diagnosis.locations import Location, LocationGrid, masked_views
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["Cell", "accepted_report_data", "excess", "held_out_group", "how_far", "signature_cells"]

Cell = tuple[int, np.ndarray, tuple[float, float], str]
"""(channel index, bin mask, band [Hz], kind)."""


def _kind_masks(record: Record, band_edges_hz: Sequence[float], period_s: float, halfwidth: int
                ) -> list[tuple[np.ndarray, tuple[float, float], str]]:
    grid = LocationGrid(record.n, record.model.sample_rate_hz, tuple(band_edges_hz), period_s, halfwidth)
    harmonic = grid.harmonic_mask()[:record.k_max]
    freq = record.frequencies_hz
    out = []
    for lo, hi in itertools.pairwise(band_edges_hz):
        in_band = (freq >= lo) & (freq < hi)
        for kind, mask in (("harmonics", in_band & harmonic), ("continuum", in_band & ~harmonic)):
            if np.any(mask):
                out.append((mask, (float(lo), float(hi)), kind))
    return out


def signature_cells(record: Record, power: np.ndarray, band_edges_hz: Sequence[float], period_s: float,
                    halfwidth: int = 1, channels: Sequence[int] | None = None, max_cells: int = 4,
                    fraction: float = 0.2) -> list[Cell]:
    """Cells holding most of a (K, 15) per-bin whitened signature power.

    Parameters
    ----------
    record : Record
        Record (bins, grid).
    power : numpy.ndarray
        (K, 15) expected excess power per bin (``|signature|^2 / S`` or an extra-noise ratio).
    band_edges_hz : sequence of float
        Bands.
    period_s : float
        Maneuver period (harmonic kind).
    halfwidth : int
        Harmonic half width [bins].
    channels : sequence of int, optional
        Channels considered (default all).
    max_cells, fraction : int, float
        At most ``max_cells`` cells with at least ``fraction`` of the largest.

    Returns
    -------
    list of Cell
    """
    chosen = range(power.shape[1]) if channels is None else channels
    scored = []
    for mask, band, kind in _kind_masks(record, band_edges_hz, period_s, halfwidth):
        for c in chosen:
            scored.append((float(np.sum(power[mask, c])), c, mask, band, kind))
    scored.sort(key=lambda item: -item[0])
    if not scored or scored[0][0] <= 0:
        return []
    top = scored[0][0]
    return [(c, mask, band, kind) for value, c, mask, band, kind in scored[:max_cells] if value >= fraction * top]


def excess(residual: np.ndarray, marginal: np.ndarray, cells: Sequence[Cell]) -> float:
    """Sum over cells of observed minus expected normalised power."""
    total = 0.0
    for c, mask, _, _ in cells:
        total += float(np.sum(np.abs(residual[mask, c]) ** 2 / marginal[mask, c]) - np.count_nonzero(mask))
    return total


def excess_variance(cells: Sequence[Cell]) -> float:
    """Variance of :func:`excess` over the cells where no gap remains: each (bin, channel) term's normalised
    power ``|Y|^2 / S`` is exponential (variance 1), and a bin that n cells share enters n times (n^2)."""
    counts: dict[int, np.ndarray] = {}
    for c, mask, _, _ in cells:
        counts[c] = counts.get(c, 0) + np.asarray(mask, dtype=np.float64)
    return float(sum(np.sum(count ** 2) for count in counts.values()))


REMAINDER_Z = 2.0
"""The excess remaining at an effect's cells counts against its shrink only where it is significant: above this
many of its noise standard deviations (:func:`excess_variance`)."""


def shrink_fraction(gain: float, remaining_excess: float, floor: float, variance: float = 0.0) -> float | None:
    """``G / max(G + R+, F)`` (None when the denominator vanishes): ``R+`` the remaining excess R where it is
    significant (``R > REMAINDER_Z sqrt(variance)``, ``variance`` that of R where no gap remains), 0 otherwise.

    Over a continuum band the remaining excess sums thousands of bins, and its noise alone outweighs a weak
    effect's gain: a readout nonlinearity of GRS2's y readout at delta chi2 32.5 (blind seed 18, set 18) had
    R = 33.9 left over 1,910 bins (noise standard deviation 43.7), read shrink 0.49 and was refused as
    explaining too little of its gap, which then read "unexplained"."""
    remainder = remaining_excess if remaining_excess > REMAINDER_Z * math.sqrt(max(variance, 0.0)) else 0.0
    denominator = max(gain + remainder, floor)
    if not denominator > 0.0:
        return None
    return gain / denominator


def cell_dicts(cells: Sequence[Cell], residual_before: np.ndarray, marginal_before: np.ndarray,
               residual_after: np.ndarray, marginal_after: np.ndarray) -> list[dict[str, Any]]:
    """Gap before and after at each cell, and the fraction of the excess explained."""
    out = []
    for c, mask, band, kind in cells:
        before = float(np.mean(np.abs(residual_before[mask, c]) ** 2 / marginal_before[mask, c]))
        after = float(np.mean(np.abs(residual_after[mask, c]) ** 2 / marginal_after[mask, c]))
        out.append({"channel": CHANNELS[c], "band_hz": list(band), "kind": kind, "bins": int(np.count_nonzero(mask)),
                    "gap_before": before, "gap_after": after,
                    "fraction_explained": (before - after) / (before - 1.0) if before > 1.0 else None})
    return out


def accepted_report_data(record: Record, names: Sequence[str], theta: np.ndarray, residual_before: np.ndarray,
                         residual_after: np.ndarray, gain: float, band_edges_hz: Sequence[float], period_s: float,
                         halfwidth: int, floor: float) -> tuple[float | None, list[dict[str, Any]]]:
    """Shrink and cell table of a deterministic effect with fitted values ``theta``."""
    marginal = record.marginal()
    # the net change of the residual (signature minus what the recalibration of G, d takes back)
    change = residual_before - residual_after
    cells = signature_cells(record, np.abs(change) ** 2 / marginal, band_edges_hz, period_s, halfwidth)
    remaining = excess(residual_after, marginal, cells)
    shrink = shrink_fraction(gain, remaining, floor, excess_variance(cells))
    return shrink, cell_dicts(cells, residual_before, marginal, residual_after, marginal)


def noise_report_data(record: Record, kappa: float, residual: np.ndarray, gain: float, base_kappa: float,
                      band_edges_hz: Sequence[float], period_s: float, halfwidth: int, floor: float
                      ) -> tuple[float | None, list[dict[str, Any]]]:
    """Shrink and cell table of the star-tracker noise with amplitude ``kappa`` over ``base_kappa``."""
    before = record.marginal(base_kappa)
    after = record.marginal(base_kappa + kappa)
    ratio = np.zeros_like(before)
    ratio[:, 0:3] = max(kappa, 0.0) * record.st_template / before[:, 0:3]
    cells = signature_cells(record, ratio, band_edges_hz, period_s, halfwidth, channels=(0, 1, 2))
    remaining = excess(residual, after, cells)
    shrink = shrink_fraction(gain, remaining, floor, excess_variance(cells))
    return shrink, cell_dicts(cells, residual, before, residual, after)


def held_out_deterministic(train: Record, test: Record, candidate: Candidate, others: Sequence[str],
                           band_edges_hz: Sequence[float], period_s: float, halfwidth: int, floor: float
                           ) -> dict[str, Any]:
    """Fit on ``train``, apply to ``test`` (free nuisance and other effects refitted there)."""
    names = candidate.column_names()
    theta_tr, cov_tr, _ = train.refine(candidate, others)
    theta_e = theta_tr[-len(names):]
    magnitude, sigma = candidate.magnitude(theta_e, cov_tr[-len(names):, -len(names):])
    test.relinearise(candidate, theta_e)
    _, _, chi2_before = test.fit(others)
    _, chi2_fixed = test.fit_with_fixed(others, names, theta_e)
    theta_best, _, chi2_best = test.fit(list(others) + names)
    gain_fixed = chi2_before - chi2_fixed
    gain_best = chi2_before - chi2_best
    marginal = test.marginal()
    theta_o, _, _ = test.fit(others)
    beta, _ = test.fit_with_fixed(others, names, theta_e)
    change = test.residual_fft(others, theta_o) - test.residual_fft(list(others) + names,
                                                                   np.concatenate((beta, theta_e)))
    cells = signature_cells(test, np.abs(change) ** 2 / marginal, band_edges_hz, period_s, halfwidth)
    remaining = excess(test.residual_fft(list(others) + names, theta_best), marginal, cells)
    # M: the held-out part's information on the effect's values, the others fitted there; P = theta_e^T M theta_e
    information = test.projected_gram(others, names)
    power = float(theta_e @ information @ theta_e)
    # the trained error e ~ N(0, C_tr) moves z by -e^T M theta_e / sqrt(P): Var = theta_e^T M C_tr M theta_e / P
    leverage = information @ theta_e
    training_variance = float(leverage @ cov_tr[-len(names):, -len(names):] @ leverage) / power if power > 0 else 0.0
    denominator = max(gain_best + max(remaining, 0.0), floor)
    return {
        "magnitude_train": magnitude, "sigma_train": sigma,
        "heldout_delta_chi2": gain_fixed, "heldout_delta_chi2_best": gain_best,
        "shrink_heldout": gain_fixed / denominator if denominator > 0 else None,
        "heldout_z": (gain_fixed + power) / (2.0 * math.sqrt(power)) if power > 0 else None,
        "heldout_expected_z": math.sqrt(power) if power > 0 else None,
        "heldout_z_sd": math.sqrt(1.0 + training_variance) if power > 0 else None,
    }


def held_out_group(train: Record, test: Record, names: Sequence[str], others: Sequence[str]) -> dict[str, float]:
    """The held-out check of several effects at once (a family stack, :mod:`.standing` rule 3): their
    magnitudes fitted together on ``train`` and applied, fixed, to ``test`` (``others`` refitted there);
    ``heldout_z``, ``heldout_expected_z`` and ``heldout_z_sd`` as for one effect (the module's definitions,
    ``theta`` the stack's vector), and ``heldout_delta_chi2``."""
    k = len(names)
    theta_tr, cov_tr, _ = train.fit(list(others) + list(names))
    theta_e, cov_e = theta_tr[-k:], cov_tr[-k:, -k:]
    _, _, chi2_before = test.fit(others)
    _, chi2_fixed = test.fit_with_fixed(others, names, theta_e)
    gain_fixed = chi2_before - chi2_fixed
    information = test.projected_gram(others, names)
    power = float(theta_e @ information @ theta_e)
    if not power > 0:
        return {}
    leverage = information @ theta_e
    return {"heldout_z": (gain_fixed + power) / (2.0 * math.sqrt(power)), "heldout_expected_z": math.sqrt(power),
            "heldout_z_sd": math.sqrt(1.0 + float(leverage @ cov_e @ leverage) / power),
            "heldout_delta_chi2": gain_fixed}


def held_out_noise(train: Record, test: Record, others: Sequence[str], band_edges_hz: Sequence[float],
                   period_s: float, halfwidth: int, floor: float) -> dict[str, Any]:
    """The star-tracker noise fitted on ``train`` and applied to ``test`` (both whitened without it)."""
    theta_tr, _, _ = train.fit(others)
    kappa_tr, _, sigma_tr = train.noise_gain(train.residual_fft(others, theta_tr))
    theta_te, _, _ = test.fit(others)
    residual = test.residual_fft(others, theta_te)
    gain_fixed = test.noise_gain_at(residual, kappa_tr)
    kappa_best, gain_best, _ = test.noise_gain(residual)
    before = test.marginal(0.0)
    ratio = np.zeros_like(before)
    ratio[:, 0:3] = max(kappa_tr, 0.0) * test.st_template / before[:, 0:3]
    cells = signature_cells(test, ratio, band_edges_hz, period_s, halfwidth, channels=(0, 1, 2))
    remaining = excess(residual, test.marginal(kappa_best), cells)
    magnitude, sigma = NoiseCandidate.magnitude(kappa_tr, sigma_tr)
    denominator = max(gain_best + max(remaining, 0.0), floor)
    null_mean, null_sd = test.noise_gain_null(residual, kappa_tr)
    return {"magnitude_train": magnitude, "sigma_train": sigma, "heldout_delta_chi2": gain_fixed,
            "heldout_delta_chi2_best": gain_best,
            "shrink_heldout": gain_fixed / denominator if denominator > 0 else None,
            "heldout_z": (gain_fixed - null_mean) / null_sd if null_sd > 0 else None}


def how_far(record: Record, top: Sequence[Location], accepted: Sequence[Candidate | NoiseCandidate],
            kappas: dict[str, float], grid: LocationGrid, bins_all: np.ndarray, template_all: np.ndarray
            ) -> list[dict[str, Any]]:
    """Gap at the top nominal locations (whole run, all frequencies, same view) after each accepted effect."""
    if not top or not accepted:
        return []
    freq = grid.frequencies_hz
    harmonic = grid.harmonic_mask()
    masks = []
    for loc in top:
        in_band = (freq >= loc.band_hz[0]) & (freq < loc.band_hz[1])
        masks.append((CHANNELS.index(loc.channel), loc.view,
                      in_band & (harmonic if loc.kind == "harmonics" else ~harmonic)))
    rows = [{"channel": loc.channel, "view": loc.view, "band_hz": list(loc.band_hz), "kind": loc.kind,
             "gap_nominal": loc.gap, "significance_nominal": loc.significance, "after": []} for loc in top]
    names = list(record.nuisance)
    kappa = 0.0
    for candidate in accepted:
        if isinstance(candidate, NoiseCandidate):
            kappa = kappas.get(candidate.key, 0.0)
        else:
            names = names + candidate.column_names()
        theta, _, _ = record.fit(names)
        residual = np.fft.rfft(record.residual_time(names, theta), axis=0)[1:bins_all.shape[0] + 1]
        residual /= math.sqrt(record.n)
        views = masked_views(dict(zip(("marginal", "conditional"), record.spectrum.normalised(
            residual, bins_all, kappa * template_all if kappa > 0 else None), strict=True)), record.keep)
        share = 1.0 if record.keep is None else float(np.mean(record.keep))  # as the scan (.locations)
        for row, (c, view, mask) in zip(rows, masks, strict=True):
            gap = float(np.mean(np.abs(views[view][mask, c]) ** 2)) / share
            before = row["gap_nominal"]
            row["after"].append({"effect": candidate.key, "gap": gap,
                                 "fraction_explained": (before - gap) / (before - 1.0) if before > 1.0 else None})
    return rows
