"""The default (``gls``) c.m.-offset estimator: per-sample (node) and bulk (offline) forms.

The two-stage filter (:mod:`taiji2_estimator_pkg.core.twostage`) accumulates the whitened basis columns of
:class:`~.model.ComOffsetModel`; the estimate for any G follows from that cross-product (two-stage ``d(G)``,
or jointly with G by :mod:`.joint`, the default); the bulk path measures the noise in the band that carries
d (:mod:`taiji2_estimator_pkg.core.noise_level`).

Length (just over 600 lines): one class whose per-sample and bulk forms share state, gates and checkpoint
and must agree (tested); kept together for that reason.
"""

from __future__ import annotations

import copy
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.com_offset.joint import solve_joint
from taiji2_estimator_pkg.core.com_offset.model import ComOffsetModel, ComOffsetOptions
from taiji2_estimator_pkg.core.epoch_arrays import EpochArrays
from taiji2_estimator_pkg.core.gate_estimate import MIN_EIGENVALUE_RATIO, GateEstimate, gate_estimate
from taiji2_estimator_pkg.core.gate_span import GateSpan
from taiji2_estimator_pkg.core.instrument import InstrumentModel, angular_differences, linear_sums
from taiji2_estimator_pkg.core.kalman import chi2_gate
from taiji2_estimator_pkg.core.noise_level import BLOCK_S, BandNoise, band_noise, r_adjustment
from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate
from taiji2_estimator_pkg.core.twostage import TwoStageFilter, solve_information
from taiji2_estimator_pkg.core.validation import InputValidator, ValidationOptions, validate_batch

#: at most this many re-estimations with the measured band noise (noise_level.py)
_NOISE_ITERATIONS = 4


def whitening(engine: TwoStageFilter) -> np.ndarray:
    """``W = L^T`` with ``Lambda^-1 = L L^T`` (steady state): ``nu = W e`` has unit covariance."""
    return np.linalg.cholesky(engine.lambda_inv_ss).T


@dataclass(frozen=True)
class ComOffsetStepReport:
    """What one per-sample update did.

    Attributes
    ----------
    t_s : float
        Stamp [s].
    nis : float
        Pre-fit NIS (3 n_grs dof, NaN if no scale factors given or not yet determined).
    accepted : bool
        Epoch used.
    rejections : tuple of (str, str)
        (stream, reason) of inputs rejected at this epoch.
    """

    t_s: float
    nis: float
    accepted: bool
    rejections: tuple[tuple[str, str], ...] = ()


