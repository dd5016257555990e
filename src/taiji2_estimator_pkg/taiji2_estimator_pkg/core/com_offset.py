"""Test-mass c.m. offsets d_i (CRF) from the GRS linear accelerations.

Two methods:

``paper`` (:class:`PaperComOffsetFilter`)
    The paper's filter: per GRS a 3-state Kalman filter (Phi = I, Q = 0, Joseph update) on the
    TMRF linear acceleration ``a_out = G_lin (v1 + v2)`` (scale factors from a scale-factor
    estimate), ``H = C_i A~`` with A~ from the star tracker's smoothed rate and acceleration, the
    same smoothing applied to a_out, and the paper's detrending (``Gamma t + Lambda``) done for
    regressor and data together (as extra diffuse states, which by Frisch-Waugh-Lovell is the same
    as detrending both sides). Diagonal R. Its covariance is too small (reported, not fixed).

``gls`` (:class:`ComOffsetEstimator`, default)
    Per epoch and GRS i, in CRF::

        z_i = C_i^T a_lin,i = A~(omega_dot, omega) d_i + a_SC + n_i,

    with A~ built from the *calibrated GRS* angular acceleration ``omega_dot^ = sum_i W_i C_i^T
    diag(u_i) G_i`` (far less noisy than the star tracker's) and omega from the attitude filter.
    ``a_SC`` is common to both GRS: white thruster noise (in R, fully correlated between the GRS)
    plus SRP, an AR(1) state of a Kalman filter; bias and trend per GRS are regression parameters
    (the paper's detrending, applied to regressor and data together by construction). The noise
    of omega_dot^ enters as ``[d_i x] e`` (errors in variables): it is in R (with the cross-GRS
    correlation), and its bias on the normal matrix is removed (corrected least squares). d_1, d_2
    are estimated jointly with their cross-covariance; d_1 - d_2 is reported with its covariance.

    Data and regressors are linear in the scale factors G, so the filter runs on a basis of series
    (one per component of G) and accumulates their full cross-product: d(G) and dd/dG are then
    exact for any G, which lets a node follow a running G estimate and still agree with the bulk
    result, and propagates the scale-factor covariance into d: ``P_d = P_d|G + J P_G J^T``.
"""

from __future__ import annotations

import copy
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .attitude import SmoothingDerivative
from .estimate_blocks import PerGrsBlocks
from .factored_steady import RegressorFactors
from .instrument import LINEAR_FROM_ANGULAR, InstrumentModel, angular_differences, linear_scale_factors, linear_sums
from .joint_com_offset import solve_joint
from .kalman import KalmanFilter, chi2_gate
from .noise_level import BandNoise, band_noise, r_adjustment
from .scale_factor import ScaleFactorEstimate, ScaleFactorModel, _EpochArrays
from .twostage import StateSpaceModel, TwoStageFilter, solve_information
from .validation import InputValidator, ValidationOptions, validate_batch

__all__ = [
    "ComOffsetEstimate",
    "ComOffsetEstimator",
    "ComOffsetModel",
    "ComOffsetOptions",
    "ComOffsetStepReport",
    "PaperComOffsetFilter",
    "PaperComOffsetOptions",
    "cross_matrix",
]

#: at most this many re-estimations with the measured band noise (noise_level.py)
_NOISE_ITERATIONS = 4

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


# ==============================================================================================
# Results and options
# ==============================================================================================


