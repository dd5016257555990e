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

The grid is coarse over the whole run (41 points), then refined where the posterior lies: each
interval that holds posterior mass (``MASS_FRACTION``) and is wider than a quarter of the posterior
spread (or than one sample: the signatures change per sample) is split (at most 16 parts, at most 41
new points per pass, the heaviest intervals first), up to ``MAX_REFINEMENTS`` passes. The intervals' masses,
not the spread, select them: a strong onset puts all the mass of a coarse grid on one point,
whose spread the grid cannot yet tell, and a second mode keeps its own intervals. The moments
integrate the likelihood with the log-likelihood linear between grid points (``SUBDIVISION`` sub-steps
per interval): a trapezoid of the weights alone reads a peak narrower than the grid as a spread of
zero. An effect present from the start has its posterior piled against the start: its onset reads ~0
within its spread.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["COARSE_POINTS", "onset_posterior"]

COARSE_POINTS = 41
FINE_POINTS = 41
MAX_REFINEMENTS = 8
SPLIT_PARTS = 16
"""An interval is split into at most this many parts per refinement."""
SUBDIVISION = 16
MASS_FRACTION = 1e-4
"""Grid intervals holding less than this fraction of the posterior are not refined (nor count for the
resolution)."""


def _moments(grid: np.ndarray, log_like: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Posterior mean and spread of ``exp(log_like)`` (flat prior), the log-likelihood taken linear between
    grid points; also the sorted grid and the cumulative posterior at its points."""
    order = np.argsort(grid)
    grid, log_like = grid[order], log_like[order]
    finite = np.isfinite(log_like)
    if not np.any(finite):
        return float(grid[0]), float("inf"), grid, np.linspace(0.0, 1.0, grid.size)
    top = np.max(log_like[finite])
    log_like = np.where(finite, log_like - top, -np.inf)
    weight = np.exp(log_like)
    if grid.size == 1:
        return float(grid[0]), 0.0, grid, np.ones(1)
    # sub-points on every interval, log-likelihood interpolated linearly (-inf stays -inf)
    frac = np.linspace(0.0, 1.0, SUBDIVISION + 1)
    x = grid[:-1, None] + frac[None, :] * np.diff(grid)[:, None]
    lo, hi = log_like[:-1, None], log_like[1:, None]
    with np.errstate(invalid="ignore"):
        ll = np.where(np.isfinite(lo) & np.isfinite(hi), lo + frac[None, :] * (hi - lo), -np.inf)
    w = np.exp(ll)
    step = np.diff(x, axis=1)
    mass = np.sum(0.5 * (w[:, 1:] + w[:, :-1]) * step, axis=1)  # per interval
    norm = float(np.sum(mass))
    if not norm > 0.0:
        return float(grid[np.argmax(weight)]), 0.0, grid, np.linspace(0.0, 1.0, grid.size)
    first = float(np.sum(0.5 * (w[:, 1:] * x[:, 1:] + w[:, :-1] * x[:, :-1]) * step)) / norm
    d2 = (x - first) ** 2
    var = float(np.sum(0.5 * (w[:, 1:] * d2[:, 1:] + w[:, :-1] * d2[:, :-1]) * step)) / norm
    cumulative = np.concatenate(([0.0], np.cumsum(mass) / norm))
    return first, math.sqrt(max(var, 0.0)), grid, cumulative


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
        statistic), ``interval`` (central 68 % of the posterior), ``resolution_s`` (widest grid
        interval holding posterior mass), ``kind``, ``evaluations``.
    """
    t = record.readouts.t_s
    dt = record.model.dt_s
    first = float(t[0])
    last = float(t[-1] - record.model.maneuver_period_s) if last_s is None else float(last_s)
    last = max(last, first + dt)
    grids, chi2s, log_dets = [], [], []

    def evaluate(points: np.ndarray) -> bool:
        """Profile at the new points (on the sample grid); False if every point was seen already."""
        points = np.unique(np.clip(np.round((points - first) / dt) * dt + first, first, last))
        seen = np.concatenate(grids) if grids else np.zeros(0)
        points = points[~np.isin(points, seen)]
        if not points.size:
            return False
        chi2, log_det = record.onset_profile(candidate, others, points)
        grids.append(points)
        chi2s.append(chi2)
        log_dets.append(log_det)
        return True

    def state() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        grid = np.concatenate(grids)
        chi2 = np.concatenate(chi2s)
        log_like = -0.5 * chi2 + 0.5 * np.concatenate(log_dets)
        return grid, chi2, log_like

    evaluate(np.linspace(first, last, COARSE_POINTS))
    for _ in range(MAX_REFINEMENTS):
        grid, _, log_like = state()
        _, sigma, sorted_grid, cumulative = _moments(grid, log_like)
        target = max(dt, 0.25 * sigma)
        width = np.diff(sorted_grid)
        mass = np.diff(cumulative)
        # the intervals holding posterior mass, wider than the target; the heaviest first
        coarse = np.flatnonzero((mass > MASS_FRACTION) & (width > target))
        if not coarse.size:
            break
        coarse = coarse[np.argsort(-mass[coarse], kind="stable")]
        parts = np.minimum(np.ceil(width[coarse] / target), SPLIT_PARTS).astype(int)
        keep = np.cumsum(parts - 1) <= FINE_POINTS
        keep[0] = True
        points = [sorted_grid[i] + width[i] * np.arange(1, m) / m
                  for i, m in zip(coarse[keep], parts[keep], strict=True)]
        if not evaluate(np.concatenate(points)):
            break
    grid, chi2, log_like = state()
    mean, sigma, sorted_grid, cumulative = _moments(grid, log_like)
    holding = np.diff(cumulative) > MASS_FRACTION
    resolution = float(np.max(np.diff(sorted_grid)[holding])) if np.any(holding) else dt
    interval = [float(np.interp(q, cumulative, sorted_grid)) for q in (0.1587, 0.8413)]
    at_start = chi2[np.argmin(np.abs(grid - first))]
    best = int(np.argmin(chi2))
    return {"value": mean, "sigma": max(sigma, dt / math.sqrt(12.0)), "mle": float(grid[best]),
            "delta_chi2": float(at_start - chi2[best]), "interval": interval,
            "resolution_s": float(max(resolution, dt)), "kind": candidate.onset_kind, "evaluations": int(grid.size),
            "first_s": first, "last_s": last}
