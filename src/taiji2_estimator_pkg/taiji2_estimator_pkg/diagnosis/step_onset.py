"""A step-onset signature at many trial onsets from one build of it.

A variant's columns from a step onset tau are ``P(x * on_tau)``: the data-side changes x its signature
builds, zero before tau, through :func:`.channels.perturbation_channels` P. P is linear, and its memory
is two samples (the star tracker's second difference, the half-sum of the mean angular acceleration,
the prewhitening of the common channel). So

    P(x * on_tau) = on_tau * P(x) + E_tau,

with E_tau non-zero only on the first two samples from tau, and computed exactly from x on the four
samples around tau. The onset profile (:meth:`.record.Record.onset_profile`) then builds the signature
once, from the start, and each trial onset costs a copy and a DFT of the channels the signature uses
instead of a build (the build was 3/4 of an onset's cost for a GRS cross-coupling: ~40 of ~50 ms at 3 h,
10 Hz).

Only for the variants whose columns are each one ``_perturb`` of :mod:`.candidates` (checked: one
logged change per column), and for a relinearised series signature (the nonlinearity: a weighted sum of
terms that are each one ``_perturb``; its onset scan took 34 of 70 s of a 3-h diagnosis); the timing
candidates (knots, exact) and the ramps are built at each onset.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, CandidateContext
from taiji2_estimator_pkg.diagnosis.channels import WRAP_SAMPLES, perturbation_channels, zero_wrap
from taiji2_estimator_pkg.diagnosis.spectral import dft

__all__ = ["MEMORY_SAMPLES", "StepPieces", "step_pieces"]

MEMORY_SAMPLES = 2
"""Samples of memory of :func:`.channels.perturbation_channels`: an output row reads the changes of its own
sample and of the two before it."""


@dataclass(frozen=True)
class StepPieces:
    """A signature built from the start (``columns``) and the data-side changes behind each column."""

    ctx: CandidateContext
    columns: list[np.ndarray]
    changes: list[dict[str, np.ndarray]]

    def columns_at(self, onset_s: float) -> list[np.ndarray]:
        """(n, 15) columns from a step at ``onset_s`` [s] (data clock): equal to the build at that onset."""
        i, lo, boundary = self._boundary(onset_s)
        out = []
        for column, rows in zip(self.columns, boundary, strict=True):
            moved = column.copy()
            moved[:i] = 0.0
            moved[lo:lo + rows.shape[0]] += rows
            out.append(moved)
        return out

    def ffts_at(self, onset_s: float, k_max: int) -> list[np.ndarray]:
        """(k_max, 15) DFTs (bins 1..k_max, :func:`.spectral.dft`) of :meth:`columns_at`, each channel that is
        zero throughout neither copied nor transformed."""
        i, lo, boundary = self._boundary(onset_s)
        out = []
        for column, rows in zip(self.columns, boundary, strict=True):
            used = np.flatnonzero(column.T.any(axis=1) | rows.T.any(axis=1))
            spectrum = np.zeros((k_max, column.shape[1]), dtype=np.complex128)
            if used.size:
                moved = column.T[used]  # (u, n) channel-major copy
                moved[:, :i] = 0.0
                moved[:, lo:lo + rows.shape[0]] += rows.T[used]
                spectrum[:, used] = dft(moved.T, k_max)
            out.append(spectrum)
        return out

    def _boundary(self, onset_s: float) -> tuple[int, int, list[np.ndarray]]:
        """(i, lo, E rows): the first sample from the onset, the first row of the boundary window and each
        column's E_tau on it (rows lo .. lo + 3, the window-local wrap rows zero in both terms)."""
        t = self.ctx.readouts.t_s
        n = t.shape[0]
        i = int(np.searchsorted(t, onset_s, side="left"))  # first sample with t >= onset
        lo, hi = max(i - MEMORY_SAMPLES, 0), min(i + MEMORY_SAMPLES, n)
        on = (t[lo:hi] >= onset_s).astype(np.float64)
        lin = replace(self.ctx.lin, m=self.ctx.lin.m[lo:hi], torque_edges=(0, 0))
        head, tail = self.ctx.lin.torque_edges
        near_edge = lo < max(head, *WRAP_SAMPLES.values()) or hi > n - tail
        boundary = []
        for changes in self.changes:
            window = {key: value[lo:hi] for key, value in changes.items()}
            masked = {key: value * on.reshape((-1,) + (1,) * (value.ndim - 1)) for key, value in window.items()}
            rows = (perturbation_channels(lin, self.ctx.model, **masked)
                    - on[:, None] * perturbation_channels(lin, self.ctx.model, **window))
            if near_edge:  # the record's own wrap and edge samples stay zero
                whole = np.zeros((n, rows.shape[1]))
                whole[lo:hi] = rows
                zero_wrap(whole, self.ctx.lin.torque_edges)
                rows = whole[lo:hi]
            boundary.append(rows)
        return i, lo, boundary


def step_pieces(candidate: Candidate, ctx: CandidateContext, weights: np.ndarray | None = None
                ) -> StepPieces | None:
    """The candidate's pieces from the start (``ctx`` without an onset), or None where its columns are not
    each one logged change (then build it at each onset). ``weights``: the pieces of the one column
    ``series_sum(ctx, weights)`` (a relinearised series signature, :meth:`.record.Record.relinearise`), each
    series term one logged change: P is linear, so the column's change is the weighted sum of theirs."""
    if candidate.onset_kind != "step":
        return None
    t = ctx.readouts.t_s
    if not t.shape[0]:
        return None
    log: list[dict[str, np.ndarray]] = []
    # a step at the first sample: every change on, and a step-only parameter's column built (Candidate.step_params)
    logged = replace(ctx.at_onset("step", float(t[0])), changes_log=log)
    if weights is None:
        columns = candidate.build(logged)
        return StepPieces(ctx, columns, log) if len(log) == len(columns) else None
    used = [w for w in weights if w != 0.0]
    if candidate.series_term is None or candidate.grid is not None or not used:
        return None  # a timing candidate's knots: its thrust change is not a logged change
    column = candidate.series_sum(logged, weights)
    if candidate.series_weighted is not None:  # the sum built in one logged change, weights applied
        return StepPieces(ctx, [column], [log[0]]) if len(log) == 1 else None
    if len(log) != len(used):
        return None
    change: dict[str, np.ndarray] = {}
    for w, term in zip(used, log, strict=True):
        for key, value in term.items():
            change[key] = change[key] + w * value if key in change else w * value
    return StepPieces(ctx, [column], [change])