@dataclass
class ComOffsetEstimate(PerGrsBlocks):
    """c.m.-offset estimate of one or two GRS (CRF).

    Attributes
    ----------
    grs_ids : tuple of int
        GRS ids, in the order of the parameter vector.
    values : numpy.ndarray
        (3 n_grs,) d_i stacked [m].
    covariance : numpy.ndarray
        (3 n_grs, 3 n_grs) total covariance, scale-factor uncertainty included [m^2] (joint
        estimator: of the joint estimate; two-stage: ``P_d|G + J P_G J^T``).
    covariance_given_scale_factors : numpy.ndarray
        (3 n_grs, 3 n_grs) covariance if the scale factors were exact [m^2].
    scale_factor_jacobian : numpy.ndarray
        (3 n_grs, 3 n_grs) dd/dG [m / (rad s^-2 V^-1)].
    determined : bool
        False until the data determine d (values then NaN).
    t_s : float
        Last epoch [s].
    n_samples : int
        Epochs used.
    nis_mean : float
        Mean post-fit NIS per degree of freedom (1 if consistent).
    rejected : dict
        Rejected inputs per stream and reason.
    method : str
        ``"gls"`` or ``"paper"``.
    scale_factors_joint : numpy.ndarray or None
        (3 n_grs,) G re-estimated jointly with d (the linear channels' information added; joint
        estimator only) [rad s^-2 V^-1].
    scale_factor_cross_covariance : numpy.ndarray or None
        (3 n_grs, 3 n_grs) Cov(d, G joint) [m rad s^-2 V^-1].
    scale_factor_covariance_joint : numpy.ndarray or None
        (3 n_grs, 3 n_grs) Cov(G joint).
    nis_band : float
        NIS per dof of the linear channels in the band that carries d, before any adjustment
        (:mod:`.noise_level`; bulk path; NaN where not measured). 1 if the noise model holds there.
    noise_adjusted : bool
        Whether R was changed to the measured band noise (then the estimate and its covariance
        follow the data's noise level, not the budget's).
    """

    grs_ids: tuple[int, ...]
    values: np.ndarray
    covariance: np.ndarray
    covariance_given_scale_factors: np.ndarray
    scale_factor_jacobian: np.ndarray
    determined: bool
    t_s: float
    n_samples: int
    nis_mean: float
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    method: str = "gls"
    scale_factors_joint: np.ndarray | None = None
    scale_factor_cross_covariance: np.ndarray | None = None
    scale_factor_covariance_joint: np.ndarray | None = None
    nis_band: float = float("nan")
    noise_adjusted: bool = False


    def difference(self) -> tuple[np.ndarray, np.ndarray]:
        """(d_1 - d_2 (3,), covariance (3, 3)) [m], [m^2] (two GRS only)."""
        if len(self.grs_ids) != 2:
            raise ValueError("d_1 - d_2 needs two GRS")
        t = np.hstack((np.eye(3), -np.eye(3)))
        return t @ self.values, t @ self.covariance @ t.T

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/YAML, messages)."""
        out = {"grs_ids": list(self.grs_ids), "values": self.values.tolist(),
               "covariance": self.covariance.tolist(),
               "covariance_given_scale_factors": self.covariance_given_scale_factors.tolist(),
               "scale_factor_jacobian": self.scale_factor_jacobian.tolist(), "determined": self.determined,
               "t_s": self.t_s, "n_samples": self.n_samples, "nis_mean": self.nis_mean,
               "rejected": self.rejected, "method": self.method, "nis_band": self.nis_band,
               "noise_adjusted": self.noise_adjusted}
        for key in ("scale_factors_joint", "scale_factor_cross_covariance", "scale_factor_covariance_joint"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value.tolist()
        if len(self.grs_ids) == 2:
            diff, cov = self.difference()
            out["difference"] = diff.tolist()
            out["difference_covariance"] = cov.tolist()
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
    snap_tolerance: float = 1e-10
    determination_margin: float = 20.0
    adapt_noise: bool = True
    validation: ValidationOptions = field(default_factory=ValidationOptions)

    def __post_init__(self) -> None:
        if self.detrend not in ("linear", "constant", "none"):
            raise ValueError(f"detrend: 'linear', 'constant' or 'none', got {self.detrend!r}")


@dataclass(frozen=True)
class PaperComOffsetOptions:
    """Options of the paper's c.m.-offset filter.

    Attributes
    ----------
    window : int
        Savitzky-Golay window of the star-tracker rate and acceleration [samples] (odd).
    polyorder : int
        Savitzky-Golay order.
    initial_sigma_m : float
        Initial 1-sigma of each d component (initial state: the nominal d) [m].
    detrend_sigma : float
        Initial 1-sigma of the detrending states, bias [m s^-2] (trend: this per 1000 s); large,
        i.e. effectively diffuse.
    gate_probability : float or None
        Chi-square gate (None: none, as in the paper).
    validation : ValidationOptions
        Input checks.
    """

    window: int = 2001
    polyorder: int = 2
    initial_sigma_m: float = 0.01
    detrend_sigma: float = 1e-6
    gate_probability: float | None = None
    validation: ValidationOptions = field(default_factory=ValidationOptions)


# ==============================================================================================
# Model of the default method
# ==============================================================================================


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


# ==============================================================================================
# Default method
# ==============================================================================================


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

    # solution for given scale factors --------------------------------------------------------
    def corrected_information(self) -> np.ndarray:
        """(q, q) cross-product of the whitened basis columns (and SRP initial state), less the
        expected errors-in-variables part: unbiased for any combination of the columns."""
        info = self.filter.info.copy()
        n = self.model.n_columns
        info[:n, :n] -= self.eiv_sum
        return info

    def _beta_system(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Information and vector on (beta, x0) for scale factors g, with the EIV correction."""
        model = self.model
        q = self.filter.q_total
        info_all = self.corrected_information()
        a_y, a_x = model.combination(np.asarray(g, dtype=np.float64))
        # append the SRP initial-state columns (x0) of the engine
        a_xx = np.zeros((q, model.n_beta + 3))
        a_xx[:model.n_columns, :model.n_beta] = a_x
        a_xx[model.n_columns:, model.n_beta:] = np.eye(3)
        a_yy = np.zeros(q)
        a_yy[:model.n_columns] = a_y
        info = a_xx.T @ info_all @ a_xx
        vec = a_xx.T @ info_all @ a_yy
        return 0.5 * (info + info.T), vec, a_xx, a_yy

    def solve(self, g: ArrayLike) -> tuple[np.ndarray, np.ndarray, bool]:
        """(beta (with SRP x0), covariance, determined) for scale factors g."""
        info, vec, _, _ = self._beta_system(np.asarray(g, dtype=np.float64))
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
        model = self.model
        info, vec, a_xx, a_yy = self._beta_system(g)
        beta, cov, _ = solve_information(info, vec)
        info_all = self.corrected_information()
        jac = np.zeros((model.n_d, model.n_g))
        for j in range(model.n_g):
            da_x = np.zeros_like(a_xx)
            da_x[model.col_xj[j], :model.n_d] = np.eye(model.n_d)
            da_y = np.zeros_like(a_yy)
            da_y[j] = 1.0
            d_info = da_x.T @ info_all @ a_xx + a_xx.T @ info_all @ da_x
            d_vec = da_x.T @ info_all @ a_yy + a_xx.T @ info_all @ da_y
            jac[:, j] = (cov @ (d_vec - d_info @ beta))[:model.n_d]
        return jac

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
        beta, cov, ok = self.solve(g)
        if not ok:
            return ComOffsetEstimate(self.grs_ids, np.full(n_d, np.nan), nan, nan, nan, False, self.t_last_s,
                                     self.filter.n_updates, float("nan"), self.validator.count_summary())
        jac = self.jacobian(g)
        cov_noise = cov[:n_d, :n_d]
        cov_total = cov_noise + jac @ p_g @ jac.T
        info, _, a_xx, a_yy = self._beta_system(g)
        g_joint = cov_gd = cov_gg = None
        n_g = self.model.n_g
        if self.options.joint and np.all(np.isfinite(p_g)) and np.all(np.linalg.eigvalsh(p_g) > 0.0):
            joint = solve_joint(self.model, self.corrected_information(), g, p_g, beta)
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

    # per-sample path -------------------------------------------------------------------------
    def _epoch_noise(self, present: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
        """(rows, R override, EIV correction) of an epoch with the GRS ``present`` ((n_grs,) bool)."""
        if np.all(present):
            return None, None, self.eiv_full
        model = self.model
        rows = np.repeat(present, 3)
        grs = self.grs_ids[int(np.flatnonzero(present)[0])]
        r = model.r_single[grs]
        # weight of the EIV term: R^-1 of the rows present (the common-mode state term is negligible)
        eiv = model.eiv_correction(np.linalg.inv(r[np.ix_(rows, rows)]), present)
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
        basis = model.basis(sums, diffs, omega, np.array([self._tau(t_s)]), present[None, :])[0]
        estimate = None
        if scale_factors is not None:
            g, _ = self._scale_factors(scale_factors)
            if np.all(np.isfinite(g)) and self.filter.n_updates:
                beta, cov, ok = self.solve(g)
                if ok:
                    theta = self._engine_theta(g, beta)
                    _, _, a_xx, _ = self._beta_system(g)
                    estimate = (theta, a_xx @ cov @ a_xx.T)
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
        epochs = _EpochArrays.build(checked, t, volts)
        if epochs.count == 0:
            return self.estimate(scale_factors)
        rows_in = np.flatnonzero((checked.grid_index >= 0) & np.any(checked.grs_ok, axis=1))
        omega = omega_all[rows_in]
        self.t0_s = float(epochs.t[0])
        tau = (epochs.t - self.t0_s) / self.options.trend_time_scale_s
        g, _ = self._scale_factors(scale_factors)
        initial = copy.deepcopy(self.filter)
        whitened = self._accumulate(initial, epochs, omega, tau, g)
        self.band_noise = None if whitened is None else band_noise(whitened)
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
            current = None if whitened is None else band_noise(whitened)
        self.last_index = int(epochs.index[-1])
        self.t_last_s = float(epochs.t[-1])
        return self.estimate(scale_factors)

    def _accumulate(self, initial: TwoStageFilter, epochs: _EpochArrays, omega: np.ndarray, tau: np.ndarray,
                    g: np.ndarray, evaluate_last: bool = True) -> np.ndarray | None:
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
            if not np.all(np.isfinite(g)) or (attempt == 1 and not evaluate_last):
                break
            beta, _, ok = self.solve(g)
            if not ok or (self.gate is None and not evaluate_last):
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

    def _drive(self, epochs: _EpochArrays, omega: np.ndarray, tau: np.ndarray, gated: np.ndarray,
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

    def _evaluate(self, initial: TwoStageFilter, epochs: _EpochArrays, omega: np.ndarray, tau: np.ndarray,
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
                "determined": self.determined}

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

    @classmethod
    def from_state_dict(cls, instrument: InstrumentModel, state: Mapping[str, Any],
                        options: ComOffsetOptions | None = None) -> ComOffsetEstimator:
        """New estimator resumed from a checkpoint."""
        est = cls(instrument, tuple(state["grs_ids"]), options)
        est.load_state_dict(state)
        return est


# ==============================================================================================
# The paper's filter
# ==============================================================================================


class PaperComOffsetFilter:
    """The paper's c.m.-offset filter, per GRS (Phi = I, Q = 0, Joseph update, diagonal R).

    State ``X = (d (3, CRF), Lambda (3, TMRF bias), Gamma (3, TMRF trend))``; measurement the
    TMRF linear acceleration smoothed like the regressor; ``H = [C_i A~, I, t I]`` with A~ from the
    star tracker's Savitzky-Golay rate and acceleration. The detrending states start diffuse
    (``detrend_sigma``), which equals detrending data and regressor together. Bulk only (the
    smoothing needs the record; per-sample nodes use :meth:`process_batch` on a buffer or the
    default method).

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal d (initial state) and noise budget.
    grs_ids : sequence of int
        GRS to calibrate.
    options : PaperComOffsetOptions, optional
        Window, order, priors, gating.
    """

    method = "paper"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: PaperComOffsetOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or PaperComOffsetOptions()
        self.grs_ids = tuple(int(g) for g in grs_ids)
        self.smoother = SmoothingDerivative(self.options.window, self.options.polyorder, instrument.dt_s)
        noise = instrument.noise
        grs_gain = float(np.sum(self.smoother.grs_kernel() ** 2))
        thruster = noise.thruster_acceleration_variance()
        self.r = {}
        for g in self.grs_ids:
            c = instrument.c(g)
            tmrf = c @ np.diag(thruster) @ c.T
            self.r[g] = grs_gain * (np.diag(tmrf) + noise.linear_readout_variance())
        self.filters: dict[int, KalmanFilter] = {}
        self.validator = InputValidator(ValidationOptions(**{**self.options.validation.__dict__,
                                                             "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.history: dict[Any, Any] = {}
        self.nis_mean = float("nan")

    def process_batch(self, t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                      scale_factors: ScaleFactorEstimate | Mapping[int, ArrayLike],
                      history_every: int = 0) -> ComOffsetEstimate:
        """Run the paper's filter over a record (closed form of the Phi = I, Q = 0 recursion).

        Parameters
        ----------
        t_s, quat_xyzw, voltages_v : array_like
            (n,), (n, 4), (n, n_grs, 6).
        scale_factors : ScaleFactorEstimate or mapping of int to array_like
            Angular G per GRS (the linear ones are ``r`` times them); the paper uses its own
            scale-factor result.
        history_every : int
            Keep the running estimate every that many updates in :attr:`history`.

        Returns
        -------
        ComOffsetEstimate
            With the filter's own (paper) covariance; no scale-factor propagation.
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        checked = validate_batch(t, quat_xyzw, volts, self.validator.options, self.grs_ids)
        epochs = _EpochArrays.build(checked, t, volts)
        w = self.options.window
        m = self.smoother.half
        count = epochs.count
        n_d = 3 * len(self.grs_ids)
        values = np.full(n_d, np.nan)
        cov = np.full((n_d, n_d), np.nan)
        if count < w + 1:
            return ComOffsetEstimate(self.grs_ids, values, cov, cov, np.zeros((n_d, n_d)), False, float("nan"),
                                     0, float("nan"))
        # windows usable: contiguous, star tracker and all GRS present
        good_st = epochs.st_ok
        good_grs = np.all(epochs.grs_ok, axis=1)
        pairs = np.diff(epochs.index) == 1
        starts = np.arange(count - w + 1)
        cum_st = np.concatenate(([0], np.cumsum(good_st)))
        cum_grs = np.concatenate(([0], np.cumsum(good_grs)))
        cum_pairs = np.concatenate(([0], np.cumsum(pairs)))
        usable = ((cum_st[starts + w] - cum_st[starts]) == w) & \
                 ((cum_grs[starts + w] - cum_grs[starts + 1]) == w - 1) & \
                 ((cum_pairs[starts + w - 1] - cum_pairs[starts]) == w - 1)
        rate_k, acc_k, grs_k = self.smoother.rate_kernel(), self.smoother.acceleration_kernel(), \
            self.smoother.grs_kernel()
        omega = np.stack([np.correlate(epochs.phi[:, a], rate_k, mode="valid") for a in range(3)], axis=1)
        omega_dot = np.stack([np.correlate(epochs.phi[:, a], acc_k, mode="valid") for a in range(3)], axis=1)
        omega, omega_dot = omega[usable], omega_dot[usable]
        centre = (starts + m)[usable]
        t_c = epochs.t[centre]
        tau = (t_c - t_c[0]) / 1000.0 if t_c.size else t_c
        a_tilde = cross_matrix(omega_dot) + cross_matrix(omega) @ cross_matrix(omega)
        g_values = self._angular(scale_factors)
        self.history = {"t_s": t_c}
        out_vals, out_cov = [], []
        nis_terms = []
        for i, g in enumerate(self.grs_ids):
            lin_sf = linear_scale_factors(g_values[g], self.instrument.linear_ratio_m)
            a_out = epochs.sums[:, i, :] * lin_sf[None, :]  # TMRF
            smoothed = np.stack([np.correlate(a_out[1:, a], grs_k, mode="valid") for a in range(3)], axis=1)[usable]
            c = self.instrument.c(g)
            h = np.zeros((centre.size, 3, 9))
            h[:, :, 0:3] = c[None] @ a_tilde
            h[:, :, 3:6] = np.eye(3)[None]
            h[:, :, 6:9] = np.eye(3)[None] * tau[:, None, None]
            x0 = np.concatenate((self.instrument.nominal_com_offsets[g], np.zeros(6)))
            s = self.options.detrend_sigma
            p0 = np.diag(np.concatenate((np.full(3, self.options.initial_sigma_m**2), np.full(6, s * s))))
            r_inv = 1.0 / self.r[g]
            info_terms = np.einsum("kji,j,kjl->kil", h, r_inv, h)
            vec_terms = np.einsum("kji,j,kj->ki", h, r_inv, smoothed)
            p0_inv = np.linalg.inv(p0)
            info = p0_inv + info_terms.sum(axis=0)
            vec = p0_inv @ x0 + vec_terms.sum(axis=0)
            p_n = np.linalg.inv(info)
            x_n = p_n @ vec
            kf = KalmanFilter(x_n, 0.5 * (p_n + p_n.T))
            kf.n_updates = centre.size
            self.filters[g] = kf
            resid = smoothed - np.einsum("kij,j->ki", h, x_n)
            nis_terms.append(np.mean(np.sum(resid * resid * r_inv, axis=1)) / 3.0)
            if history_every > 0:
                pick = np.arange(history_every - 1, centre.size, history_every)
                cum_info = p0_inv[None] + np.cumsum(info_terms, axis=0)[pick]
                cum_vec = (p0_inv @ x0)[None] + np.cumsum(vec_terms, axis=0)[pick]
                vals = np.linalg.solve(cum_info, cum_vec[..., None])[..., 0][:, :3]
                sig = np.sqrt(np.diagonal(np.linalg.inv(cum_info), axis1=1, axis2=2))[:, :3]
                self.history[g] = {"values": vals, "sigma": sig}
                self.history["t_s"] = t_c[pick]
            out_vals.append(x_n[:3])
            out_cov.append(p_n[:3, :3])
        values = np.concatenate(out_vals)
        cov = np.zeros((n_d, n_d))
        for i, block in enumerate(out_cov):
            cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] = block
        self.nis_mean = float(np.mean(nis_terms))
        return ComOffsetEstimate(self.grs_ids, values, cov, cov.copy(), np.zeros((n_d, n_d)), True,
                                 float(epochs.t[-1]), int(centre.size), self.nis_mean,
                                 {k: dict(v) for k, v in checked.counts.items()}, self.method)

    def _angular(self, scale_factors: ScaleFactorEstimate | Mapping[int, ArrayLike]) -> dict[int, np.ndarray]:
        if isinstance(scale_factors, ScaleFactorEstimate):
            return {g: scale_factors.of(g)[0] for g in self.grs_ids}
        return {int(g): np.asarray(v, dtype=np.float64) for g, v in scale_factors.items()}

