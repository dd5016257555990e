"""Options and model of the default (``gls``) scale-factor estimator: the attitude driven by the fused
GRS angular acceleration, the readout difference of the two GRS. Equations: docs/estimators.md,
section 4."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from taiji2_estimator_pkg.core.factored_steady import RegressorFactors
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.twostage import StateSpaceModel
from taiji2_estimator_pkg.core.validation import ValidationOptions


@dataclass(frozen=True)
class ScaleFactorOptions:
    """Options of the default (``gls``) scale-factor estimator.

    Attributes
    ----------
    gate_probability : float or None
        False-alarm probability of the chi-square gate per update (None: no gating).
    gate_refresh_s : float
        Per-sample path: the gates test each epoch against the estimate of the data before the first
        epoch of its span of this much data time, solved once per span (:mod:`.gate_span`) [s]; at most
        one sample period: a solve at every epoch.
    max_bridged_gap_s : float
        Longest gap [s] bridged by the state prediction; longer gaps restart the attitude state.
    gap_acceleration_sigma_rad_s2 : float
        1-sigma of the change of the angular acceleration since the last GRS sample, over a step
        without GRS data (whose input is that sample's, held) [rad s^-2].
    snap_tolerance : float
        Relative distance at which the filter covariance is set back to its steady state.
    determination_margin : float
        Two GRS: the estimate is published once the marginal information on G exceeds this
        multiple of the statistical fluctuation of the bias-corrected GRS-pair term.
    validation : ValidationOptions
        Input checks.
    star_tracker_offset_s : float
        Constant time of each star-tracker readout after the GRS sampling instant of its epoch [s]
        (the slot of :mod:`taiji2_estimator_pkg.epochs`, within half a sample period): the attitude is
        measured at ``t_k + tau`` (:class:`ScaleFactorModel`).
    """

    gate_probability: float | None = 1e-6
    gate_refresh_s: float = 1.0
    max_bridged_gap_s: float = 10.0
    gap_acceleration_sigma_rad_s2: float = 1e-9
    snap_tolerance: float = 1e-10
    determination_margin: float = 20.0
    validation: ValidationOptions = field(default_factory=ValidationOptions)
    star_tracker_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if not (self.gate_refresh_s >= 0.0 and math.isfinite(self.gate_refresh_s)):
            raise ValueError(f"gate_refresh_s: a finite time >= 0 [s], got {self.gate_refresh_s!r}")


class ScaleFactorModel:
    """State-space model of the attitude driven by the GRS, in decoupled coordinates.

    The star-tracker noise is whitened (``T = R^-1/2``) and the axes rotated (``U^T``) so that the
    fused process noise is diagonal: ``y'' = M y``, ``a'' = M a``, ``M = U^T T``. Each axis is then
    an independent double integrator with unit measurement noise, which makes the steady-state
    closed loop block diagonal (2 x 2 per axis) for the bulk path.

    The star tracker is modelled at its own sample times: a readout taken ``tau`` after the GRS
    instant t_k of its epoch measures ``phi(t_k + tau) = phi_k + tau omega_k + tau^2 / 2 a``, so the
    measurement row is ``H = [I, tau I]`` (per axis ``[1, tau]``: the decoupled blocks stay). The
    last term (the angular acceleration over the partial step, ``a``) is left out: it is below
    ``(P/2)^2 / 2 |a| = 1.3e-3 s^2 x 5e-9 rad s^-2 = 7e-12 rad`` at 10 Hz with the nominal maneuvers,
    1e-5 of the star tracker's 1-sigma noise (0.2 arcsec = 1e-6 rad). ``tau`` is one constant per
    record (the stream's slot, :mod:`taiji2_estimator_pkg.epochs`); per-sample stamp jitter is not
    modelled (a few ms rms moves ``tau omega`` by ~1e-9 rad).

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry and noise budget.
    grs_ids : sequence of int
        One or two GRS ids.
    star_tracker_offset_s : float
        tau: each star-tracker readout's time after its epoch's GRS instant [s], ``|tau| < dt``.
    """

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int], star_tracker_offset_s: float = 0.0
                 ) -> None:
        self.instrument = instrument
        self.grs_ids = tuple(int(g) for g in grs_ids)
        if not 1 <= len(self.grs_ids) <= 2 or len(set(self.grs_ids)) != len(self.grs_ids):
            raise ValueError(f"grs_ids: one or two distinct ids, got {grs_ids!r}")
        self.dt = instrument.dt_s
        self.c = {g: instrument.c(g) for g in self.grs_ids}
        self.q_grs = {g: instrument.angular_noise_crf(g) for g in self.grs_ids}
        q_inv = {g: np.linalg.inv(self.q_grs[g]) for g in self.grs_ids}
        self.q_fused = np.linalg.inv(sum(q_inv.values()))
        self.weights = {g: self.q_fused @ q_inv[g] for g in self.grs_ids}
        st_var = instrument.noise.star_tracker_variance()
        whiten = np.diag(1.0 / np.sqrt(st_var))
        values, vectors = np.linalg.eigh(whiten @ self.q_fused @ whiten.T)
        self.to_model = vectors.T @ whiten  # M = U^T T
        self.from_model = np.linalg.inv(self.to_model)
        dt = self.dt
        eye = np.eye(3)
        self.f = np.block([[eye, dt * eye], [np.zeros((3, 3)), eye]])
        self.b = np.vstack((0.5 * dt * dt * eye, dt * eye))
        tau = float(star_tracker_offset_s)
        if not (math.isfinite(tau) and abs(tau) < dt):
            raise ValueError(f"star_tracker_offset_s: within a sample period ({dt} s), got {tau!r}")
        self.star_tracker_offset_s = tau
        self.h = np.hstack((eye, tau * eye))
        self.state_space = StateSpaceModel(
            f=self.f, b=self.b, q=self.b @ np.diag(values) @ self.b.T, h=self.h, r=np.eye(3),
            blocks=((0, 3), (1, 4), (2, 5)))
        self.n_params = 3 * len(self.grs_ids)
        # GRS1 - GRS2 consistency: residual covariance and the corrected-least-squares term
        if len(self.grs_ids) == 2:
            g1, g2 = self.grs_ids
            self.w_diff = np.linalg.inv(self.q_grs[g1] + self.q_grs[g2])
            self.w_diff = 0.5 * (self.w_diff + self.w_diff.T)
            # W = L L^T: a weighted sum of squares sum_k D_k^T W D_k becomes one Gram product (L^T D)^T (L^T D)
            self.w_diff_chol = np.linalg.cholesky(self.w_diff)
            var = instrument.noise.angular_readout_variance()
            correction = np.zeros(6)
            for block, g in enumerate(self.grs_ids):
                projected = self.c[g] @ self.w_diff @ self.c[g].T
                correction[3 * block:3 * block + 3] = var / instrument.nominal_scale_factors[g] ** 2 \
                    * np.diag(projected)
            self.cls_correction = np.diag(correction)
            self.pair_null_dimension = self._pair_null_dimension()
        else:
            self.w_diff = None
            self.w_diff_chol = None
            self.cls_correction = None
            self.pair_null_dimension = 0

    def _pair_null_dimension(self) -> int:
        """The number of directions of G the GRS pair cannot see (2 for the built-in layouts: the common
        scale of (phi, theta) and of psi): ``6 - rank`` of ``D_0(e_j)`` stacked over unit accelerations
        e_j about the CRF axes (``D_0`` is linear in the acceleration), at the nominal G."""
        g_nominal = {g: np.asarray(self.instrument.nominal_scale_factors[g], dtype=np.float64) for g in self.grs_ids}
        rows = []
        for axis in range(3):
            unit = np.zeros(3)
            unit[axis] = 1.0
            differences = np.stack([self.c[g] @ unit / g_nominal[g] for g in self.grs_ids])  # U~ = C a / G [V]
            rows.append(self.difference_regressor(differences))
        singular = np.linalg.svd(np.vstack(rows), compute_uv=False)
        return 6 - int(np.sum(singular > 1e-9 * singular[0]))

    def pair_information(self, moment: np.ndarray, n_pairs: int) -> np.ndarray:
        """(6, 6) information of the GRS pair: ``sum D^T W D - n K`` without its curvature along the
        directions it cannot see.

        The pair's equation ``D G = e_1 - e_2`` is homogeneous: it measures the direction of G (the
        ratios of the two GRS), not its scale. Noise-free its information ``A_0`` is zero along the
        ``k`` directions ``delta_g = c G_g`` (:meth:`_pair_null_dimension`). The CLS-corrected sum is not:
        its fluctuation (std ``sqrt(2 n) K``) leaves a curvature ``a`` there, of either sign, and a
        homogeneous quadratic ``G^T A G`` with curvature along G itself pulls the whole scale towards zero
        (or pushes it away) by ``a / I`` of G: ``a / I / sigma_rel`` sigmas, 1-3 per seed on the
        range-limited designs, where the two-GRS estimate's error was 1.2-1.5 times its reported sigma
        (CHANGELOG.md, 2026-11-29). In the coordinates relative to the nominal G, the ``k`` smallest
        eigenvalues of the sum are set to zero: its own eigenvectors keep the ratios the data measure,
        the scale is left to the star tracker.
        """
        scale = np.concatenate([self.instrument.nominal_scale_factors[g] for g in self.grs_ids])
        relative = (moment - n_pairs * self.cls_correction) * scale[:, None] * scale[None, :]
        values, vectors = np.linalg.eigh(0.5 * (relative + relative.T))
        values[:self.pair_null_dimension] = 0.0
        return (vectors * values) @ vectors.T / scale[:, None] / scale[None, :]

    def regressor_noise_correction(self, gramian: np.ndarray) -> dict[tuple[int, ...], np.ndarray]:
        """Per-step bias of the star-tracker information from the readout noise in the input.

        The input regressor holds the GRS readout noise n (``U = U_0 + N``) and the process noise is
        ``w = -N G``: the sensitivities and the innovations share it, and ``E[sum S^T Lambda^-1 S]``
        exceeds the noise-free information by, per step and per column c (G component of GRS i,
        axis a, input direction ``v_c = M W_i C_i^T e_a``)::

            K_cc = sigma_ia^2 / G_ia^2  (B v_c)^T X (B v_c),

        X the innovation Gramian (:meth:`TwoStageFilter.innovation_gramian`). Subtracting it
        (corrected least squares) removes the attenuation bias of G.

        Returns
        -------
        dict
            GRS present at a step (tuple of ids) to the (p,) diagonal of K.
        """
        var = self.instrument.noise.angular_readout_variance()
        out: dict[tuple[int, ...], np.ndarray] = {}
        configurations = [self.grs_ids] + ([(g,) for g in self.grs_ids] if len(self.grs_ids) == 2 else [])
        for present in configurations:
            weights = self.weights if len(present) == len(self.grs_ids) else {present[0]: np.eye(3)}
            diag = np.zeros(self.n_params)
            for block, g in enumerate(self.grs_ids):
                if g not in present:
                    continue
                directions = self.b @ (self.to_model @ weights[g] @ self.c[g].T)  # (6, 3)
                energy = np.einsum("ia,ij,ja->a", directions, gramian, directions)
                diag[3 * block:3 * block + 3] = var / self.instrument.nominal_scale_factors[g] ** 2 * energy
            out[tuple(present)] = diag
        return out

    def input_noise(self, present: Sequence[int]) -> np.ndarray:
        """(3, 3) model-coordinate covariance of the readout noise in the angular acceleration of a step
        with the GRS ``present`` (not empty; fused when all are present) [model units]."""
        q_crf = self.q_fused if len(present) == len(self.grs_ids) else self.q_grs[present[0]]
        return self.to_model @ q_crf @ self.to_model.T

    def process_noise_model(self, present: Sequence[int], gap_sigma: float) -> np.ndarray:
        """(6, 6) model-coordinate process noise of a step with only the GRS ``present``."""
        if len(present) == len(self.grs_ids):
            return self.state_space.q
        if present:
            q_crf = self.q_grs[present[0]]
        else:
            q_crf = gap_sigma**2 * np.eye(3)
        q_model = self.to_model @ q_crf @ self.to_model.T
        return self.b @ q_model @ self.b.T

    def input_regressor(self, differences: Mapping[int, np.ndarray], present: Sequence[int]) -> np.ndarray:
        """(3, 3 n_grs) model-coordinate d(acceleration)/dG of one step.

        ``differences[g]`` is U~ of GRS g (3,) [V]; only the GRS in ``present`` contribute
        (fused with their information weights).
        """
        out = np.zeros((3, self.n_params))
        if not present:
            return out
        if len(present) == len(self.grs_ids):
            weights = self.weights
        else:
            weights = {present[0]: np.eye(3)}
        for block, g in enumerate(self.grs_ids):
            if g in present:
                out[:, 3 * block:3 * block + 3] = self.to_model @ weights[g] @ self.c[g].T * differences[g][None, :]
        return out

    def fused_input_matrix(self, grs: int) -> np.ndarray:
        """(3, 3) ``M_g = T W_g C_g^T``: GRS g's U~ (times G) to the fused model-coordinate acceleration
        when every GRS is present (the regular steps of the bulk paths)."""
        return self.to_model @ self.weights[grs] @ self.c[grs].T

    def input_regressor_factors(self, differences: np.ndarray) -> RegressorFactors:
        """(L, 3, 3 n_grs) regressors of regular steps (all GRS present, :meth:`input_regressor` of each)
        as factors: the series are U~ (L, 3 n_grs) of differences (L, n_grs, 3), the patterns
        ``M_g[:, c] e_j^T`` (:meth:`fused_input_matrix`, j = 3 block + c)."""
        n_series = 3 * len(self.grs_ids)
        patterns = np.zeros((n_series, 3, self.n_params))
        for block, grs in enumerate(self.grs_ids):
            matrix = self.fused_input_matrix(grs)
            for c in range(3):
                patterns[3 * block + c, :, 3 * block + c] = matrix[:, c]
        return RegressorFactors(differences.reshape(differences.shape[0], n_series), patterns)

    def input_batch(self, differences: np.ndarray, g: np.ndarray) -> np.ndarray:
        """(L, 3) known inputs ``U_k g`` of regular steps (:meth:`input_regressor_factors` times ``g``,
        without forming the regressors), differences (L, n_grs, 3)."""
        out = np.zeros((differences.shape[0], 3))
        for block, grs in enumerate(self.grs_ids):
            out += (differences[:, block, :] * g[3 * block:3 * block + 3]) @ self.fused_input_matrix(grs).T
        return out

    def difference_row(self, differences_1: np.ndarray, differences_2: np.ndarray) -> np.ndarray:
        """(3, 6) ``D`` of one epoch (see :meth:`difference_regressor`)."""
        g1, g2 = self.grs_ids
        return np.hstack((self.c[g1].T * differences_1[None, :], -self.c[g2].T * differences_2[None, :]))

    def difference_residual(self, differences: np.ndarray, g: np.ndarray) -> np.ndarray:
        """(..., 3) ``D g`` (:meth:`difference_regressor` times ``g``, without forming ``D``)."""
        g1, g2 = self.grs_ids
        return (differences[..., 0, :] * g[0:3]) @ self.c[g1] - (differences[..., 1, :] * g[3:6]) @ self.c[g2]

    def difference_regressor(self, differences: np.ndarray) -> np.ndarray:
        """(..., 3, 6) ``D = [C_1^T diag(u_1), -C_2^T diag(u_2)]`` (CRF), differences (..., 2, 3)."""
        g1, g2 = self.grs_ids
        out = np.empty((*differences.shape[:-2], 3, 6))
        out[..., :, 0:3] = self.c[g1].T * differences[..., 0, None, :]
        out[..., :, 3:6] = -self.c[g2].T * differences[..., 1, None, :]
        return out
