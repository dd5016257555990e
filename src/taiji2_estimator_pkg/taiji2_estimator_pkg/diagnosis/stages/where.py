"""Stage 2, where: residual channels against their exact nominal noise, per channel, band (maneuver
harmonics and continuum) and time segment (:mod:`..locations`), with the time window of the
significant locations. :func:`scan` is also the final scan's (stage 4)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.locations import (
    Location,
    LocationGrid,
    masked_views,
    scan_locations,
    time_window,
)
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.record import Record
from taiji2_estimator_pkg.diagnosis.spectral import dft
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal

__all__ = ["Scan", "ScanGrid", "Where", "locate", "scan", "scan_grid"]


@dataclass(frozen=True)
class ScanGrid:
    """The location grid of the run and the nominal noise spectra on every DFT bin.

    Attributes
    ----------
    grid : LocationGrid
    cells : dict
        ``(band, kind) -> bin mask`` of the grid's cells.
    bins : ndarray
        Every DFT bin but the mean.
    marginal : ndarray
        Nominal marginal spectrum on those bins.
    template : ndarray
        Star-tracker low-frequency noise template on those bins.
    """

    grid: LocationGrid
    cells: dict[tuple[Any, str], np.ndarray]
    bins: np.ndarray
    marginal: np.ndarray
    template: np.ndarray


@dataclass(frozen=True)
class Scan:
    """One scan of the residual (:func:`scan`): locations (most significant first), number of
    tests, significance threshold and the residual's DFT."""

    locations: list[Location]
    tests: int
    threshold: float
    residual: np.ndarray


@dataclass(frozen=True)
class Where:
    """Stage 2's result: the grid, the nominal model's scan and its readout-response fit."""

    grid: ScanGrid
    before: Scan
    readout_response: dict[str, Any]


def scan_grid(full: Record, options: DiagnosisOptions) -> ScanGrid:
    """The location grid and nominal spectra of the record's run."""
    model = full.model
    grid = LocationGrid(full.n, model.sample_rate_hz, tuple(options.band_edges_hz), model.maneuver_period_s,
                        options.harmonic_halfwidth)
    bins_all = np.arange(1, (full.n - 1) // 2 + 1)
    marginal_all = full.spectrum.marginal(bins_all)
    template_all = full.spectrum.st_template(bins_all, options.st_corner_hz)
    cells_by_band = {(band, kind): mask for band, kind, mask in grid.cells()}
    return ScanGrid(grid, cells_by_band, bins_all, marginal_all, template_all)


def scan(full: Record, grid: ScanGrid, t_s: np.ndarray, names: Sequence[str], theta: np.ndarray, kappa: float,
         options: DiagnosisOptions) -> Scan:
    """Scan the residual of the fit ``(names, theta)`` (noise model plus ``kappa`` x the star-tracker
    template) for significant locations; the first significant ones get their time window. The epochs
    that hold estimates are left out (``full.keep``, :func:`.locations.masked_views`)."""
    residual = dft(full.residual_time(names, theta))
    extra = kappa * grid.template if kappa > 0 else None
    marginal_view, conditional_view = full.spectrum.normalised(residual, grid.bins, extra)
    # the estimated epochs (bridged samples, commands lost at a change) are missing, not data (.locations)
    views = masked_views({"marginal": marginal_view, "conditional": conditional_view}, full.keep)
    locations, count, threshold = scan_locations(views, grid.grid, t_s, options.segments, options.alpha_locations,
                                                 keep=full.keep)
    # where in time: the window of the significant locations (the first ones)
    for i, loc in enumerate(locations[:options.max_locations]):
        if not loc.significant:
            break
        window, resolution = time_window(views[loc.view][:, CHANNELS.index(loc.channel)],
                                         grid.cells[(loc.band_hz, loc.kind)], t_s)
        locations[i] = replace(loc, window_s=window, window_resolution_s=resolution)
    return Scan(locations, count, threshold, residual)


def locate(inp: DiagnosisInput, nominal: Nominal, options: DiagnosisOptions, say: Progress) -> Where:
    """Where the nominal model's residual departs from its noise."""
    full = nominal.full
    grid = scan_grid(full, options)
    say("scanning the residual channels (where)")
    readout_response = full.response(nominal.nuisance, nominal.theta)[1].to_dict()
    before = scan(full, grid, inp.t_s, nominal.nuisance, nominal.theta, 0.0, options)
    return Where(grid, before, readout_response)
