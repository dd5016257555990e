"""Options, noise model and basis of series of the default (``gls``) c.m.-offset estimator.

Per epoch and GRS i, in CRF::

    z_i = C_i^T a_lin,i = A~(omega_dot, omega) d_i + a_SC + n_i,

A~ from the *calibrated GRS* angular acceleration, ``a_SC`` common to both GRS (white thruster
noise in R, SRP an AR(1) state), bias and trend per GRS as regression parameters, the noise of
omega_dot^ as ``[d_i x] e`` (errors in variables). Data and regressors are linear in G: the filter
runs on a basis of series (:class:`ComOffsetModel`) and accumulates their full cross-product.
Equations: docs/estimators.md, section 5.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.factored_steady import RegressorFactors
from taiji2_estimator_pkg.core.instrument import LINEAR_FROM_ANGULAR, InstrumentModel
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorModel
from taiji2_estimator_pkg.core.twostage import StateSpaceModel
from taiji2_estimator_pkg.core.validation import ValidationOptions

# linear axis read through each angular scale factor: G_Pphi -> y, G_Ptheta -> z, G_Ppsi -> x
_LINEAR_AXIS_OF_ANGULAR = {j: LINEAR_FROM_ANGULAR.index(j) for j in range(3)}


def cross_matrix(v: ArrayLike) -> np.ndarray:
    """``[v x]`` of (..., 3) vectors: (..., 3, 3) with ``[v x] w = v x w``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


@dataclass(frozen=True)
class ComOffsetOptions:
    """Options of the default (``gls``) c.m.-offset estimator.

    Attributes
    ----------
    detrend : str
        Per-GRS nuisance regression: ``"linear"`` (bias and trend, the paper's Gamma t + Lambda),
        ``"constant"`` (bias only) or ``"none"``.
    joint : bool
        Estimate d jointly with G from every channel (:mod:`.joint_com_offset`, default; reaches the
        full bound), or the two-stage ``d(G^)`` with ``P_d|G + J P_G J^T`` (False).
    trend_time_scale_s : float
        Time unit of the trend regressor [s] (conditioning only).
    gate_probability : float or None
        False-alarm probability of the chi-square gate per epoch (None: no gating).
    gate_refresh_s : float
        Per-sample path: the gate tests each epoch against the estimate of the data before the first
        epoch of its span of this much data time, solved once per span (:mod:`.gate_span`) [s]; at most
        one sample period: a solve at every epoch.
    snap_tolerance : float
        Relative distance at which the filter covariance is set back to its steady state.
    determination_margin : float
        Publish once the information on d exceeds this multiple of the statistical fluctuation of
        the errors-in-variables correction.
    adapt_noise : bool
        Bulk path: measure the noise of the linear channels in the band that carries d from the
        post-fit innovations and, where it departs from the model beyond its scatter, estimate
        again with R changed accordingly (:mod:`.noise_level`).
    validation : ValidationOptions
        Input checks.
    """

    detrend: str = "linear"
    joint: bool = True
    trend_time_scale_s: float = 1000.0
    gate_probability: float | None = 1e-6
    gate_refresh_s: float = 1.0
    snap_tolerance: float = 1e-10
    determination_margin: float = 20.0
    adapt_noise: bool = True
    validation: ValidationOptions = field(default_factory=ValidationOptions)

    def __post_init__(self) -> None:
        if self.detrend not in ("linear", "constant", "none"):
            raise ValueError(f"detrend: 'linear', 'constant' or 'none', got {self.detrend!r}")
        if not (self.gate_refresh_s >= 0.0 and math.isfinite(self.gate_refresh_s)):
            raise ValueError(f"gate_refresh_s: a finite time >= 0 [s], got {self.gate_refresh_s!r}")


