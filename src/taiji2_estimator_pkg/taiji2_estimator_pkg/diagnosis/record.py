"""One record (the whole run, or its training or held-out part): channels, spectra, normal equations.

Also the calibration of the nominal model (Gauss-Newton on the nuisance columns only).

Length (just over 600 lines): the record class and the calibration build the same columns, whitening and
normal equations from one set of helpers (``column_fft``, ``fixed_change``); kept together for that reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from itertools import pairwise

import numpy as np
from scipy.optimize import minimize_scalar

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, CandidateContext
from taiji2_estimator_pkg.diagnosis.channels import (
    Linearization,
    linearize,
    nuisance_column,
    nuisance_names,
    readouts_from_input,
)
from taiji2_estimator_pkg.diagnosis.dynamics import ResponseFit, fit_response
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.locations import scan_keep
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.spectral import ConditionedFit, Design, NoiseSpectrum, Whitener, dft
from taiji2_estimator_pkg.diagnosis.step_onset import StepPieces, step_pieces

__all__ = ["Record", "RecordSettings", "calibrate", "column_fft", "fixed_change"]

_FIXED = "__fixed_change__"  # a scratch design column for fits with a fixed channel change


class RecordSettings:
    """The options a record needs (a subset of :class:`.options.DiagnosisOptions`).

    Parameters
    ----------
    f_max_hz : float
        Highest frequency of the fits [Hz].
    orbit_period_s, suspension_hz, damping, st_corner_hz : float
        Candidate settings.
    """

    def __init__(self, f_max_hz: float, orbit_period_s: float, suspension_hz: float, damping: float,
                 st_corner_hz: float) -> None:
        self.f_max_hz = f_max_hz
        self.orbit_period_s = orbit_period_s
        self.suspension_hz = suspension_hz
        self.damping = damping
        self.st_corner_hz = st_corner_hz


def column_fft(column: np.ndarray, k_max: int) -> np.ndarray:
    """DFT (bins 1..k_max) of an (n, 15) column, transforming only its non-zero channels."""
    out = np.zeros((k_max, column.shape[1]), dtype=np.complex128)
    rows = column.T  # channel-major: contiguous for the Fortran-ordered columns of .channels
    used = np.flatnonzero(rows.any(axis=1))
    if used.size:
        out[:, used] = dft(rows[used].T, k_max)
    return out


def _k_max(n: int, sample_rate_hz: float, f_max_hz: float) -> int:
    return max(1, min(int(f_max_hz * n / sample_rate_hz), (n - 1) // 2))


class Record:
    """Channels, exact spectra, column DFTs and normal equations of one record.

    Parameters
    ----------
    inp : DiagnosisInput
        Data.
    model : NominalModel
        Nominal model.
    g_angular, com_offset_m : numpy.ndarray
        (2, 3) linearization point (calibrated G, d).
    settings : RecordSettings
        Fit band and candidate settings.
    candidates : sequence of Candidate
        Variants whose columns are built.
    t_mid_s : float
        Reference time of the drift signatures [s] (middle of the whole run).
    onsets : dict of str to float, optional
        Variant key -> onset [s] of the variants that start mid-run (:meth:`set_onset`).
    fixed : sequence of (Candidate, theta, onset), optional
        Effects of an extended nominal model, subtracted from the channels at their given values
        (:func:`fixed_change`).
    """

    def __init__(self, inp: DiagnosisInput, model: NominalModel, g_angular: np.ndarray, com_offset_m: np.ndarray,
                 settings: RecordSettings, candidates: Sequence[Candidate], t_mid_s: float,
                 onsets: dict[str, float] | None = None,
                 fixed: Sequence[tuple] = ()) -> None:
        self.inp = inp
        self.model = model
        self.settings = settings
        self.readouts = readouts_from_input(inp, model)
        self.lin: Linearization = linearize(self.readouts, model, g_angular, com_offset_m)
        self.n = inp.n
        #: (n,) epochs the location scan uses (estimated ones and their neighbours left out), None: all
        self.keep = scan_keep(inp.filled, inp.n)
        self.k_max = _k_max(self.n, model.sample_rate_hz, settings.f_max_hz)
        self.bins = np.arange(1, self.k_max + 1)
        self.spectrum = NoiseSpectrum(model, com_offset_m, self.n, inp.angular_loss)
        self.ctx = CandidateContext(self.lin, self.readouts, model, settings.orbit_period_s, settings.suspension_hz,
                                    settings.damping, t_mid_s)
        self.fixed = list(fixed)
        if self.fixed:  # the extended nominal model: its known effects leave the channels
            self.lin.channels[:] -= sum(fixed_change(self.ctx, *entry) for entry in self.fixed)
        self.onsets: dict[str, float] = dict(onsets or {})
        self.nuisance = nuisance_names()
        self.ffts: dict[str, np.ndarray] = {}
        for name in self.nuisance:
            self.ffts[name] = column_fft(nuisance_column(self.lin, model, name), self.k_max)
        self.candidates = {c.key: c for c in candidates}
        for candidate in candidates:
            for name, column in zip(candidate.column_names(), candidate.build(self.ctx_of(candidate)), strict=True):
                self.ffts[name] = column_fft(column, self.k_max)
        self.names = list(self.ffts)
        self.y_fft = dft(self.lin.channels, self.k_max)
        self.st_template = self.spectrum.st_template(self.bins, settings.st_corner_hz)
        self.kappa = 0.0
        self.secant: dict[str, float] = {}
        self.exact_secants: dict[str, np.ndarray] = {}
        self._torque_psd: np.ndarray | None = None
        self.whitener: Whitener
        self.design: Design
        self.rebuild(0.0)

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Frequencies of the fit bins [Hz]."""
        return self.bins * self.model.sample_rate_hz / self.n

    def rebuild(self, kappa: float) -> None:
        """Whiten with the extra star-tracker noise ``kappa`` (f_knee^2) and rebuild the normal equations.

        Columns keep their current linearisation (see :meth:`relinearise`).
        """
        self.kappa = float(kappa)
        extra = self.kappa * self.st_template if self.kappa > 0 else None
        self.whitener = Whitener(self.spectrum, self.bins, extra)
        self.design = Design.build(self.whitener, self.y_fft, self.names, [self.ffts[n] for n in self.names])

    @property
    def n_rows(self) -> int:
        """Real rows of the least squares (2 K 15)."""
        return self.design.n_rows

    def indices(self, names: Sequence[str]) -> np.ndarray:
        """Design indices of column names."""
        return self.design.index(names)

    def fit(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, float]:
        """(estimates, covariance, chi2) of a set of columns."""
        return self.design.fit(self.indices(names))

    def _ensure_series(self, candidate: Candidate, terms: int | None = None) -> list[str]:
        """The names of the candidate's series columns (the first ``terms``, or all), built into the design
        where missing (one term at a time where the candidate builds terms alone)."""
        names = candidate.series_names()[:terms]
        missing = [j for j, name in enumerate(names) if name not in self.ffts]
        if missing and candidate.series is not None:
            ffts = [column_fft(column, self.k_max)
                    for column in _series_columns(candidate, self.ctx_of(candidate), missing)]
            built = [names[j] for j in missing]
            for name, fft in zip(built, ffts, strict=True):
                self.ffts[name] = fft
            self.names = [*self.names, *built]
            self.design.append(self.whitener, built, ffts)
        return names

    def add_candidate(self, candidate: Candidate) -> list[str]:
        """Build the columns of a candidate the record was not made with into the fit (an impulse found in the
        final residual); returns their names."""
        names = candidate.column_names()
        ffts = [column_fft(column, self.k_max) for column in candidate.build(self.ctx_of(candidate))]
        self.candidates[candidate.key] = candidate
        for name, fft in zip(names, ffts, strict=True):
            self.ffts[name] = fft
        self.names = [*self.names, *names]
        self.design.append(self.whitener, names, ffts)
        return names

    def set_exact_secant(self, candidate: Candidate, value: float, change: np.ndarray) -> None:
        """Make a one-parameter candidate's column ``change / value`` ((n, 15) channel change at
        ``value``, computed exactly rather than from its knots): theta x column is then exact at value."""
        (name,) = candidate.column_names()
        column = change / value if value != 0.0 else change
        self.exact_secants[candidate.key] = column
        self.ffts[name] = column_fft(column, self.k_max)
        self.design.replace(self.whitener, name, self.ffts[name])
        self.secant[candidate.key] = float(value)

    def chi2_with_column(self, free: Sequence[str], change: np.ndarray) -> float:
        """Chi-square after subtracting a fixed (n, 15) channel change and refitting ``free``."""
        fft = column_fft(change, self.k_max)
        if _FIXED not in self.design.names:
            self.design.append(self.whitener, [_FIXED], [fft])
        else:
            self.design.replace(self.whitener, _FIXED, fft)
        return self.design.chi2_with_offset(self.indices(free), self.indices([_FIXED]), np.ones(1))

    def relinearise(self, candidate: Candidate, theta: np.ndarray) -> None:
        """Replace a polynomial signature's column by its secant at ``theta``: theta x column = the
        exact (series) channel change, so that a linear fit near theta is consistent."""
        self.exact_secants.pop(candidate.key, None)
        if candidate.series is None or candidate.coefficients is None:
            return
        value = float(np.ravel(theta)[0])
        names = self._ensure_series(candidate)
        weights = self._secant_weights(candidate, value)
        (name,) = candidate.column_names()
        self.ffts[name] = sum(w * self.ffts[n] for w, n in zip(weights, names, strict=True))
        self.design.replace(self.whitener, name, self.ffts[name])
        self.secant[candidate.key] = value

    @staticmethod
    def _secant_weights(candidate: Candidate, value: float) -> np.ndarray:
        if value == 0.0:
            if candidate.grid is not None:  # knot signatures: the central secant about 0
                step = 0.5 * float(np.min(np.abs(np.diff(candidate.grid))))
                return (candidate.coefficients(step) - candidate.coefficients(-step)) / (2.0 * step)
            size = len(candidate.coefficients(1.0))
            return candidate.coefficients(1.0) * (np.arange(size) == 0)
        return candidate.coefficients(value) / value

    def series_fit(self, candidate: Candidate, others: Sequence[str]) -> tuple[float, float]:
        """Magnitude and chi2 of a polynomial signature fitted by its exact series, ``others`` refitted.

        With the other columns projected out, ``chi2(theta) = c - 2 v^T b + v^T M v`` with
        ``v = coefficients(theta)``: a cheap polynomial, scanned densely over
        ``|theta| <= bound`` and refined by golden section.
        """
        if candidate.series is None or candidate.coefficients is None:
            raise ValueError(f"{candidate.key} has no series")
        if candidate.leading is not None:  # the leading terms first; all of them only for a magnitude beyond
            terms, leading_bound = candidate.leading
            value, chi2 = self._series_fit(candidate, others, terms)
            if abs(value) <= leading_bound(self.ctx):
                return value, chi2
        return self._series_fit(candidate, others, None)

    def _series_fit(self, candidate: Candidate, others: Sequence[str], terms: int | None) -> tuple[float, float]:
        """:meth:`series_fit` with the first ``terms`` of the series (None: all)."""
        series = self._ensure_series(candidate, terms)
        design = self.design
        free, fixed = self.indices(others), self.indices(series)
        gram = design.gram
        g_ff = gram[np.ix_(free, free)]
        scale = np.sqrt(np.maximum(np.diag(g_ff), 1e-300))
        rhs = np.column_stack((design.xty[free], gram[np.ix_(free, fixed)])) / scale[:, None]
        solved = np.linalg.solve(g_ff / np.outer(scale, scale) + 1e-13 * np.eye(free.size), rhs) / scale[:, None]
        chi2_others = design.yty - float(design.xty[free] @ solved[:, 0])
        b = design.xty[fixed] - gram[np.ix_(free, fixed)].T @ solved[:, 0]
        m = gram[np.ix_(fixed, fixed)] - gram[np.ix_(free, fixed)].T @ solved[:, 1:]
        def coefficients(value: float | np.ndarray) -> np.ndarray:
            return candidate.coefficients(value)[..., :len(series)]

        def objective(value: float) -> float:
            v = coefficients(value)
            return chi2_others - 2.0 * float(v @ b) + float(v @ m @ v)

        if candidate.grid is not None:
            grid = candidate.grid
        else:
            limit = candidate.bound(self.ctx) if candidate.bound is not None else np.inf
            linear = float(b[0] / m[0, 0]) if m[0, 0] > 0 else 0.0
            sigma = 1.0 / math.sqrt(max(m[0, 0], 1e-300))
            width = min(max(300.0 * sigma, 5.0 * abs(linear)), 2.0 * limit) if np.isfinite(limit) else \
                max(300.0 * sigma, 5.0 * abs(linear))
            ramp = np.linspace(-1.0, 1.0, 2001)
            grid = linear + width * np.sign(ramp) * ramp ** 2
            if np.isfinite(limit):
                grid = grid[np.abs(grid) <= limit]
                grid = np.append(grid, 0.0) if grid.size else np.array([0.0])
        weights = coefficients(grid)
        values = chi2_others - 2.0 * weights @ b + np.einsum("gi,ij,gj->g", weights, m, weights)
        best = int(np.argmin(values))
        lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
        if hi > lo:
            refined = minimize_scalar(objective, bounds=(min(lo, hi), max(lo, hi)), method="bounded")
            value = float(refined.x)
        else:
            value = float(grid[best])
        return value, objective(value)

    def refine(self, candidate: Candidate, others: Sequence[str]) -> tuple[np.ndarray, np.ndarray, float]:
        """Fit ``others`` + the candidate; a polynomial signature by its exact series (:meth:`series_fit`),
        its column then becoming the secant at the fitted magnitude.

        Returns the fit of ``others + candidate`` (estimates, covariance, chi2).
        """
        names = list(others) + candidate.column_names()
        if candidate.series is None or candidate.coefficients is None:
            return self.fit(names)
        value, _ = self.series_fit(candidate, others)
        self.relinearise(candidate, np.array([value]))
        return self.fit(names)

    def chi2(self, names: Sequence[str]) -> float:
        """Residual chi-square of a set of columns (no covariance: cheaper)."""
        return self.design.chi2(self.indices(names))

    def residual_fft(self, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
        """(K, 15) residual after subtracting ``names`` times ``theta``."""
        out = self.y_fft.copy()
        for name, value in zip(names, theta, strict=True):
            out -= value * self.ffts[name]
        return out

    def signature_fft(self, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
        """(K, 15) sum of columns times values."""
        out = np.zeros_like(self.y_fft)
        for name, value in zip(names, theta, strict=True):
            out += value * self.ffts[name]
        return out

    def fit_with_fixed(self, free: Sequence[str], fixed: Sequence[str], theta_fixed: np.ndarray
                       ) -> tuple[np.ndarray, float]:
        """Free columns refitted after subtracting fixed ones: (estimates, chi2)."""
        idx, o = self.indices(free), self.indices(fixed)
        beta = self.design.solve_with_offset(idx, o, theta_fixed)
        return beta, self.design.chi2_with_offset(idx, o, theta_fixed)

    def projected_gram(self, free: Sequence[str], fixed: Sequence[str]) -> np.ndarray:
        """Whitened Gram matrix of the ``fixed`` columns after projecting out the ``free`` ones:
        ``M = X_o^T X_o - X_o^T X_f (X_f^T X_f)^-1 X_f^T X_o``, the Fisher information of the fixed
        columns' values with the free ones fitted."""
        idx, o = self.indices(free), self.indices(fixed)
        gram = self.design.gram
        cross_term = gram[np.ix_(idx, o)]
        g_ff = gram[np.ix_(idx, idx)]
        scale = np.sqrt(np.maximum(np.diag(g_ff), 1e-300))
        solved = np.linalg.solve(g_ff / np.outer(scale, scale) + 1e-13 * np.eye(idx.size),
                                 cross_term / scale[:, None]) / scale[:, None]
        return gram[np.ix_(o, o)] - cross_term.T @ solved

    # time domain --------------------------------------------------------------------------
    def ctx_of(self, candidate: Candidate, onset_s: float | str | None = "current") -> CandidateContext:
        """The candidate context with the candidate's onset (``"current"``: the one set, if any)."""
        onset = self.onsets.get(candidate.key) if onset_s == "current" else onset_s
        return self.ctx.at_onset(candidate.onset_kind, onset) if onset is not None else self.ctx

    def _candidate_columns(self, candidate: Candidate, onset_s: float | str | None = "current") -> list[np.ndarray]:
        """Time-domain columns of a candidate at its current linearisation (the secant, if relinearised),
        starting at its onset (or at ``onset_s``)."""
        ctx = self.ctx_of(candidate, onset_s)
        value = self.secant.get(candidate.key)
        if candidate.key in self.exact_secants:
            if onset_s == "current" or candidate.exact is None or not value:
                return [self.exact_secants[candidate.key]]
            return [candidate.exact(ctx, value) / value]
        if value is None or candidate.series is None:
            return candidate.build(ctx)
        weights = self._secant_weights(candidate, value)
        return [candidate.series_sum(ctx, weights)]

    def column_ffts(self, candidate: Candidate, onset_s: float | str | None = "current") -> list[np.ndarray]:
        """(K, 15) DFTs of a candidate's columns at its current linearisation, starting at its onset (or
        at ``onset_s``), built anew (not those of the design)."""
        return [column_fft(column, self.k_max) for column in self._candidate_columns(candidate, onset_s)]

    def set_onset(self, candidate: Candidate, onset_s: float | None) -> None:
        """Let a candidate start at ``onset_s`` (None: from the start): its columns (and series) rebuilt."""
        if onset_s is None:
            self.onsets.pop(candidate.key, None)
        else:
            self.onsets[candidate.key] = float(onset_s)
        ctx = self.ctx_of(candidate)
        if candidate.key in self.exact_secants and candidate.exact is not None and self.secant.get(candidate.key):
            value = self.secant[candidate.key]
            self.set_exact_secant(candidate, value, candidate.exact(ctx, value))
        names = candidate.series_names()
        if candidate.series is not None and names and names[0] in self.ffts:
            built = [j for j, name in enumerate(names) if name in self.ffts]  # a leading part, or all
            for j, column in zip(built, _series_columns(candidate, ctx, built), strict=True):
                self.ffts[names[j]] = column_fft(column, self.k_max)
                self.design.replace(self.whitener, names[j], self.ffts[names[j]])
        if candidate.key in self.exact_secants:
            return
        for name, column in zip(candidate.column_names(), self._candidate_columns(candidate), strict=True):
            self.ffts[name] = column_fft(column, self.k_max)
            self.design.replace(self.whitener, name, self.ffts[name])

    def onset_profile(self, candidate: Candidate, others: Sequence[str], onsets_s: Sequence[float],
                      fixed: ConditionedFit | None = None,
                      columns: dict[tuple[str, float], list[np.ndarray]] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
        """chi2 and ``log det`` of the candidate's parameter covariance for each trial onset, ``others``
        refitted (the profile likelihood over the onset; :func:`.onset.onset_posterior`). ``fixed``: the
        others' normal equations already factored (``design.conditioned``); ``columns``: (variant key, onset)
        -> column DFTs kept across calls by a caller whose variant's signature does not change meanwhile.
        A family of variants (``candidate.members``, :mod:`.family_candidates`) is profiled over one onset
        of all its members."""
        members = getattr(candidate, "members", (candidate,))
        chi2 = np.empty(len(onsets_s))
        log_det = np.empty(len(onsets_s))
        pieces: dict[str, StepPieces | bool | None] = {}
        if fixed is None:
            fixed = self.design.conditioned(self.indices(others))  # the others' normal equations, factored once
        for i, onset in enumerate(onsets_s):
            ffts = [fft for member in members for fft in self._onset_ffts(member, float(onset), pieces, columns)]
            _, cov, chi2[i] = fixed.add(self.whitener, ffts)
            # the parameters present from the start only: a step-only one (Candidate.step_params) is profiled,
            # its flat-prior integral diverging as the onset nears the start, where its column vanishes
            q = sum(member.n_params for member in members)
            sign, value = np.linalg.slogdet(cov[:q, :q])
            log_det[i] = value if sign > 0 else -np.inf
        return chi2, log_det

    def _onset_ffts(self, candidate: Candidate, onset_s: float, pieces: dict[str, StepPieces | bool | None],
                    columns: dict[tuple[str, float], list[np.ndarray]] | None) -> list[np.ndarray]:
        """The candidate's column DFTs from ``onset_s`` on (:meth:`onset_profile`); ``pieces``: its step pieces
        (.step_onset) by key, built at the first onset not kept in ``columns``."""
        key = (candidate.key, onset_s)
        ffts = None if columns is None else columns.get(key)
        if ffts is not None:
            return ffts
        if candidate.key not in pieces:
            if candidate.key in self.exact_secants:
                pieces[candidate.key] = False
            else:  # a relinearised series signature from its weighted terms (.step_onset)
                value = self.secant.get(candidate.key)
                weights = None if candidate.series is None or value is None else self._secant_weights(candidate,
                                                                                                      value)
                pieces[candidate.key] = step_pieces(candidate, self.ctx, weights) or False
        built = pieces[candidate.key]
        ffts = built.ffts_at(onset_s, self.k_max) if built else self.column_ffts(candidate, onset_s)
        if columns is not None:
            columns[key] = ffts
        return ffts

    def time_column(self, name: str) -> np.ndarray:
        """(n, 15) column by name (recomputed)."""
        if name in self.nuisance:
            return nuisance_column(self.lin, self.model, name)
        key, _, param = name.rpartition(":")
        candidate = self.candidates[key]
        return self._candidate_columns(candidate)[candidate.params.index(param)]

    def residual_time(self, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
        """(n, 15) residual channels after the fitted columns and the chain's high-frequency response
        (all frequencies; :mod:`.dynamics`)."""
        return self.response(names, theta)[0]

    def response(self, names: Sequence[str], theta: np.ndarray) -> tuple[np.ndarray, ResponseFit]:
        """Residual channels after the fitted columns, with the response fitted and removed, and that fit."""
        out = self.lin.channels.copy()
        built: dict[str, list[np.ndarray]] = {}
        for name, value in zip(names, theta, strict=True):
            if value == 0.0:
                continue
            if name in self.nuisance:
                out -= value * nuisance_column(self.lin, self.model, name)
                continue
            key, _, param = name.rpartition(":")
            candidate = self.candidates[key]
            if key not in built:
                built[key] = self._candidate_columns(candidate)
            out -= value * built[key][candidate.params.index(param)]
        if self._torque_psd is None:
            self._torque_psd = self.spectrum.marginal(np.arange(1, self.n // 2 + 1))[:, 3:6]
        # the model's prediction of the angular acceleration with the fitted columns (timing included):
        # m - residual = acc_pred + sum of the columns' torque parts, free of the channel's noise
        predicted = self.lin.m - out[:, 3:6]
        return fit_response(out, predicted, self.lin.torque_edges, self.model.dt_s, self.settings.f_max_hz,
                            self._torque_psd)

    def marginal(self, kappa: float | None = None) -> np.ndarray:
        """(K, 15) per-channel spectrum at the fit bins with the star-tracker extra ``kappa``."""
        out = self.whitener.marginal.copy()
        kappa = self.kappa if kappa is None else kappa
        if kappa != self.kappa:
            out[:, 0:3] += (kappa - self.kappa) * self.st_template
        return out

    # star-tracker low-frequency noise ------------------------------------------------------
    def _noise_terms(self, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        whitener = self.whitener
        w = whitener.apply(residual)
        left = whitener.inverse[:, :, 0:3]  # L^-1 U in scaled coordinates
        a = np.einsum("kri,krj->kij", left.conj(), left)  # U^T S^-1 U
        v = np.einsum("kri,kr->ki", left.conj(), w)  # U^T S^-1 Y
        template = self.st_template / whitener.scale[None, 0:3] ** 2
        return a, v, template

    @staticmethod
    def _objective(a: np.ndarray, v: np.ndarray, template: np.ndarray, kappa: float) -> float:
        """sum_k [log det(I + A K) - v^H K (I + A K)^-1 v]: change of -log L by the extra noise."""
        k = kappa * template
        m = np.eye(3) + a * k[:, None, :]
        _, logdet = np.linalg.slogdet(m)
        solved = np.linalg.solve(m, v[:, :, None])[:, :, 0]
        quad = np.einsum("ki,ki->k", v.conj(), k * solved).real
        return float(np.sum(logdet - quad))

    @staticmethod
    def _information(a: np.ndarray, template: np.ndarray, kappa: float) -> float:
        """Fisher information of kappa (complex bins): sum_k tr((B T)^2), B = A (I + K A)^-1."""
        k = kappa * template
        m = np.eye(3) + k[:, :, None] * a  # I + K A
        b = np.linalg.solve(m.transpose(0, 2, 1), a.transpose(0, 2, 1)).transpose(0, 2, 1)
        bt = b * template[:, None, :]
        return float(np.sum(np.einsum("kij,kji->k", bt, bt).real))

    def noise_gain(self, residual: np.ndarray) -> tuple[float, float, float]:
        """Fit the extra star-tracker noise to a residual (on top of the current whitening).

        Returns
        -------
        kappa : float
            f_knee^2 [Hz^2] (>= 0).
        gain : float
            ``2 delta log L`` (Whittle).
        sigma : float
            1-sigma of kappa (expected information at the estimate).
        """
        a, v, template = self._noise_terms(residual)
        unit = 1.0 / math.sqrt(max(self._information(a, template, 0.0), 1e-300))
        best = minimize_scalar(lambda x: self._objective(a, v, template, x * x * unit), bounds=(0.0, 60.0),
                               method="bounded", options={"xatol": 1e-4})
        kappa = float(best.x) ** 2 * unit
        gain = -2.0 * self._objective(a, v, template, kappa)
        if gain <= 0.0:
            kappa, gain = 0.0, 0.0
        sigma = 1.0 / math.sqrt(max(self._information(a, template, kappa), 1e-300))
        return kappa, gain, sigma

    def noise_gain_at(self, residual: np.ndarray, kappa: float) -> float:
        """``2 delta log L`` of a fixed extra amplitude (held-out check)."""
        a, v, template = self._noise_terms(residual)
        return -2.0 * self._objective(a, v, template, kappa)

    def noise_gain_null(self, residual: np.ndarray, kappa: float) -> tuple[float, float]:
        """Mean and std of :meth:`noise_gain_at` at ``kappa`` when the data hold no extra noise
        (:meth:`null_moments`); the held-out z of the noise effect tests its gain against them."""
        a, _, template = self._noise_terms(residual)
        return self.null_moments(a, template, kappa)

    @staticmethod
    def null_moments(a: np.ndarray, template: np.ndarray, kappa: float) -> tuple[float, float]:
        """Mean and std of the gain ``-2 sum_k [log det(I + A K) - v^H M v]`` for ``v ~ CN(0, A)``.

        ``M = K (I + A K)^-1`` is Hermitian, so for a complex circular Gaussian v
        ``E[v^H M v] = tr(M A)`` and ``Var[v^H M v] = tr((M A)^2)``: ``E = -2 sum_k [log det(I + A K)
        - tr(M A)]``, ``Var = 4 sum_k tr((M A)^2)``. With no extra noise ``v = U^H S^-1 Y ~ CN(0, A)``.
        """
        k = kappa * template
        m_inv = np.eye(a.shape[-1]) + a * k[:, None, :]  # I + A K
        _, logdet = np.linalg.slogdet(m_inv)
        ma = k[:, :, None] * np.linalg.solve(m_inv, a)  # M A = K (I + A K)^-1 A
        trace = np.einsum("kii->k", ma).real
        trace_sq = np.einsum("kij,kji->k", ma, ma).real
        mean = -2.0 * float(np.sum(logdet - trace))
        return mean, 2.0 * math.sqrt(max(float(np.sum(trace_sq)), 0.0))


def _series_columns(candidate: Candidate, ctx: CandidateContext, terms: Sequence[int]) -> list[np.ndarray]:
    """The candidate's series columns ``terms`` (indices), each alone where it can build one term alone."""
    if candidate.series_term is not None:
        return [candidate.series_term(ctx, j) for j in terms]
    return [c for j, c in enumerate(candidate.series(ctx)) if j in terms]


#: with free effects, past this many iterations a re-fit whose update shrinks by less than
#: :data:`SLOW_CONTRACTION` per iteration is stopped (it would not reach 0.05 sigma in the iterations left;
#: it is then withheld as not converged, as at its last iteration)
SLOW_AFTER = 8
SLOW_CONTRACTION = 0.8


def calibrate(inp: DiagnosisInput, model: NominalModel, settings: RecordSettings, iterations: int,
              progress: Callable[[str], None],
              fixed: Sequence[tuple] = (), t_mid_s: float | None = None,
              info: dict | None = None, free: Sequence[tuple] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray]:
    """Gauss-Newton calibration of G and d (with the trends and wrap impulses).

    ``fixed``: effects of an extended nominal model (candidate, values, onset), subtracted from the
    channels at each iteration (:func:`fixed_change`); ``free``: effects of the same form whose values
    are only the starting point: they are re-fitted with G and d (their channel change at the current
    values subtracted, their derivative a column of the fit, relinearised at every iteration), so that
    G and d are the joint estimate under the extended model and their sigmas are marginal over the
    effects (a G that an effect aliases with is as uncertain as that effect's magnitude makes it).
    ``info`` (if given) receives ``"cov"``, the (12, 12) covariance of (relative G, d) of the last
    iteration, ``"chi2"``, ``"dof"``, ``"last_update_sigma"`` (the last iteration's largest update in
    sigmas: the fit has not converged where it is large; with ``free``, a fit whose updates grow twice in a
    row past its third iteration stops there, and one whose update shrinks by less than a factor
    :data:`SLOW_CONTRACTION` past :data:`SLOW_AFTER` iterations), ``"iterations"`` (those run) and, with
    ``free``, ``"free_values"`` (the re-fitted values, one array per entry), ``"free_sigma"`` and
    ``"beyond_series_bound"`` (the free effects whose value left the range where their series form holds).

    Returns
    -------
    g_angular : numpy.ndarray
        (2, 3) calibrated angular scale factors [rad s^-2 V^-1].
    com_offset_m : numpy.ndarray
        (2, 3) calibrated d [m].
    sigma_g_relative : numpy.ndarray
        (2, 3) relative 1-sigma of G.
    sigma_d_m : numpy.ndarray
        (2, 3) 1-sigma of d [m].
    """
    g = model.g_angular.copy()
    d = model.com_offset_m.copy()
    readouts = readouts_from_input(inp, model)
    n = inp.n
    k_max = _k_max(n, model.sample_rate_hz, settings.f_max_hz)
    bins = np.arange(1, k_max + 1)
    names = nuisance_names()
    sigma_g = np.full((2, 3), np.inf)
    sigma_d = np.full((2, 3), np.inf)
    t_mid = float(0.5 * (inp.t_s[0] + inp.t_s[-1])) if t_mid_s is None else t_mid_s
    values = [np.atleast_1d(np.asarray(entry[1], dtype=np.float64)).copy() for entry in free]
    ctx = None
    updates: list[float] = []
    for iteration in range(max(1, iterations)):
        lin = linearize(readouts, model, g, d)
        columns: list[np.ndarray] = []
        if fixed or free:
            ctx = CandidateContext(lin, readouts, model, settings.orbit_period_s, settings.suspension_hz,
                                   settings.damping, t_mid)
            with np.errstate(over="ignore", invalid="ignore"):  # a diverging re-fit: checked below
                for entry in fixed:
                    lin.channels[:] -= fixed_change(ctx, *entry)
                instrument = replace(ctx, lin=lin.noise_free()) if free else ctx
                for entry, value in zip(free, values, strict=True):
                    change, derivatives = _change_and_derivatives(ctx, entry, value, instrument)
                    lin.channels[:] -= change
                    columns += derivatives
            if not (np.all(np.isfinite(lin.channels)) and all(np.all(np.isfinite(c)) for c in columns)):
                # the effects' values left every range where their model is finite: no fit at them
                progress(f"calibration iteration {iteration + 1}: the extended model is not finite; stopped")
                if info is not None:
                    info["last_update_sigma"] = math.inf
                break
        whitener = Whitener(NoiseSpectrum(model, d, n, inp.angular_loss), bins)
        design = Design.build(whitener, dft(lin.channels, k_max), [*names, *(f"free{j}" for j in range(len(columns)))],
                              [column_fft(nuisance_column(lin, model, name), k_max) for name in names]
                              + [column_fft(column, k_max) for column in columns])
        theta, cov, chi2 = design.fit(np.arange(len(names) + len(columns)))
        sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
        steps, sigma_free = theta[len(names):], sig[len(names):]
        bounds = np.cumsum([0, *(value.size for value in values)])
        for value, (start, stop) in zip(values, pairwise(bounds), strict=True):
            value += steps[start:stop]
        if info is not None:
            info["cov"] = cov[:12, :12]
            info["chi2"] = chi2
            info["dof"] = design.n_rows - len(names) - len(columns)
            if free:
                info["free_values"] = [value.copy() for value in values]
                info["free_sigma"] = [sigma_free[start:stop] for start, stop in pairwise(bounds)]
        sigma_g, sigma_d = sig[:6].reshape(2, 3), sig[6:12].reshape(2, 3)
        g = g * (1.0 + theta[:6].reshape(2, 3))
        d = d + theta[6:12].reshape(2, 3)
        moved = np.concatenate((theta[:12], steps))
        scale = np.concatenate((sig[:12], sig[len(names):]))
        change = float(np.max(np.abs(moved) / np.where(scale > 0, scale, 1.0)))
        progress(f"calibration iteration {iteration + 1}: largest update {change:.3g} sigma")
        if info is not None:
            info["last_update_sigma"] = change
            info["iterations"] = iteration + 1
        if change < 0.05:
            break
        updates.append(change)
        if free and len(updates) >= SLOW_AFTER and updates[-1] > SLOW_CONTRACTION * updates[-2]:
            progress(f"calibration iteration {iteration + 1}: the updates shrink too slowly; stopped")
            break
        if free and len(updates) >= 4 and updates[-1] > updates[-2] > updates[-3]:
            # a re-fit whose updates grow twice in a row past its third iteration is not converging (an
            # alias swapped in that oscillates against a nonlinearity: 0.35, 0.73, 1.1, 1.7, 1.4, 0.58 sigma):
            # it is withheld at the last iteration as at this one, without the iterations in between
            progress(f"calibration iteration {iteration + 1}: the updates grow; stopped")
            break
    if info is not None and free:  # a series form holds only within its bound (the nonlinearity: k a_max ~ 0.2)
        info["beyond_series_bound"] = [
            entry[0].key for entry, value in zip(free, values, strict=True)
            if entry[0].exact is None and entry[0].series is not None and entry[0].bound is not None
            and (ctx is None or not abs(float(value[0])) <= entry[0].bound(ctx))]
    return g, d, sigma_g, sigma_d


def _change_and_derivatives(ctx: CandidateContext, entry: tuple, value: np.ndarray, instrument: CandidateContext
                            ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The channel change of a free effect at ``value`` (on ``ctx``: the measured accelerations) and its
    derivative per parameter, on ``instrument`` (:meth:`.channels.Linearization.noise_free`: a column
    with the channel's own noise in it shrinks its effect and moves G): the signature columns of a
    linear one (no exact or series form: its change is ``sum value_j column_j``), a forward difference
    (step 1e-4 of the value) of an exact or series one. The fit then solves the instrumental-variable
    equations ``J_instrument^T W r = 0``, whose solution is unbiased where the measured ``J^T W r = 0``
    is not."""
    candidate, _, onset, *rest = entry
    t_ref = rest[0] if rest else None
    if candidate.exact is None and (candidate.series is None or candidate.coefficients is None):
        columns = candidate.build(_onset_context(ctx, candidate, onset, t_ref))
        derivatives = list(candidate.build(_onset_context(instrument, candidate, onset, t_ref)))
        return sum(v * column for v, column in zip(value, columns, strict=True)), derivatives
    change = fixed_change(ctx, candidate, value, onset, t_ref)
    at_value = fixed_change(instrument, candidate, value, onset, t_ref)
    derivatives = []
    for j in range(value.size):
        unit = np.zeros(value.size)
        unit[j] = 1e-4 * abs(float(value[j])) or 1e-9
        derivatives.append((fixed_change(instrument, candidate, value + unit, onset, t_ref) - at_value) / unit[j])
    return change, derivatives


def _onset_context(ctx: CandidateContext, candidate: Candidate, onset_s: float | None,
                   t_ref_s: float | None) -> CandidateContext:
    ctx = ctx.at_onset(candidate.onset_kind, onset_s)
    return ctx if t_ref_s is None else replace(ctx, t_mid_s=float(t_ref_s))


def fixed_change(ctx: CandidateContext, candidate: Candidate, theta: np.ndarray, onset_s: float | None,
                 t_ref_s: float | None = None) -> np.ndarray:
    """(n, 15) channel change of a candidate at the values ``theta`` (exact where the signature has an
    exact or series form, first order otherwise), starting at ``onset_s``; a drift is zero at ``t_ref_s``
    (default: the middle of the run)."""
    ctx = _onset_context(ctx, candidate, onset_s, t_ref_s)
    theta = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    if candidate.exact is not None:
        return candidate.exact(ctx, float(theta[0]))
    if candidate.series is not None and candidate.coefficients is not None:
        return candidate.series_sum(ctx, candidate.coefficients(float(theta[0])))
    return sum(value * column for value, column in zip(theta, candidate.build(ctx), strict=True))
