"""When an effect starts: the profile likelihood over its onset time, and its posterior mean and spread.

An effect may start during the run, as a step (a thruster degrades, a heater switches, a mass
moves) or, for the drifts, as a drift that starts (``ONSET_KINDS`` of :mod:`.candidates`). For a
trial onset tau the effect's signature is rebuilt from tau on (data side, exactly: a step in the
star-tracker attitude is a step in the attitude, not in its second difference) and fitted jointly
with the calibration and the other accepted effects: ``chi2(tau)`` is the profile (generalised
likelihood ratio, Willsky and Jones) over the onset. The onset is reported as the mean and standard
deviation of ``L(tau) ~ exp(-chi2(tau) / 2) |Cov_theta(tau)|^(1/2)`` (the effect's amplitude
integrated out, flat prior on tau over the run): for a step the likelihood is not regular (its
maximum has the heavy, non-Gaussian spread of a change point, ~5x the Delta chi2 = 1 half width),
and the posterior mean and spread are the estimate whose error the spread describes (for a
location-type parameter the Pitman estimator's mean square error is the expected posterior
variance); for a ramp the likelihood is regular and the two agree with the curvature.

The grid is coarse over the whole run (41 points), then refined where the posterior mass lies
(41 points), then once more to a spacing well below the spread (31 points); the resolution is one
sample at best (the signatures change per sample). An effect present from the start has its
posterior piled against the start: its onset reads ~0 within its spread.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .candidates import Candidate
from .record import Record

__all__ = ["COARSE_POINTS", "onset_posterior"]

COARSE_POINTS = 41
FINE_POINTS = 41
FINEST_POINTS = 31


def _moments(grid: np.ndarray, log_like: np.ndarray) -> tuple[float, float, np.ndarray]:
    order = np.argsort(grid)
    grid, log_like = grid[order], log_like[order]
    finite = np.isfinite(log_like)
    weight = np.zeros_like(log_like)
    if np.any(finite):
        weight[finite] = np.exp(log_like[finite] - np.max(log_like[finite]))
    norm = np.trapezoid(weight, grid) if grid.size > 1 else 1.0
    if not norm > 0.0:
        return float(grid[0]), float("inf"), weight
    mean = float(np.trapezoid(weight * grid, grid) / norm)
    var = float(np.trapezoid(weight * (grid - mean) ** 2, grid) / norm)
    return mean, math.sqrt(max(var, 0.0)), weight


def onset_posterior(record: Record, candidate: Candidate, others: Sequence[str], last_s: float | None = None
                    ) -> dict[str, Any]:
    """Onset of a candidate: profile over trial onsets, posterior mean and standard deviation.

    Parameters
    ----------
    record : Record
        The whole run.
    candidate : Candidate
        The variant (its current linearisation).
    others : sequence of str
        Columns refitted with it (nuisance and the other accepted effects).
    last_s : float, optional
        Latest onset considered [s] (default: one maneuver period before the end).

    Returns
    -------
    dict
        ``value``, ``sigma`` (posterior mean and standard deviation [s]), ``mle`` (the profile's
        best onset), ``delta_chi2`` (chi2 from the start minus chi2 at the best onset: the GLR
        statistic), ``interval`` (central 68 % of the posterior), ``resolution_s`` (finest grid
        spacing), ``kind``, ``evaluations``.
    """
    t = record.readouts.t_s
    dt = record.model.dt_s
    first = float(t[0])
    last = float(t[-1] - record.model.maneuver_period_s) if last_s is None else float(last_s)
    last = max(last, first + dt)
    grids, chi2s, log_dets = [], [], []

    def evaluate(points: np.ndarray) -> None:
        points = np.unique(np.clip(np.round((points - first) / dt) * dt + first, first, last))
        seen = np.concatenate(grids) if grids else np.zeros(0)
        points = points[~np.isin(points, seen)]
        if points.size:
            chi2, log_det = record.onset_profile(candidate, others, points)
            grids.append(points)
            chi2s.append(chi2)
            log_dets.append(log_det)

    def state() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        grid = np.concatenate(grids)
        chi2 = np.concatenate(chi2s)
        log_like = -0.5 * chi2 + 0.5 * np.concatenate(log_dets)
        return grid, chi2, log_like

    evaluate(np.linspace(first, last, COARSE_POINTS))
    spacing = (last - first) / (COARSE_POINTS - 1)
    for points in (FINE_POINTS, FINEST_POINTS):
        grid, _, log_like = state()
        mean, sigma, weight = _moments(grid, log_like)
        order = np.argsort(grid)
        mass = grid[order][weight > 1e-6 * np.max(weight)] if np.any(weight > 0) else grid
        lo = max(first, float(mass.min()) - spacing)
        hi = min(last, float(mass.max()) + spacing)
        if math.isfinite(sigma) and sigma > 0:
            lo, hi = max(lo, mean - 8.0 * sigma), min(hi, mean + 8.0 * sigma)
        if hi - lo <= 2.0 * dt or spacing <= dt:
            break
        new_spacing = (hi - lo) / (points - 1)
        if new_spacing >= 0.8 * spacing:
            break
        evaluate(np.linspace(lo, hi, points))
        spacing = max(new_spacing, dt)
    grid, chi2, log_like = state()
    mean, sigma, weight = _moments(grid, log_like)
    order = np.argsort(grid)
    sorted_grid = grid[order]
    cumulative = np.concatenate(([0.0], np.cumsum(0.5 * (weight[1:] + weight[:-1]) * np.diff(sorted_grid))))
    cumulative /= max(cumulative[-1], 1e-300)
    interval = [float(np.interp(q, cumulative, sorted_grid)) for q in (0.1587, 0.8413)]
    at_start = chi2[np.argmin(np.abs(grid - first))]
    best = int(np.argmin(chi2))
    return {"value": mean, "sigma": max(sigma, dt / math.sqrt(12.0)), "mle": float(grid[best]),
            "delta_chi2": float(at_start - chi2[best]), "interval": interval,
            "resolution_s": float(max(spacing, dt)), "kind": candidate.onset_kind, "evaluations": int(grid.size),
            "first_s": first, "last_s": last}
