"""Stage 3's second look at every step: an effect that starts mid-run.

The selection scores every variant with its signature *from the start*. An effect that starts at 60 %
of the run shares only part of that signature, and drifts (ramps) fit a late step better than the step's
own from-start signature: a thruster torque gain on z from 5,855 s of a 3-h run (issue 39's benchmark)
gained delta chi2 22 from the start, 818 from 5,855 s on, while a c.m. drift gained 120 from the start;
the selection named four drifts and a lag, the held-out check refused them all, and the gap stayed
"unexplained". So at every step the leading physical variants by their gain from the start (:data:`LEADING`:
a late effect still correlates with its from-start signature) are also fitted from each onset of a coarse
grid (:data:`ONSET_FRACTIONS` of the span ``onset_posterior`` searches), the other columns refitted
(:meth:`.record.Record.onset_profile`); timing conventions, constant by nature, are not.

The best (variant, onset) passes when its gain beats the floor Bonferroni-corrected over every variant
and every onset of the grid (the same family-wise level as the floor: at a fixed onset the gain is
chi-square with p degrees of freedom without the effect), its BIC score with the onset as one more
parameter is positive, and the onset itself earns its parameter against the same variant from the start
(``onset_penalty`` ln N, the rule that models an onset in the selection). The selection then takes it
where its score beats the best from-start score; its onset is estimated as for any accepted effect
(:func:`..onset.onset_posterior`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2 as chi2_dist

from taiji2_estimator_pkg.diagnosis.candidates import Candidate
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["LEADING", "ONSET_FRACTIONS", "LateStart", "late_start"]

LEADING = 3
"""Variants, by their gain from :data:`SCREEN_FRACTION` of the run on, fitted from every trial onset."""

SCREEN_FRACTION = 0.5
"""The screen's onset, as a fraction of the onset span (a step from anywhere in the middle half of the run
shares most of its signature with a step from its middle)."""

ONSET_FRACTIONS = (0.1, 0.3, 0.5, 0.7, 0.9)
"""Trial onsets, as fractions of the span from the first sample to one maneuver period before the end (the
gain of a late step is broad in its trial onset: 771 and 818 at 0.5 and 0.6 of the run in the case above)."""


@dataclass(frozen=True)
class LateStart:
    """A variant named from a late onset: its gain there and from the start, and the trial onset [s]."""

    candidate: Candidate
    gain: float
    gain_from_start: float
    onset_s: float
    floor: float


def late_start(full: Record, ranked: Sequence[tuple[float, Candidate]], current: Sequence[str], chi2_current: float,
               n_candidates: int, alpha: float, log_n: float, onset_penalty: float,
               columns: dict[tuple[str, float], list[np.ndarray]]) -> LateStart | None:
    """The best late-starting variant that passes (see the module doc), or None.

    Parameters
    ----------
    full : Record
        The fitting workspace.
    ranked : sequence of (gain, Candidate)
        Deterministic variants not yet accepted with their gain from the start (timing ones are skipped).
    current : sequence of str
        Columns of the model so far (refitted with each trial).
    chi2_current : float
        Its chi2.
    n_candidates : int
        Variants in the catalog (the Bonferroni count, times the onsets).
    alpha : float
        Family-wise level of the floor (``DiagnosisOptions.alpha_candidates``).
    log_n, onset_penalty : float
        BIC penalty per parameter and the onset's own penalty factor.
    columns : dict
        (variant key, onset [s]) -> its column DFTs, kept by the caller across the steps of one selection: a
        variant not accepted keeps its signature, so each is built once (the screen is then a refit per step).

    Returns
    -------
    LateStart or None
    """
    t = full.readouts.t_s
    first, last = float(t[0]), float(t[-1] - full.model.maneuver_period_s)
    if last <= first:
        return None
    onsets = [first + f * (last - first) for f in ONSET_FRACTIONS]
    tests = max(n_candidates, 1) * len(onsets)
    middle = [first + SCREEN_FRACTION * (last - first)]
    physical = [item for item in ranked if not item[1].is_timing]
    fixed = full.design.conditioned(full.indices(current))  # the current model's normal equations, factored once

    def profile(candidate: Candidate, points: Sequence[float]) -> np.ndarray:
        """chi2 of the current model with the variant from each onset."""
        return full.onset_profile(candidate, current, points, fixed=fixed, columns=columns)[0]

    screen = [float(profile(candidate, middle)[0]) for _, candidate in physical]
    leading = [physical[i] for i in np.argsort(screen)[:LEADING]]
    best: LateStart | None = None
    for gain_from_start, candidate in leading:
        chi2 = profile(candidate, onsets)
        i = int(np.argmin(chi2))
        gain = chi2_current - float(chi2[i])
        p = candidate.n_params_from_onset
        floor = float(chi2_dist.isf(alpha / tests, p))  # chi2 with p dof at each fixed onset
        passes = (gain > floor and gain - (p + 1) * log_n > 0.0
                  and gain - gain_from_start > onset_penalty * log_n)
        if passes and (best is None or gain > best.gain):
            best = LateStart(candidate, gain, gain_from_start, onsets[i], floor)
    return best