class ComOffsetEstimator:
    """Default (``gls``) c.m.-offset estimator: per-sample (node) and bulk (offline) forms.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal d and noise budget.
    grs_ids : sequence of int
        GRS estimated jointly (one or both).
    options : ComOffsetOptions, optional
        Tuning.

    Examples
    --------
    Per sample (a node; ``g`` is the latest :class:`ScaleFactorEstimate` and ``omega`` the rate
    from :meth:`ScaleFactorEstimator.rate_estimate`)::

        co = ComOffsetEstimator(instrument, (1, 2))
        co.update(t, {1: v1, 2: v2}, omega, scale_factors=g)
        d = co.estimate(g)

    In bulk (offline)::

        d = ComOffsetEstimator(instrument, (1, 2)).process_batch(t, voltages, omega, g)
    """

    method = "gls"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: ComOffsetOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or ComOffsetOptions()
        self.model = ComOffsetModel(instrument, grs_ids, self.options)
        self.grs_ids = self.model.grs_ids
        self.filter = TwoStageFilter(self.model.state_space, self.model.n_columns, self.options.snap_tolerance)
        self.validator = InputValidator(ValidationOptions(**{**self.options.validation.__dict__,
                                                             "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.gate = None if self.options.gate_probability is None else chi2_gate(self.model.m,
                                                                                  self.options.gate_probability)
        self.eiv_full = self.model.eiv_correction(self.filter.lambda_inv_ss)
        self.eiv_sum = np.zeros((self.model.n_columns, self.model.n_columns))
        self.n_eiv = 0
        self.band_noise: BandNoise | None = None
        self.t0_s: float | None = None
        self.t_last_s = float("nan")
        self.last_index: int | None = None
        self.determined = False
        self._combination_cache: tuple | None = None
        self._noise_cache: dict[tuple[int, bytes], tuple[ComOffsetModel, tuple]] = {}
        self.gate_span = GateSpan(max(1, round(self.options.gate_refresh_s * instrument.sample_rate_hz)))

    # solution for given scale factors --------------------------------------------------------
    def corrected_information(self) -> np.ndarray:
        """(q, q) cross-product of the whitened basis columns (and SRP initial state), less the
        expected errors-in-variables part: unbiased for any combination of the columns."""
        info = self.filter.info.copy()
        n = self.model.n_columns
        info[:n, :n] -= self.eiv_sum
        return info

    def _engine_combination(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(a_xx, a_yy): the column combination for scale factors g on the engine's parameters (the
        columns and the SRP initial state x0). Kept for the last (model, g): the per-epoch gate asks for
        the same G every epoch while the estimate of G stands still. Callers must not modify them."""
        model = self.model
        key = (id(model), g.tobytes())
        if self._combination_cache is not None and self._combination_cache[0] == key:
            return self._combination_cache[1]
        q = self.filter.q_total
        a_y, a_x = model.combination(g)
        # append the SRP initial-state columns (x0) of the engine
        a_xx = np.zeros((q, model.n_beta + 3))
        a_xx[:model.n_columns, :model.n_beta] = a_x
        a_xx[model.n_columns:, model.n_beta:] = np.eye(3)
        a_yy = np.zeros(q)
        a_yy[:model.n_columns] = a_y
        self._combination_cache = (key, (a_xx, a_yy), model)  # the model is held so its id stays unique
        return a_xx, a_yy

    def _beta_system(self, g: np.ndarray, info_all: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Information and vector on (beta, x0) for scale factors g, with the EIV correction, from
        ``info_all`` (default: :meth:`corrected_information`, all epochs so far)."""
        if info_all is None:
            info_all = self.corrected_information()
        a_xx, a_yy = self._engine_combination(np.asarray(g, dtype=np.float64))
        info = a_xx.T @ info_all @ a_xx
        vec = a_xx.T @ info_all @ a_yy
        return 0.5 * (info + info.T), vec, a_xx, a_yy

    def solve(self, g: ArrayLike) -> tuple[np.ndarray, np.ndarray, bool]:
        """(beta (with SRP x0), covariance, determined) for scale factors g."""
        g = np.asarray(g, dtype=np.float64)
        return self._solve_system(g, self._beta_system(g))

    def _solve_system(self, g: np.ndarray, system: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
                      ) -> tuple[np.ndarray, np.ndarray, bool]:
        """:meth:`solve` of the :meth:`_beta_system` ``system`` at g."""
        info, vec, _, _ = system
        beta, cov, full = solve_information(info, vec)
        if full and not self.determined:
            n_d = self.model.n_d
            _, a_x = self.model.combination(np.asarray(g, dtype=np.float64))
            eiv_d = (a_x.T @ self.eiv_full @ a_x)[:n_d, :n_d]
            fluctuation = math.sqrt(2.0 * max(self.n_eiv, 1)) * np.diag(eiv_d)
            scale = np.sqrt(fluctuation)
            largest = float(np.linalg.eigvalsh(cov[:n_d, :n_d] * scale[:, None] * scale[None, :])[-1])
            self.determined = largest > 0.0 and 1.0 / largest > self.options.determination_margin
        return beta, cov, full and self.determined

    def jacobian(self, g: ArrayLike) -> np.ndarray:
        """(n_d, n_g) dd^/dG at scale factors g."""
        g = np.asarray(g, dtype=np.float64)
        system = self._beta_system(g)
        beta, cov, _ = solve_information(system[0], system[1])
        return self._jacobian(system, beta, cov, self.corrected_information())

    def _jacobian(self, system: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], beta: np.ndarray,
                  cov: np.ndarray, info_all: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` from the :meth:`_beta_system` ``system`` at g, its solution (``beta``, ``cov``) and
        :meth:`corrected_information` (computed once by :meth:`estimate`)."""
        model = self.model
        n_d = model.n_d
        _, _, a_xx, a_yy = system
        # dA_x/dG_j is a selection E_j (ones at rows col_xj[j], columns :n_d) and da_y/dG_j the unit vector e_j
        # (data column j), so with M = I A_x and m = I a_y:
        #   d_info_j = E_j^T M + M^T E_j,   d_vec_j = E_j^T m + A_x^T I e_j
        # and d_info_j beta = E_j^T (M beta) + M[col_xj[j]]^T beta_d: slices of M and m, no dense E_j
        m_x = info_all @ a_xx
        m_y = info_all @ a_yy
        m_x_beta = m_x @ beta
        data_x = a_xx.T @ info_all[:, model.col_data]
        rhs = np.empty((beta.size, model.n_g))
        for j in range(model.n_g):
            rows = model.col_xj[j]
            # d_vec_j - d_info_j beta
            column = data_x[:, j] - m_x[rows].T @ beta[:n_d]
            column[:n_d] += m_y[rows] - m_x_beta[rows]
            rhs[:, j] = column
        return (cov @ rhs)[:n_d]

    def estimate(self, scale_factors: ScaleFactorEstimate | tuple[ArrayLike, ArrayLike]) -> ComOffsetEstimate:
        """Estimate of d for the given scale factors (their covariance is propagated).

        Parameters
        ----------
        scale_factors : ScaleFactorEstimate or (G, P_G)
            G of ``grs_ids`` in order (3 n_grs,) and its covariance.

        Returns
        -------
        ComOffsetEstimate
        """
        g, p_g = self._scale_factors(scale_factors)
        n_d = self.model.n_d
        nan = np.full((n_d, n_d), np.nan)
        if not np.all(np.isfinite(g)) or self.filter.n_updates == 0:
            return ComOffsetEstimate(self.grs_ids, np.full(n_d, np.nan), nan, nan, nan, False, self.t_last_s,
                                     self.filter.n_updates, float("nan"), self.validator.count_summary())
        # the (beta, x0) system at g, its solution and the corrected information: computed once here (they
        # are deterministic: the same numbers as computing each again where it is used)
        system = self._beta_system(g)
        beta, cov, ok = self._solve_system(g, system)
        if not ok:
            return ComOffsetEstimate(self.grs_ids, np.full(n_d, np.nan), nan, nan, nan, False, self.t_last_s,
                                     self.filter.n_updates, float("nan"), self.validator.count_summary())
        info_all = self.corrected_information()
        jac = self._jacobian(system, beta, cov, info_all)
        cov_noise = cov[:n_d, :n_d]
        cov_total = cov_noise + jac @ p_g @ jac.T
        info, _, a_xx, a_yy = system
        g_joint = cov_gd = cov_gg = None
        n_g = self.model.n_g
        if self.options.joint and np.all(np.isfinite(p_g)) and np.all(np.linalg.eigvalsh(p_g) > 0.0):
            joint = solve_joint(self.model, info_all, g, p_g, beta)
            beta = joint.beta
            g_joint = joint.g
            cov_total = joint.covariance[n_g:n_g + n_d, n_g:n_g + n_d]
            cov_gd = joint.covariance[n_g:n_g + n_d, :n_g].copy()
            cov_gg = joint.covariance[:n_g, :n_g].copy()
            _, _, a_xx, a_yy = self._beta_system(g_joint)
        w = a_yy - a_xx @ beta
        chi2 = float(w @ self.filter.info @ w)
        dof = max(self.filter.dof_total - info.shape[0], 1)
        rejected = self.validator.count_summary()
        if self.filter.n_rejected:
            rejected.setdefault("epoch", {})["gated"] = self.filter.n_rejected
        return ComOffsetEstimate(self.grs_ids, beta[:n_d].copy(), 0.5 * (cov_total + cov_total.T), cov_noise,
                                 jac, True, self.t_last_s, self.filter.n_updates, chi2 / dof, rejected,
                                 scale_factors_joint=g_joint, scale_factor_cross_covariance=cov_gd,
                                 scale_factor_covariance_joint=cov_gg,
                                 nis_band=float("nan") if self.band_noise is None else self.band_noise.nis,
                                 noise_adjusted=bool(np.any(self.model.r_adjustment)))

    def _scale_factors(self, scale_factors: ScaleFactorEstimate | tuple[ArrayLike, ArrayLike]
                       ) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(scale_factors, ScaleFactorEstimate):
            values, covs = [], []
            for g in self.grs_ids:
                v, c = scale_factors.of(g)
                values.append(v)
                covs.append(c)
            g_all = np.concatenate(values)
            p = np.zeros((3 * len(self.grs_ids),) * 2)
            idx = [scale_factors.grs_ids.index(g) for g in self.grs_ids]
            for a, ia in enumerate(idx):
                for b, ib in enumerate(idx):
                    p[3 * a:3 * a + 3, 3 * b:3 * b + 3] = scale_factors.covariance[3 * ia:3 * ia + 3, 3 * ib:3 * ib + 3]
            return g_all, p
        g_all = np.asarray(scale_factors[0], dtype=np.float64).reshape(-1)
        return g_all, np.asarray(scale_factors[1], dtype=np.float64).reshape(g_all.size, g_all.size)

    def _engine_theta(self, g: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """Engine parameters (columns, x0) whose innovation combination is the residual at (g, beta)."""
        model = self.model
        theta = np.zeros(self.filter.q_total)
        theta[model.col_data] = -g
        theta[model.col_x0] = beta[:model.n_beta]
        for j in range(model.n_g):
            theta[model.col_xj[j]] = g[j] * beta[:model.n_d]
        theta[model.n_columns:] = beta[model.n_beta:]
        return theta

    def _span_gate_estimate(self, index: int, g: np.ndarray | None) -> GateEstimate | None:
        """The gate's estimate for the epoch at grid ``index`` at scale factors g (None: no gate): that of
        the data before the first epoch of its span (core/gate_span.py), solved once per span and G."""
        span = self.gate_span
        if span.starts(index, self.filter.n_segments):
            span.take(self.corrected_information() if self.filter.n_updates else None)
        if g is None or span.information is None or not np.all(np.isfinite(g)):
            return None
        key = g.tobytes()
        if span.solved is None or span.solved[0] != key:
            span.solved = (key, self._gate_estimate(g, span.information))
        return span.solved[1]

    def _gate_estimate(self, g: np.ndarray, info_all: np.ndarray) -> GateEstimate | None:
        """The estimate from the corrected information ``info_all`` at scale factors g, for the gate
        (None: not determined).

        Once determined, by a Cholesky factor of the (beta, x0) information where its eigenvalues certainly
        determine every direction (core/gate_estimate.py: the same algebra as :meth:`solve`'s
        eigen-decomposition at a fraction of its cost); :meth:`solve`'s algebra otherwise."""
        g = np.asarray(g, dtype=np.float64)
        system = self._beta_system(g, info_all)
        if self.determined:
            info, vec, a_xx, _ = system
            solved = gate_estimate(info, vec, MIN_EIGENVALUE_RATIO)
            if solved is not None:
                beta, factor, scale = solved
                return GateEstimate(self._engine_theta(g, beta), factor, scale, a_xx)
        beta, cov, ok = self._solve_system(g, system)
        if not ok:
            return None
        return GateEstimate.from_covariance(self._engine_theta(g, beta), cov, system[2])

    # per-sample path -------------------------------------------------------------------------
    def _epoch_noise(self, present: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
        """(rows, R override, EIV correction) of an epoch with the GRS ``present`` ((n_grs,) bool)."""
        if np.all(present):
            return None, None, self.eiv_full
        model = self.model
        # the same for every epoch with these GRS (and this model): built once, ~1 ms with the dense basis
        key = (id(model), present.tobytes())
        cached = self._noise_cache.get(key)
        if cached is not None:
            return cached[1]
        rows = np.repeat(present, 3)
        grs = self.grs_ids[int(np.flatnonzero(present)[0])]
        r = model.r_single[grs]
        # weight of the EIV term: R^-1 of the rows present (the common-mode state term is negligible)
        eiv = model.eiv_correction(np.linalg.inv(r[np.ix_(rows, rows)]), present)
        self._noise_cache[key] = (model, (rows, r, eiv))  # the model is held so its id stays unique
        return rows, r, eiv

    def _tau(self, t_s: float) -> float:
        return (float(t_s) - float(self.t0_s)) / self.options.trend_time_scale_s  # type: ignore[arg-type]

    def start_new_segment(self) -> None:
        """The next epoch starts a new segment (diffuse state): its data need not continue the dynamics
        of the epochs before (a restarted source). The information on d is kept."""
        if not self.filter.fresh:
            self.filter.reset_segment()

    def update(self, t_s: float, voltages: Mapping[int, ArrayLike] | None, omega_rad_s: ArrayLike | None = None,
               scale_factors: ScaleFactorEstimate | tuple[ArrayLike, ArrayLike] | None = None
               ) -> ComOffsetStepReport:
        """Process one epoch of GRS voltages.

        Parameters
        ----------
        t_s : float
            Stamp [s].
        voltages : mapping of int to array_like
            GRS id to (6,) voltages [V] (absent: missing).
        omega_rad_s : array_like, optional
            (3,) body rate in CRF [rad/s] (None: zero; it enters only the small centripetal term).
        scale_factors : ScaleFactorEstimate or (G, P_G), optional
            Current scale factors, for the pre-fit NIS and gating (None: no NIS, no gating).

        Returns
        -------
        ComOffsetStepReport
        """
        rejections: list[tuple[str, str]] = []
        model = self.model
        sums = np.zeros((1, model.n_grs, 3))
        diffs = np.zeros((1, model.n_grs, 3))
        rows = np.zeros(model.m, dtype=bool)
        for gid, v in (voltages or {}).items():
            check = self.validator.check_grs(t_s, int(gid), v)
            if not check.ok:
                rejections.append((f"grs{gid}", str(check.reason)))
                continue
            i = self.grs_ids.index(int(gid))
            sums[0, i] = linear_sums(check.value)
            diffs[0, i] = angular_differences(check.value)
            rows[3 * i:3 * i + 3] = True
        if not np.any(rows):
            return ComOffsetStepReport(float(t_s), float("nan"), False, tuple(rejections))
        if self.t0_s is None:
            self.t0_s = float(t_s)
        index = round((float(t_s) - self.t0_s) * self.instrument.sample_rate_hz)
        if self.last_index is not None and index <= self.last_index:
            rejections.append(("epoch", "out_of_order_stamp"))
            return ComOffsetStepReport(float(t_s), float("nan"), False, tuple(rejections))
        if self.last_index is not None:
            for _ in range(index - self.last_index - 1):
                self.filter.step(None)
        self.last_index = index
        self.t_last_s = float(t_s)
        omega = np.zeros((1, 3)) if omega_rad_s is None else np.asarray(omega_rad_s, dtype=np.float64).reshape(1, 3)
        if not np.all(np.isfinite(omega)):
            omega = np.zeros((1, 3))
        present = rows[0::3].copy()
        if present.all():  # the usual epoch: the factored form, ~45x faster than the dense assembly
            basis = model.basis_one(sums[0], diffs[0], omega[0], self._tau(t_s))
        else:
            basis = model.basis(sums, diffs, omega, np.array([self._tau(t_s)]), present[None, :])[0]
        g = None if scale_factors is None else self._scale_factors(scale_factors)[0]
        estimate = self._span_gate_estimate(index, g)
        sel, r_step, eiv = self._epoch_noise(present)
        info = self.filter.step(np.zeros(model.m), basis, rows=sel, r=r_step,
                                gate=self.gate if estimate is not None else None, estimate=estimate)
        if info.accepted:
            self.eiv_sum += eiv
            self.n_eiv += 1
        else:
            rejections.append(("epoch", "gated"))
        return ComOffsetStepReport(float(t_s), info.nis, info.accepted, tuple(rejections))

    # bulk path ----------------------------------------------------------------------------------
    def process_batch(self, t_s: ArrayLike, voltages_v: ArrayLike, omega_rad_s: ArrayLike | None,
                      scale_factors: ScaleFactorEstimate | tuple[ArrayLike, ArrayLike]) -> ComOffsetEstimate:
        """Process a whole record in bulk.

        Parameters
        ----------
        t_s : array_like
            (n,) stamps [s].
        voltages_v : array_like
            (n, n_grs, 6) voltages of ``grs_ids`` in order [V] (NaN rows: missing).
        omega_rad_s : array_like or None
            (n, 3) body rate at the same stamps, CRF [rad/s] (NaN rows or None: zero).
        scale_factors : ScaleFactorEstimate or (G, P_G)
            Final scale factors (used for the NIS/gating pass and the estimate).

        Returns
        -------
        ComOffsetEstimate
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        omega_all = np.zeros((t.size, 3)) if omega_rad_s is None else np.asarray(omega_rad_s, dtype=np.float64)
        omega_all = np.where(np.isfinite(omega_all), omega_all, 0.0)
        if self.filter.n_updates:
            raise RuntimeError("process_batch runs on a fresh estimator (use update() to continue)")
        checked = validate_batch(t, np.full((t.size, 4), np.nan), volts, self.validator.options, self.grs_ids)
        for stream, counts in checked.counts.items():
            if stream == "star_tracker":
                continue
            for reason, number in counts.items():
                self.validator.counts.setdefault(stream, Counter())[reason] += number
        epochs = EpochArrays.build(checked, t, volts)
        if epochs.count == 0:
            return self.estimate(scale_factors)
        rows_in = np.flatnonzero((checked.grid_index >= 0) & np.any(checked.grs_ok, axis=1))
        omega = omega_all[rows_in]
        self.t0_s = float(epochs.t[0])
        tau = (epochs.t - self.t0_s) / self.options.trend_time_scale_s
        g, _ = self._scale_factors(scale_factors)
        initial = copy.deepcopy(self.filter)
        whitened = self._accumulate(initial, epochs, omega, tau, g)
        block = max(1, round(BLOCK_S * self.instrument.sample_rate_hz))
        self.band_noise = None if whitened is None else band_noise(whitened, block)
        current = self.band_noise
        for _ in range(_NOISE_ITERATIONS if self.options.adapt_noise else 0):
            if current is None or not current.significant:
                break
            # the noise in the band that carries d differs from the model: estimate again with R
            # changed to whiten that band (noise_level.py), so weights and covariance follow the data.
            # Repeated: a filter with too small an R lets its SRP state take up part of the excess, so
            # one measurement sees only part of it (2-3 passes for a force noise at 2x PSD).
            adjustment = self.model.r_adjustment + r_adjustment(whitening(initial), current.covariance)
            self.model = ComOffsetModel(self.instrument, self.grs_ids, self.options, adjustment)
            initial = TwoStageFilter(self.model.state_space, self.model.n_columns, self.options.snap_tolerance)
            self.eiv_full = self.model.eiv_correction(initial.lambda_inv_ss)
            whitened = self._accumulate(initial, epochs, omega, tau, g)
            current = None if whitened is None else band_noise(whitened, block)
        self.last_index = int(epochs.index[-1])
        self.t_last_s = float(epochs.t[-1])
        return self.estimate(scale_factors)

    def _accumulate(self, initial: TwoStageFilter, epochs: EpochArrays, omega: np.ndarray, tau: np.ndarray,
                    g: np.ndarray) -> np.ndarray | None:
        """Accumulate the record from ``initial`` with the chi-square gate (a second pass without the
        flagged epochs); returns the whitened post-fit innovations of the accepted solution (NaN
        where not a regular epoch), or None when not evaluated."""
        gated = np.zeros(epochs.count, dtype=bool)
        whitened = None
        for attempt in range(2):
            self.filter = copy.deepcopy(initial)
            self.eiv_sum = np.zeros_like(self.eiv_full)
            self.n_eiv = 0
            self.determined = False
            self._drive(epochs, omega, tau, gated)
            whitened = None
            if not np.all(np.isfinite(g)):
                break
            beta, _, ok = self.solve(g)
            if not ok:
                break
            nis, whitened = self._evaluate(initial, epochs, omega, tau, gated, g, beta)
            if self.gate is None or attempt == 1:
                break
            new = (nis > self.gate) & ~gated
            if not np.any(new):
                break
            gated |= new
        self.filter.n_rejected = int(np.count_nonzero(gated))
        return whitened

    def _drive(self, epochs: EpochArrays, omega: np.ndarray, tau: np.ndarray, gated: np.ndarray,
               evaluate: tuple[np.ndarray, np.ndarray] | None = None, nis: np.ndarray | None = None,
               innovations: np.ndarray | None = None) -> None:
        """Run the filter over the epochs: accumulate, or (``evaluate = (g, beta)``) record post-fit NIS."""
        model = self.model
        theta = None if evaluate is None else evaluate
        usable = np.any(epochs.grs_ok, axis=1) & ~gated
        full = np.all(epochs.grs_ok, axis=1) & ~gated
        if self.model.n_grs == 1:
            full = usable
        k = 0
        count = epochs.count
        zeros = np.zeros(model.m)
        # run_end[k]: one past the last epoch of the run of full, consecutive epochs that starts at k
        continues = np.zeros(count, dtype=bool)
        continues[:-1] = full[:-1] & full[1:] & (np.diff(epochs.index) == 1)
        breaks = np.flatnonzero(~continues)
        run_end = breaks[np.searchsorted(breaks, np.arange(count))] + 1
        while k < count:
            if k > 0:
                for _ in range(int(epochs.index[k] - epochs.index[k - 1] - 1)):
                    self.filter.step(None)
            if full[k]:  # a run of regular epochs (run_regular also takes the transient after an irregular one)
                stop = int(run_end[k])
                start = k
                chunk = 32768
                while start < stop:
                    end = min(start + chunk, stop)
                    if theta is None:
                        basis = model.basis_factors(epochs.sums[start:end], epochs.diffs[start:end],
                                                    omega[start:end], tau[start:end])
                        self.filter.run_regular(np.zeros((end - start, model.m)), basis)
                        self.eiv_sum += (end - start) * self.eiv_full
                        self.n_eiv += end - start
                    else:
                        y_eval = model.residual(epochs.sums[start:end], epochs.diffs[start:end], omega[start:end],
                                                tau[start:end], evaluate[0], evaluate[1])
                        out = self.filter.run_regular(y_eval, want_innovations=innovations is not None)
                        nis[start:end] = out.nis  # type: ignore[index]
                        if innovations is not None and out.innovations is not None:
                            innovations[start:end] = out.innovations
                    start = end
                k = stop
                continue
            if usable[k]:
                present = epochs.grs_ok[k]
                sel, r_step, eiv = self._epoch_noise(present)
                if theta is None:
                    basis = model.basis(epochs.sums[k:k + 1], epochs.diffs[k:k + 1], omega[k:k + 1],
                                        tau[k:k + 1], present[None, :])[0]
                    self.filter.step(zeros, basis, rows=sel, r=r_step)
                    self.eiv_sum += eiv
                    self.n_eiv += 1
                else:
                    y_eval = model.residual(epochs.sums[k:k + 1], epochs.diffs[k:k + 1], omega[k:k + 1],
                                            tau[k:k + 1], evaluate[0], evaluate[1], present[None, :])[0]
                    result = self.filter.step(y_eval, rows=sel, r=r_step)
                    nis[k] = result.post_nis  # type: ignore[index]
            else:
                self.filter.step(None)
            k += 1

    def _evaluate(self, initial: TwoStageFilter, epochs: EpochArrays, omega: np.ndarray, tau: np.ndarray,
                  gated: np.ndarray, g: np.ndarray, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(post-fit NIS (L,), whitened post-fit innovations (L, m), NaN rows where not regular)."""
        saved = self.filter
        self.filter = initial.evaluation_copy(self._engine_theta(g, beta))
        nis = np.zeros(epochs.count)
        innovations = np.full((epochs.count, self.model.m), np.nan)
        self._drive(epochs, omega, tau, gated, (g, beta), nis, innovations)
        self.filter = saved
        return nis, innovations @ whitening(initial).T

    # checkpoint ---------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Checkpoint (plain lists/numbers)."""
        return {"method": self.method, "grs_ids": list(self.grs_ids), "filter": self.filter.state_dict(),
                "validator": self.validator.state_dict(), "eiv_sum": self.eiv_sum.tolist(), "n_eiv": self.n_eiv,
                "t0_s": self.t0_s, "t_last_s": self.t_last_s, "last_index": self.last_index,
                "determined": self.determined, "gate_span": self.gate_span.state_dict()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Resume from a :meth:`state_dict` checkpoint."""
        if tuple(state["grs_ids"]) != self.grs_ids or state["method"] != self.method:
            raise ValueError("checkpoint of a different estimator configuration")
        self.filter.load_state_dict(state["filter"])
        self.validator.load_state_dict(state["validator"])
        self.eiv_sum = np.asarray(state["eiv_sum"], dtype=np.float64)
        self.n_eiv = int(state["n_eiv"])
        self.t0_s = state["t0_s"]
        self.t_last_s = float(state["t_last_s"])
        self.last_index = state["last_index"]
        self.determined = bool(state["determined"])
        if "gate_span" in state:  # checkpoints before the gate's spans: a snapshot at the next epoch
            self.gate_span.load_state_dict(state["gate_span"])

    @classmethod
    def from_state_dict(cls, instrument: InstrumentModel, state: Mapping[str, Any],
                        options: ComOffsetOptions | None = None) -> ComOffsetEstimator:
        """New estimator resumed from a checkpoint."""
        est = cls(instrument, tuple(state["grs_ids"]), options)
        est.load_state_dict(state)
        return est