class ComOffsetModel:
    """Noise model, SRP filter and the basis of series of the default c.m.-offset estimator.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal d (errors-in-variables noise) and noise budget.
    grs_ids : sequence of int
        One or two GRS (their angular readouts are fused for omega_dot, their linear readouts are
        the measurements).
    options : ComOffsetOptions
        Nuisance model.
    """

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int], options: ComOffsetOptions,
                 r_adjustment: np.ndarray | None = None) -> None:
        self.instrument = instrument
        self.grs_ids = tuple(int(g) for g in grs_ids)
        self.options = options
        n_grs = len(self.grs_ids)
        self.n_grs = n_grs
        self.m = 3 * n_grs
        self.angular = ScaleFactorModel(instrument, self.grs_ids)  # fusion weights, Q_f
        self.c = {g: instrument.c(g) for g in self.grs_ids}
        noise = instrument.noise
        thruster = np.diag(noise.thruster_acceleration_variance())
        q_fused = self.angular.q_fused
        d_nom = [instrument.nominal_com_offsets[g] for g in self.grs_ids]
        r = np.zeros((self.m, self.m))
        for a in range(n_grs):
            for b in range(n_grs):
                block = thruster + cross_matrix(d_nom[a]) @ q_fused @ cross_matrix(d_nom[b]).T
                if a == b:
                    block = block + instrument.linear_noise_crf(self.grs_ids[a])
                r[3 * a:3 * a + 3, 3 * b:3 * b + 3] = block
        # r_adjustment: the change of R measured in the band that carries d (noise_level.py)
        self.r_adjustment = np.zeros((self.m, self.m)) if r_adjustment is None else np.asarray(r_adjustment)
        r = r + self.r_adjustment
        self.r = 0.5 * (r + r.T)
        # an epoch with only GRS i: omega_dot from GRS i alone (errors-in-variables noise Q_i)
        self.q_single = {g: instrument.angular_noise_crf(g) for g in self.grs_ids}
        self.r_single = {}
        for a, g in enumerate(self.grs_ids):
            r_g = self.r.copy()
            e_block = cross_matrix(d_nom[a]) @ self.q_single[g] @ cross_matrix(d_nom[a]).T
            r_g[3 * a:3 * a + 3, 3 * a:3 * a + 3] = (thruster + instrument.linear_noise_crf(g) + e_block
                                                     + self.r_adjustment[3 * a:3 * a + 3, 3 * a:3 * a + 3])
            self.r_single[g] = 0.5 * (r_g + r_g.T)
        h = np.vstack([np.eye(3)] * n_grs)
        srp = noise.srp_process()
        # state coordinates in which the steady-state filter decouples: eigenvectors of H^T R^-1 H
        info = h.T @ np.linalg.solve(self.r, h)
        _, rotation = np.linalg.eigh(0.5 * (info + info.T))
        self.state_rotation = rotation  # s_CRF = rotation s_model
        self.state_space = StateSpaceModel(
            f=srp.decay * np.eye(3), b=np.zeros((3, 1)), q=srp.innovation_variance * np.eye(3),
            h=h @ rotation, r=self.r, blocks=((0,), (1,), (2,)))
        # parameters beta: d (3 n), then per-GRS nuisance
        self.n_d = 3 * n_grs
        per_grs = {"linear": 6, "constant": 3, "none": 0}[options.detrend]
        self.n_nuisance = per_grs * n_grs
        self.n_beta = self.n_d + self.n_nuisance
        self.n_g = 3 * n_grs
        # basis columns: data bases (n_g) | X0 (n_beta) | X^(j) d-blocks (n_g * n_d) | data Jacobian (n_g)
        self.col_data = slice(0, self.n_g)
        self.col_x0 = slice(self.n_g, self.n_g + self.n_beta)
        self.col_xj = [slice(self.n_g + self.n_beta + j * self.n_d, self.n_g + self.n_beta + (j + 1) * self.n_d)
                       for j in range(self.n_g)]
        start = self.n_g + self.n_beta + self.n_g * self.n_d
        self.col_jac = slice(start, start + self.n_g)
        self.n_columns = start + self.n_g
        self.ratio = instrument.linear_ratio_m
        self.q_fused = q_fused
        # nominal G and d: the mean of dz/dG (joint estimator; see data_jacobian_patterns)
        self.g_nominal = np.concatenate([instrument.nominal_scale_factors[g] for g in self.grs_ids])
        self.d_nominal = [np.asarray(d, dtype=np.float64) for d in d_nom]
        # per-sample variance of each voltage-difference series u_ij [V^2] (angular readout / G^2)
        self.diff_variance = np.concatenate([noise.angular_readout_variance() for _ in self.grs_ids]) \
            / self.g_nominal ** 2
        self.data_jacobian_projections = self._data_jacobian_projections()

    def _data_jacobian_projections(self) -> list[tuple[int, np.ndarray]]:
        """Per scale factor G_j: (GRS index i, ``C_i^T e_a e_a^T C_i / G_j``), a the linear axis read through G_j.

        ``z_i = C_i^T diag(r G_i,perm) s_i``, so ``dz_i/dG_j = C_i^T e_a r s_i,a`` whose mean is
        ``C_i^T e_a e_a^T C_i (A~ d_i) / G_j``: the data column of G_j with its noise (the common
        spacecraft acceleration above all) replaced by the model's mean. The joint estimator uses
        this mean Jacobian (:mod:`.joint_com_offset`): the noise part would carry information on G
        through the noise level and the assumed linear/angular ratio r (second moments), which
        neither the bound nor real hardware supports. Evaluated at the nominal G and d (mm-level
        knowledge of d changes it by < 1e-2: efficiency, not consistency).
        """
        out = []
        for i, g in enumerate(self.grs_ids):
            c = self.c[g]
            for j in range(3):
                row = c[_LINEAR_AXIS_OF_ANGULAR[j]]
                out.append((i, np.outer(row, row) / self.g_nominal[3 * i + j]))
        return out

    # basis series ---------------------------------------------------------------------------
    def basis(self, sums: np.ndarray, diffs: np.ndarray, omega: np.ndarray, tau: np.ndarray,
              present: np.ndarray | None = None) -> np.ndarray:
        """Basis columns of L epochs: (L, m, n_columns).

        Parameters
        ----------
        sums : numpy.ndarray
            (L, n_grs, 3) voltage sums [V].
        diffs : numpy.ndarray
            (L, n_grs, 3) voltage differences U~ [V].
        omega : numpy.ndarray
            (L, 3) body rate, CRF [rad/s].
        tau : numpy.ndarray
            (L,) trend regressor (time since the reference over the trend time scale).
        present : numpy.ndarray, optional
            (L, n_grs) GRS present (default all): an epoch with one GRS takes omega_dot from it
            alone (weight I instead of the fusion weight).
        """
        length = sums.shape[0]
        out = np.zeros((length, self.m, self.n_columns))
        n_grs = self.n_grs
        # data bases: z_i = C_i^T diag(r G_lin) s_i = sum_j G_ij r C_i^T e_lin(j) s_i,lin(j)
        for i, g in enumerate(self.grs_ids):
            c_t = self.c[g].T
            for j in range(3):
                axis = _LINEAR_AXIS_OF_ANGULAR[j]
                out[:, 3 * i:3 * i + 3, 3 * i + j] = self.ratio * c_t[None, :, axis] * sums[:, i, axis, None]
        # X0: omega x (omega x d) blocks, then nuisance
        w2 = cross_matrix(omega)
        w2 = w2 @ w2
        base = self.n_g
        for i in range(n_grs):
            out[:, 3 * i:3 * i + 3, base + 3 * i:base + 3 * i + 3] = w2
        col = base + self.n_d
        if self.options.detrend in ("linear", "constant"):
            for i in range(n_grs):
                for a in range(3):
                    out[:, 3 * i + a, col + 3 * i + a] = 1.0
            col += 3 * n_grs
        if self.options.detrend == "linear":
            for i in range(n_grs):
                for a in range(3):
                    out[:, 3 * i + a, col + 3 * i + a] = tau
            col += 3 * n_grs
        # X^(ij): omega_dot^(ij) x d blocks, omega_dot^(ij) = W_i C_i^T e_j u_ij
        alone = None
        if present is not None and n_grs == 2:
            alone = np.all(present, axis=1)[:, None] | np.zeros((1, 1), dtype=bool)
        for i, g in enumerate(self.grs_ids):
            mapping = self.angular.weights[g] @ self.c[g].T
            single = self.c[g].T
            for j in range(3):
                omega_dot = mapping[None, :, j] * diffs[:, i, j, None]  # (L, 3)
                if alone is not None:
                    only = present[:, i] & ~alone[:, 0]
                    omega_dot = np.where(only[:, None], single[None, :, j] * diffs[:, i, j, None], omega_dot)
                    omega_dot = np.where(present[:, i, None], omega_dot, 0.0)
                block = cross_matrix(omega_dot)
                cols = self.col_xj[3 * i + j]
                for k in range(n_grs):
                    out[:, 3 * k:3 * k + 3, cols.start + 3 * k:cols.start + 3 * k + 3] = block
                for jj, (k, projection) in enumerate(self.data_jacobian_projections):
                    # g_s P_jj (omega_dot^(s) x d_k), the series' share of the mean of dz/dG_jj
                    out[:, 3 * k:3 * k + 3, self.col_jac.start + jj] += self.g_nominal[3 * i + j] * (
                        (block @ self.d_nominal[k]) @ projection.T)
        return out

    def basis_one(self, sums: np.ndarray, diffs: np.ndarray, omega: np.ndarray, tau: float) -> np.ndarray:
        """:meth:`basis` of one epoch with every GRS present, (m, n_columns): its :meth:`basis_factors`' scalar
        series times the constant patterns (built once), the per-epoch path of the running estimator (one
        matrix product instead of the dense assembly's Python loops; equal to :meth:`basis` to rounding).

        Parameters: ``sums``, ``diffs`` (n_grs, 3) [V]; ``omega`` (3,) [rad/s]; ``tau`` the trend regressor.
        """
        patterns = self.__dict__.get("_one_patterns")
        if patterns is None:
            zeros = np.zeros((1, self.n_grs, 3))
            factors = self.basis_factors(zeros, zeros, np.zeros((1, 3)), np.zeros(1))
            patterns = factors.patterns.reshape(factors.patterns.shape[0], -1)
            self.__dict__["_one_patterns"] = patterns
        series = [sums[i, _LINEAR_AXIS_OF_ANGULAR[j]] for i in range(self.n_grs) for j in range(3)]
        series += [omega[a] * omega[b] for a in range(3) for b in range(a, 3)]
        if self.options.detrend in ("linear", "constant"):
            series.append(1.0)
        if self.options.detrend == "linear":
            series.append(tau)
        series += [diffs[i, j] for i in range(self.n_grs) for j in range(3)]
        return (np.asarray(series) @ patterns).reshape(self.m, self.n_columns)

    def basis_factors(self, sums: np.ndarray, diffs: np.ndarray, omega: np.ndarray,
                      tau: np.ndarray) -> RegressorFactors:
        """The :meth:`basis` of L epochs with every GRS present, as scalar series times patterns.

        Every basis column is a scalar series times a constant vector: the voltage sums (data
        bases), the products ``omega_a omega_b`` (``[omega x]^2 = omega omega^T - |omega|^2 I``),
        1 and tau (nuisance), the voltage differences (``omega_dot^(ij) = W_i C_i^T e_j u_ij``).
        20 series for two GRS instead of 60 dense columns per measurement row.
        """
        length = sums.shape[0]
        n_grs, m = self.n_grs, self.m
        series: list[np.ndarray] = []
        patterns: list[np.ndarray] = []

        def add(values: np.ndarray) -> np.ndarray:
            series.append(np.broadcast_to(values, (length,)))
            patterns.append(np.zeros((m, self.n_columns)))
            return patterns[-1]

        for i, g in enumerate(self.grs_ids):
            c_t = self.c[g].T
            for j in range(3):
                axis = _LINEAR_AXIS_OF_ANGULAR[j]
                add(sums[:, i, axis])[3 * i:3 * i + 3, 3 * i + j] = self.ratio * c_t[:, axis]
        base = self.n_g
        eye = np.eye(3)
        for a in range(3):
            for b in range(a, 3):
                block = eye[a][:, None] * eye[b][None, :]
                block = block - eye if a == b else block + block.T
                pattern = add(omega[:, a] * omega[:, b])
                for i in range(n_grs):
                    pattern[3 * i:3 * i + 3, base + 3 * i:base + 3 * i + 3] = block
        col = base + self.n_d
        if self.options.detrend in ("linear", "constant"):
            pattern = add(np.ones(length))
            pattern[np.arange(m), col + np.arange(m)] = 1.0
            col += m
        if self.options.detrend == "linear":
            pattern = add(tau)
            pattern[np.arange(m), col + np.arange(m)] = 1.0
            col += m
        for i, g in enumerate(self.grs_ids):
            mapping = self.angular.weights[g] @ self.c[g].T
            for j in range(3):
                block = cross_matrix(mapping[:, j])
                pattern = add(diffs[:, i, j])
                cols = self.col_xj[3 * i + j]
                for k in range(n_grs):
                    pattern[3 * k:3 * k + 3, cols.start + 3 * k:cols.start + 3 * k + 3] = block
                for jj, (k, projection) in enumerate(self.data_jacobian_projections):
                    pattern[3 * k:3 * k + 3, self.col_jac.start + jj] += self.g_nominal[3 * i + j] * (
                        projection @ block @ self.d_nominal[k])
        return RegressorFactors(np.column_stack(series), np.stack(patterns))

    def residual(self, sums: np.ndarray, diffs: np.ndarray, omega: np.ndarray, tau: np.ndarray, g: np.ndarray,
                 beta: np.ndarray, present: np.ndarray | None = None) -> np.ndarray:
        """``z(g) - X(g) beta`` of L epochs, (L, m) (same as the basis combination, computed directly)."""
        length = sums.shape[0]
        omega_dot = np.zeros((length, 3))
        z = np.zeros((length, self.m))
        both = np.ones(length, dtype=bool) if present is None else np.all(present, axis=1)
        for i, grs in enumerate(self.grs_ids):
            gi = g[3 * i:3 * i + 3]
            mine = np.ones(length, dtype=bool) if present is None else present[:, i]
            fused = (diffs[:, i, :] * gi[None, :]) @ (self.angular.weights[grs] @ self.c[grs].T).T
            alone = (diffs[:, i, :] * gi[None, :]) @ self.c[grs]
            omega_dot += np.where((mine & both)[:, None], fused, np.where(mine[:, None], alone, 0.0))
            lin = self.ratio * gi[list(LINEAR_FROM_ANGULAR)]
            z[:, 3 * i:3 * i + 3] = (sums[:, i, :] * lin[None, :]) @ self.c[grs]
        col = self.n_d
        for i in range(self.n_grs):
            rows = slice(3 * i, 3 * i + 3)
            # A~ d = omega_dot x d + omega x (omega x d), A~ = [omega_dot x] + [omega x]^2
            d = np.broadcast_to(beta[3 * i:3 * i + 3], omega.shape)
            z[:, rows] -= np.cross(omega_dot, d) + np.cross(omega, np.cross(omega, d))
            if self.options.detrend in ("linear", "constant"):
                z[:, rows] -= beta[col + 3 * i:col + 3 * i + 3][None, :]
        if self.options.detrend in ("linear", "constant"):
            col += 3 * self.n_grs
        if self.options.detrend == "linear":
            for i in range(self.n_grs):
                z[:, 3 * i:3 * i + 3] -= tau[:, None] * beta[col + 3 * i:col + 3 * i + 3][None, :]
        return z

    def combination(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Column combinations for scale factors g.

        Returns
        -------
        a_y : numpy.ndarray
            (n_columns,) coefficients giving the data ``z(g)``.
        a_x : numpy.ndarray
            (n_columns, n_beta) coefficients giving the regressor ``X(g)``.
        """
        a_y = np.zeros(self.n_columns)
        a_y[self.col_data] = g
        a_x = np.zeros((self.n_columns, self.n_beta))
        a_x[self.col_x0, :] = np.eye(self.n_beta)
        for j in range(self.n_g):
            a_x[self.col_xj[j], :self.n_d] = g[j] * np.eye(self.n_d)
        return a_y, a_x

    def eiv_correction(self, lambda_inv: np.ndarray, present: np.ndarray | None = None) -> np.ndarray:
        """(n_columns, n_columns) ``E[B_e^T Lambda^-1 B_e]`` of one epoch: the readout noise of the
        voltage differences in the basis columns (errors in variables).

        The columns built from the voltage differences (the ``omega_dot^`` regressors and the data
        Jacobian) carry its white noise ``n_s`` (variance :attr:`diff_variance`), so their
        cross-products are inflated by ``sum_s var_s P_s^T Lambda^-1 P_s`` (``P_s`` the pattern of
        series s); subtracting it makes every normal matrix and score built from the columns
        unbiased (corrected least squares), whatever combination of G and d they are taken at.

        Parameters
        ----------
        lambda_inv : numpy.ndarray
            Inverse innovation covariance of the rows present [(m s^-2)^-2].
        present : numpy.ndarray, optional
            (n_grs,) GRS present (default all); ``lambda_inv`` is then over their rows.
        """
        present = np.ones(self.n_grs, dtype=bool) if present is None else np.asarray(present, dtype=bool)
        rows = np.repeat(present, 3)
        zeros = np.zeros((1, self.n_grs, 3))
        still = self.basis(zeros, zeros, np.zeros((1, 3)), np.zeros(1), present[None, :])[0]
        out = np.zeros((self.n_columns, self.n_columns))
        for s, variance in enumerate(self.diff_variance):
            if not present[s // 3]:
                continue
            unit = np.zeros((1, self.n_grs, 3))
            unit[0, s // 3, s % 3] = 1.0
            pattern = (self.basis(zeros, unit, np.zeros((1, 3)), np.zeros(1), present[None, :])[0] - still)[rows]
            out += variance * pattern.T @ lambda_inv @ pattern
        return 0.5 * (out + out.T)
