"""Aliases: variants whose signatures, after the nominal model, are (nearly) the same (stage 5, how far)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["ALIAS_CHUNK", "Aliases"]

ALIAS_CHUNK = 16
"""Variants whose onset signatures are whitened at once in the alias check (memory: 16 design columns)."""


class Aliases:
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
        (a torque gain from t0 and an inertia error from t0 are as alike as from the start). From an
        onset no exact timing scan is run, so a knot timing variant (the delays, the lag) is compared
        with the other timing variants by their first-order columns there: a delay and a lag both shift
        the thrust by -tau d(torque)/dt (a 5.7-ms delay from 5,404 s, named as a 7.2-ms lag from 5,483 s,
        had no alias: blind seed 13, set 21; only the two delay families were compared), and the star
        tracker's part tells the delay families apart.
        A variant with linear columns (every non-timing one, and the star-tracker offset) is not compared
        with the knot timing variants from an onset.
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
        # a knot (exact-scan) timing variant meets the other knot variants here; every variant with linear
        # columns (the star-tracker offset among them) meets all the variants with linear columns
        knots = candidate.grid is not None
        others = [c for c in self.single if c.key != candidate.key and (c.grid is None or knots)]
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
