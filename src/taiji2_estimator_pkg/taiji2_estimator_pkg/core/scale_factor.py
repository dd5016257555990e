"""Angular scale factors G = (G_Pphi, G_Ptheta, G_Ppsi) of one or both GRS.

Two methods:

``paper`` (:class:`PaperScaleFactorFilter`)
    The paper's filter: per GRS a 3-state Kalman filter, Phi = I, Q = 0, Joseph update,
    ``H_k = C_i^-1 U~_k``, measurement = star-tracker angular acceleration from a smoothing
    derivative (Savitzky-Golay) of the attitude, the GRS side filtered with the equivalent kernel,
    diagonal R = the per-sample variance of the smoothed noise. Kept as the paper wrote it; its
    covariance treats strongly correlated samples as white and is far too small (reported, not
    fixed).

``gls`` (:class:`ScaleFactorEstimator`, default)
    A linear-Gaussian state space whose state is the small-angle attitude phi and rate omega
    (CRF), driven by the GRS angular acceleration ``a_k = sum_i W_i C_i^T diag(u_i,k) G_i``
    (fused over the GRS with the information weights ``W_i = Q_f Q_i^-1``), process noise = the
    GRS angular readout noise mapped to CRF (``Q_f``, per sample), measurement = the raw
    small-angle attitude phi from the star tracker, white R. G is constant and enters linearly:
    the two-stage filter of :mod:`.twostage` gives the exact GLS estimate and covariance (= the
    augmented Kalman filter with a diffuse prior on G and on the initial attitude and rate).
    With two GRS the readout difference ``B_1 G_1 - B_2 G_2 = e_1 - e_2`` (independent of the
    fused acceleration) adds a static regression on the six parameters; its regressor holds the
    readout noise, so its normal matrix is bias-corrected (corrected least squares, exact in
    expectation): the estimate stays unbiased.
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

from .attitude import AttitudeIntegrator, SmoothingDerivative, integrate_attitude
from .estimate_blocks import PerGrsBlocks
from .factored_steady import RegressorFactors
from .instrument import InstrumentModel, angular_differences, linear_sums
from .kalman import KalmanFilter, chi2_gate
from .twostage import StateSpaceModel, TwoStageFilter, solve_information
from .validation import InputValidator, ValidationOptions, validate_batch

__all__ = [
    "PaperScaleFactorFilter",
    "PaperScaleFactorOptions",
    "ScaleFactorEstimate",
    "ScaleFactorEstimator",
    "ScaleFactorModel",
    "ScaleFactorOptions",
    "StepReport",
]


# ==============================================================================================
# Results
# ==============================================================================================


@dataclass
class ScaleFactorEstimate(PerGrsBlocks):
    """Scale-factor estimate of one or two GRS.

    Attributes
    ----------
    grs_ids : tuple of int
        GRS ids, in the order of the parameter vector.
    values : numpy.ndarray
        (3 n_grs,) (G_Pphi, G_Ptheta, G_Ppsi) per GRS [rad s^-2 V^-1].
    covariance : numpy.ndarray
        (3 n_grs, 3 n_grs) joint covariance [rad^2 s^-4 V^-2].
    determined : bool
        False until the data determine every parameter (values then NaN).
    t_s : float
        Stamp of the last processed sample [s].
    n_samples : int
        Star-tracker updates used.
    nis_mean : float
        Mean post-fit NIS per degree of freedom (1 if consistent).
    rejected : dict
        Rejected inputs per stream and reason (validation and gating).
    method : str
        ``"gls"`` or ``"paper"``.
    """

    grs_ids: tuple[int, ...]
    values: np.ndarray
    covariance: np.ndarray
    determined: bool
    t_s: float
    n_samples: int
    nis_mean: float
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    method: str = "gls"


    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/YAML, messages, checkpoints)."""
        return {"grs_ids": list(self.grs_ids), "values": self.values.tolist(),
                "covariance": self.covariance.tolist(), "determined": self.determined, "t_s": self.t_s,
                "n_samples": self.n_samples, "nis_mean": self.nis_mean, "rejected": self.rejected,
                "method": self.method}


@dataclass(frozen=True)
class StepReport:
    """What one per-sample update did.

    Attributes
    ----------
    t_s : float
        Stamp [s].
    nis : float
        Pre-fit NIS of the star-tracker update (3 dof; NaN if none or not yet determined).
    nis_grs : float
        NIS of the GRS1-GRS2 consistency residual (3 dof; joint estimation only, else NaN).
    accepted : bool
        Star-tracker update used.
    rejections : tuple of (str, str)
        (stream, reason) of inputs rejected at this sample.
    """

    t_s: float
    nis: float
    nis_grs: float
    accepted: bool
    rejections: tuple[tuple[str, str], ...] = ()


# ==============================================================================================
# Options
# ==============================================================================================


@dataclass(frozen=True)
class ScaleFactorOptions:
    """Options of the default (``gls``) scale-factor estimator.

    Attributes
    ----------
    gate_probability : float or None
        False-alarm probability of the chi-square gate per update (None: no gating).
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
    """

    gate_probability: float | None = 1e-6
    max_bridged_gap_s: float = 10.0
    gap_acceleration_sigma_rad_s2: float = 1e-9
    snap_tolerance: float = 1e-10
    determination_margin: float = 20.0
    validation: ValidationOptions = field(default_factory=ValidationOptions)


@dataclass(frozen=True)
class PaperScaleFactorOptions:
    """Options of the paper's scale-factor filter.

    Attributes
    ----------
    window : int
        Savitzky-Golay window [samples] (odd).
    polyorder : int
        Savitzky-Golay polynomial order.
    initial_sigma_fraction : float
        Initial 1-sigma of G as a fraction of the nominal value (P_0).
    gate_probability : float or None
        Chi-square gate (None: none, as in the paper).
    validation : ValidationOptions
        Input checks.
    """

    window: int = 2001
    polyorder: int = 2
    initial_sigma_fraction: float = 0.1
    gate_probability: float | None = None
    validation: ValidationOptions = field(default_factory=ValidationOptions)


# ==============================================================================================
# The state-space model of the default method
# ==============================================================================================


class ScaleFactorModel:
    """State-space model of the attitude driven by the GRS, in decoupled coordinates.

    The star-tracker noise is whitened (``T = R^-1/2``) and the axes rotated (``U^T``) so that the
    fused process noise is diagonal: ``y'' = M y``, ``a'' = M a``, ``M = U^T T``. Each axis is then
    an independent double integrator with unit measurement noise, which makes the steady-state
    closed loop block diagonal (2 x 2 per axis) for the bulk path.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry and noise budget.
    grs_ids : sequence of int
        One or two GRS ids.
    """

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int]) -> None:
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
        self.h = np.hstack((eye, np.zeros((3, 3))))
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
        else:
            self.w_diff = None
            self.w_diff_chol = None
            self.cls_correction = None

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


# ==============================================================================================
# Default method
# ==============================================================================================


class ScaleFactorEstimator:
    """Default (``gls``) scale-factor estimator: per-sample (node) and bulk (offline) forms.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal values and noise budget.
    grs_ids : sequence of int
        GRS estimated jointly (one or both).
    options : ScaleFactorOptions, optional
        Tuning.

    Examples
    --------
    Per sample (a node)::

        est = ScaleFactorEstimator(instrument, (1, 2))
        report = est.update(t, quat_xyzw, {1: v1, 2: v2})   # any input may be None / absent
        g = est.estimate()                                   # running estimate + covariance

    In bulk (offline, a whole bag)::

        est = ScaleFactorEstimator(instrument, (1, 2))
        g = est.process_batch(t, quats, voltages)            # (n,), (n, 4), (n, 2, 6)
    """

    method = "gls"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: ScaleFactorOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or ScaleFactorOptions()
        self.model = ScaleFactorModel(instrument, grs_ids)
        self.grs_ids = self.model.grs_ids
        self.filter = TwoStageFilter(self.model.state_space, self.model.n_params, self.options.snap_tolerance)
        validation = self.options.validation
        self.validator = InputValidator(ValidationOptions(**{**validation.__dict__, "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.attitude = AttitudeIntegrator()
        self.gate = None if self.options.gate_probability is None else chi2_gate(3, self.options.gate_probability)
        p = self.model.n_params
        self.st_correction = self.model.regressor_noise_correction(self.filter.innovation_gramian())
        self.st_correction_sum = np.zeros(p)  # accumulated diagonal of the star-tracker CLS term
        self.diff_moment = np.zeros((p, p))  # sum D^T W D over consistent GRS pairs (uncorrected)
        self.n_diff = 0
        self.n_gated_grs = 0
        self.determined = False
        self._cache: tuple[np.ndarray, np.ndarray, bool] | None = None
        self._segments_x0: list[tuple[np.ndarray, np.ndarray]] = []
        #: input regressor and GRS of the last step with GRS data, held over steps without any
        self._held: tuple[np.ndarray, tuple[int, ...]] | None = None
        self.last_index: int | None = None
        self.t0_s: float | None = None
        self.t_last_s = float("nan")
        self.rates: np.ndarray | None = None
        self.rate_times: np.ndarray | None = None

    # information and solution ------------------------------------------------------------------
    def _total_information(self) -> tuple[np.ndarray, np.ndarray]:
        """Information over (G, x0): two-stage filter plus the CLS-corrected GRS-pair term."""
        info = self.filter.info.copy()
        p = self.model.n_params
        info[:p, :p] -= np.diag(self.st_correction_sum)
        if self.n_diff:
            info[:p, :p] += self.diff_moment - self.n_diff * self.model.cls_correction
        return info, self.filter.vector

    def _check_determined(self, info: np.ndarray) -> bool:
        """Whether the data determine every parameter well enough to publish an estimate.

        Single GRS: the information is positive definite. Two GRS: in addition the marginal
        information on G must exceed, by ``determination_margin``, the statistical fluctuation
        ``sqrt(2 n) K`` of the bias-corrected GRS-pair term (in the two directions that the pair
        cannot see, the common scale of (phi, theta) and of psi, only the star tracker informs).
        """
        p = self.model.n_params
        _, cov, full = solve_information(info, np.zeros(info.shape[0]))
        if not full:
            return False
        if self.model.cls_correction is None:
            return True
        marginal_inv = cov[:p, :p]
        fluctuation = math.sqrt(2.0 * max(self.n_diff, 1)) * np.diag(self.model.cls_correction)
        scale = np.sqrt(fluctuation)
        # smallest eigenvalue of F^-1/2 I_G F^-1/2 = 1 / largest of F^1/2 I_G^-1 F^1/2
        largest = float(np.linalg.eigvalsh(marginal_inv * scale[:, None] * scale[None, :])[-1])
        return largest > 0.0 and 1.0 / largest > self.options.determination_margin

    def _solve(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """(theta, covariance, determined) over (G, x0), cached until new data arrive."""
        if self._cache is None:
            info, vec = self._total_information()
            theta, cov, full = solve_information(info, vec, positive=self.determined)
            if not self.determined and full:
                self.determined = self._check_determined(info)
            self._cache = (theta, cov, full and self.determined)
        return self._cache

    def estimate(self) -> ScaleFactorEstimate:
        """Running estimate with its covariance (all GRS jointly); NaN until determined."""
        theta, cov, ok = self._solve()
        p = self.model.n_params
        values = theta[:p] if ok else np.full(p, np.nan)
        covariance = cov[:p, :p] if ok else np.full((p, p), np.nan)
        dof = max(self.filter.dof_total - self.filter.q_total, 1)
        chi2 = float(self.filter.chi2 - self.filter.vector @ theta) if ok else float("nan")
        rejected = self.validator.count_summary()
        if self.filter.n_rejected:
            rejected.setdefault("star_tracker", {})["gated"] = self.filter.n_rejected
        if self.n_gated_grs:
            rejected.setdefault("grs_pair", {})["gated"] = self.n_gated_grs
        return ScaleFactorEstimate(self.grs_ids, values, covariance, ok, self.t_last_s,
                                   self.filter.n_updates, chi2 / dof, rejected, self.method)

    def rate_estimate(self) -> np.ndarray:
        """Filtered body rate omega at the last epoch, CRF [rad/s] (current estimate; NaN if undetermined)."""
        theta, _, ok = self._solve()
        if not ok:
            return np.full(3, np.nan)
        state = self.filter.x + self.filter.sens @ theta
        return self.model.from_model @ state[3:]

    # per-sample path -----------------------------------------------------------------------------
    def _index(self, t_s: float) -> int:
        if self.t0_s is None:
            self.t0_s = float(t_s)
        return round((float(t_s) - self.t0_s) * self.instrument.sample_rate_hz)

    def start_new_segment(self) -> None:
        """The next epoch starts a new segment (diffuse state): its data need not continue the dynamics
        of the epochs before (a restarted source). The information on G is kept."""
        if not self.filter.fresh:
            self.filter.reset_segment()
            self._cache = None

    def _hold(self, diffs: Mapping[int, np.ndarray], present: tuple[int, ...]) -> np.ndarray:
        """The input regressor of a step with the GRS ``present`` (not empty), kept for the steps after
        it that have no GRS data."""
        regressor = self.model.input_regressor(diffs, present)
        self._held = (regressor, present)
        return regressor

    def _step_input(self, diffs: Mapping[int, np.ndarray], present: tuple[int, ...]
                    ) -> tuple[np.ndarray | None, np.ndarray | None, tuple[int, ...]]:
        """(input regressor, process noise (None: the nominal one), GRS) of a step with the GRS
        ``present``: their input, held for later steps; without any, the held one (:meth:`_held_input`)."""
        if not present:
            return self._held_input()
        q_step = None if len(present) == len(self.grs_ids) else \
            self.model.process_noise_model(present, self.options.gap_acceleration_sigma_rad_s2)
        return self._hold(diffs, present), q_step, present

    def _hold_present(self, epochs: _EpochArrays, grs_present: np.ndarray, k: int) -> None:
        """:meth:`_hold` of epoch ``k`` of a batch if it has GRS data (as :meth:`update` holds every such epoch)."""
        present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k, j])
        if present:
            self._hold({g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)}, present)

    def _held_input(self) -> tuple[np.ndarray | None, np.ndarray, tuple[int, ...]]:
        """(input regressor, process noise, GRS) of a step without GRS data.

        The angular acceleration changes little from one 0.1-s step to the next (the maneuver is a
        square wave of minutes), so the last GRS input is held, with its readout noise plus
        ``gap_acceleration_sigma_rad_s2`` for the change (a torque switch). Taking the unknown
        acceleration as zero-mean noise (sigma 1e-8) instead biased G by 8-11 sigma over 1200 s with
        5 % of the epochs lost at random, and a diffuse one leaves G undetermined; held, G is
        unbiased within the Monte Carlo's resolution (20 seeds), also with every torque switch lost,
        for 11 % more sigma. Before any GRS sample: no input, that sigma alone.
        """
        gap = self.model.process_noise_model((), self.options.gap_acceleration_sigma_rad_s2)
        if self._held is None:
            return None, gap, ()
        regressor, present = self._held
        return regressor, self.model.process_noise_model(present, self.options.gap_acceleration_sigma_rad_s2) + gap, \
            present

    def _bridge(self, missing: int, g: np.ndarray | None = None) -> None:
        """Advance over ``missing`` epochs without any data (the last GRS input held, see
        :meth:`_held_input`); ``g``: in an evaluation pass, the scale factors the held input is applied with."""
        if missing <= 0:
            return
        if missing * self.instrument.dt_s > self.options.max_bridged_gap_s:
            self.filter.reset_segment()
            self._cache = None
            return
        regressor, q_step, present = self._held_input()
        for _ in range(missing):
            if g is not None:
                self.filter.step(None, None, None if regressor is None else regressor @ g, None, q=q_step)
                continue
            fresh = self.filter.fresh
            self.filter.step(None, None, None, regressor, q=q_step)
            if present and not fresh:
                self.st_correction_sum += self.st_correction[present]

    def update(self, t_s: float, quat_xyzw: ArrayLike | None = None,
               voltages: Mapping[int, ArrayLike] | None = None) -> StepReport:
        """Process one epoch (star tracker and GRS readouts stamped ``t_s``).

        Parameters
        ----------
        t_s : float
            Stamp [s] (on the 1/fs grid of the first stamp).
        quat_xyzw : array_like, optional
            (4,) star-tracker attitude (None: missing).
        voltages : mapping of int to array_like, optional
            GRS id to (6,) voltages ``vx1, vx2, vy1, vy2, vz1, vz2`` [V] (absent: missing).

        Returns
        -------
        StepReport
        """
        rejections: list[tuple[str, str]] = []
        q_ok = None
        if quat_xyzw is not None:
            check = self.validator.check_star_tracker(t_s, quat_xyzw)
            if check.ok:
                q_ok = check.value
            else:
                rejections.append(("star_tracker", str(check.reason)))
        diffs: dict[int, np.ndarray] = {}
        for gid, v in (voltages or {}).items():
            check = self.validator.check_grs(t_s, int(gid), v)
            if check.ok:
                v = check.value
                diffs[int(gid)] = np.array((v[2] - v[3], v[4] - v[5], v[0] - v[1]))
            else:
                rejections.append((f"grs{gid}", str(check.reason)))
        if q_ok is None and not diffs:
            return StepReport(float(t_s), float("nan"), float("nan"), False, tuple(rejections))
        index = self._index(t_s)
        if self.last_index is not None and index <= self.last_index:
            rejections.append(("epoch", "out_of_order_stamp"))
            return StepReport(float(t_s), float("nan"), float("nan"), False, tuple(rejections))
        if self.last_index is not None:
            self._bridge(index - self.last_index - 1)
        self.last_index = index
        self.t_last_s = float(t_s)
        theta, cov, ok = self._solve()
        estimate = (theta, cov) if ok else None
        present = tuple(g for g in self.grs_ids if g in diffs)
        nis_grs = float("nan")
        if len(self.grs_ids) == 2 and len(present) == 2:
            d_row = self.model.difference_row(diffs[self.grs_ids[0]], diffs[self.grs_ids[1]])
            if ok:
                resid = d_row @ theta[:6]
                total = self.model.q_grs[self.grs_ids[0]] + self.model.q_grs[self.grs_ids[1]] \
                    + d_row @ cov[:6, :6] @ d_row.T
                nis_grs = float(resid @ np.linalg.solve(total, resid))
            if self.gate is not None and ok and nis_grs > self.gate:
                self.n_gated_grs += 1  # inconsistent GRS pair: use neither at this epoch
                rejections.append(("grs_pair", "gated"))
                present = ()
            else:
                self.diff_moment += d_row.T @ self.model.w_diff @ d_row
                self.n_diff += 1
        phi = None if q_ok is None else self.attitude.add(q_ok)
        y = None if phi is None else self.model.to_model @ phi
        regressor, q_step, present = self._step_input(diffs, present)
        fresh = self.filter.fresh
        info = self.filter.step(y, None, None, regressor, q=q_step, gate=self.gate if ok else None,
                                estimate=estimate)
        if present and not fresh:
            self.st_correction_sum += self.st_correction[present]
        self._cache = None
        if not info.accepted:
            rejections.append(("star_tracker", "gated"))
        return StepReport(float(t_s), info.nis, nis_grs, y is not None and info.accepted, tuple(rejections))

    # bulk path ----------------------------------------------------------------------------------------
    def process_batch(self, t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                      want_rates: bool = False) -> ScaleFactorEstimate:
        """Process a whole record in bulk.

        Parameters
        ----------
        t_s : array_like
            (n,) stamps shared by the star tracker and the GRS [s].
        quat_xyzw : array_like
            (n, 4) star-tracker readouts (NaN rows: missing).
        voltages_v : array_like
            (n, n_grs, 6) voltages of ``grs_ids`` in order [V] (NaN rows: missing).
        want_rates : bool
            Also compute the filtered body rate at every epoch with the final estimate
            (:attr:`rates` (L, 3) CRF [rad/s] at :attr:`rate_times` (L,) [s]).

        Returns
        -------
        ScaleFactorEstimate
            Same numbers as :meth:`update` sample by sample when nothing is gated. The bulk form
            gates on post-fit residuals (NIS of every epoch at the final estimate) and, if any
            epoch exceeds the gate, runs again without those epochs.
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        if self.last_index is not None or self.filter.n_updates:
            raise RuntimeError("process_batch runs on a fresh estimator (use update() to continue)")
        checked = validate_batch(t, quat_xyzw, volts, self.validator.options, self.grs_ids)
        for stream, counts in checked.counts.items():
            for reason, number in counts.items():
                self.validator.counts.setdefault(stream, Counter())[reason] += number
        epochs = _EpochArrays.build(checked, t, volts)
        initial = copy.deepcopy(self.filter)
        gated_st = np.zeros(epochs.count, dtype=bool)
        gated_pair = np.zeros(epochs.count, dtype=bool)
        states = None  # filtered states of the last evaluation pass, if it used the final estimate
        for attempt in range(2):
            self.filter = copy.deepcopy(initial)
            self.diff_moment = np.zeros_like(self.diff_moment)
            self.st_correction_sum = np.zeros_like(self.st_correction_sum)
            self.n_diff = 0
            self.determined = False
            self._cache = None
            self._accumulate(epochs, gated_st, gated_pair)
            self._segments_x0 = list(self.filter.segment_x0)
            theta, _, ok = self._solve()
            if self.gate is None or attempt == 1 or not ok:
                break
            nis_st, nis_pair, states = self._evaluate(initial, epochs, gated_st, gated_pair, theta)
            new_st = (nis_st > self.gate) & ~gated_st
            new_pair = (nis_pair > self.gate) & ~gated_pair
            if not (np.any(new_st) or np.any(new_pair)):
                break  # nothing newly gated: theta is final and ``states`` were evaluated with it
            states = None
            gated_st |= new_st
            gated_pair |= new_pair
        self.filter.n_rejected = int(np.count_nonzero(gated_st))
        self.n_gated_grs = int(np.count_nonzero(gated_pair))
        theta, _, ok = self._solve()
        if want_rates and ok:
            if states is None:
                _, _, states = self._evaluate(initial, epochs, gated_st, gated_pair, theta)
            self.rates = states[:, 3:] @ self.model.from_model.T
            self.rate_times = epochs.t.copy()
        if epochs.count:
            self.last_index = int(epochs.index[-1])
            self.t0_s = float(epochs.t0)
            self.t_last_s = float(epochs.t[-1])
            self.attitude.load_state_dict({"last": epochs.last_quat.tolist(), "phi": epochs.last_phi.tolist()})
        return self.estimate()

    def _epoch_plan(self, epochs: _EpochArrays, gated_st: np.ndarray, gated_pair: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        grs_present = epochs.grs_ok & ~gated_pair[:, None]
        st_present = epochs.st_ok & ~gated_st
        regular = st_present & np.all(grs_present, axis=1)
        return regular, st_present, grs_present

    def _accumulate(self, epochs: _EpochArrays, gated_st: np.ndarray, gated_pair: np.ndarray) -> None:
        """Accumulation pass: information of every epoch (bulk for regular runs)."""
        regular, st_present, grs_present = self._epoch_plan(epochs, gated_st, gated_pair)
        model = self.model
        if len(self.grs_ids) == 2:
            both = np.all(grs_present, axis=1)
            if np.any(both):
                d_rows = model.difference_regressor(epochs.diffs[both])
                # sum_k D_k^T W D_k = Z^T Z with Z = stacked L^T D_k  (W = L L^T)
                whitened = (model.w_diff_chol.T @ d_rows).reshape(-1, d_rows.shape[-1])
                self.diff_moment += whitened.T @ whitened
                self.n_diff += int(np.count_nonzero(both))
        y_all = epochs.phi @ model.to_model.T
        self._held = None
        for kind, start, stop in self._runs(epochs, regular, st_present):
            if kind == "skip":
                self._hold_present(epochs, grs_present, start)
                continue
            if kind == "gap":
                self._bridge(stop)
            elif kind == "regular":
                fresh = self.filter.fresh
                u_reg = model.input_regressor_factors(epochs.diffs[start:stop])
                self.filter.run_regular(y_all[start:stop], None, None, u_reg)
                self.st_correction_sum += (stop - start - int(fresh)) * self.st_correction[self.grs_ids]
                self._hold_present(epochs, grs_present, stop - 1)
            else:
                k = start
                present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k, j])
                diffs = {g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)}
                regressor, q_step, present = self._step_input(diffs, present)
                fresh = self.filter.fresh
                self.filter.step(y_all[k] if st_present[k] else None, None, None, regressor, q=q_step)
                if present and not fresh:
                    self.st_correction_sum += self.st_correction[present]
        self._cache = None

    def _runs(self, epochs: _EpochArrays, regular: np.ndarray, st_present: np.ndarray) -> Any:
        """Yield ("gap", 0, missing), ("regular", start, stop), ("single", k, k + 1) or ("skip", k, k + 1).

        A regular run goes to :meth:`TwoStageFilter.run_regular` whether or not the filter is at its
        steady state (after an irregular epoch the transient back to it is vectorised there too); the
        filter's state is inspected lazily, as the generator is consumed.

        A segment starts at its first star-tracker epoch: before it the state is diffuse (the
        initial state is a GLS parameter), so epochs without a star-tracker measurement, and gaps,
        carry no information on G (any input there is absorbed by the diffuse state) and are
        skipped. Processing them would leave the covariance off its steady state (a prediction
        without update) and send thousands of epochs down the per-sample path until the Riccati
        recursion converges back (the case of a bag whose first GRS sample precedes the first
        star-tracker sample, e.g. a writer stamping a GRS sample with the start of its step).
        """
        k = 0
        count = epochs.count
        # run_end[k]: one past the last epoch of the run of regular, consecutive epochs from k
        continues = np.zeros(count, dtype=bool)
        continues[:-1] = regular[:-1] & regular[1:] & (np.diff(epochs.index) == 1)
        breaks = np.flatnonzero(~continues)
        run_end = breaks[np.searchsorted(breaks, np.arange(count))] + 1
        while k < count:
            if self.filter.fresh and not st_present[k]:
                yield ("skip", k, k + 1)
                k += 1
                continue
            if k > 0 and not self.filter.fresh:
                missing = int(epochs.index[k] - epochs.index[k - 1] - 1)
                if missing > 0:
                    yield ("gap", 0, missing)
            if regular[k]:
                stop = int(run_end[k])
                yield ("regular", k, stop)
                k = stop
            else:
                yield ("single", k, k + 1)
                k += 1

    def _evaluate(self, initial: TwoStageFilter, epochs: _EpochArrays, gated_st: np.ndarray,
                  gated_pair: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Evaluation pass at the final estimate: post-fit NIS of every epoch and filtered states."""
        regular, st_present, grs_present = self._epoch_plan(epochs, gated_st, gated_pair)
        model = self.model
        p = model.n_params
        g_hat = theta[:p]
        segments = self._segments_x0
        first_theta = theta if not segments else np.concatenate((g_hat, segments[0][0] - segments[0][1] @ g_hat))
        saved = self.filter
        self.filter = initial.evaluation_copy(first_theta)
        segment = 0
        nis_st = np.zeros(epochs.count)
        states = np.zeros((epochs.count, 6))
        y_all = epochs.phi @ model.to_model.T
        skipped: list[int] = []
        self._held = None
        for kind, start, stop in self._runs(epochs, regular, st_present):
            if kind == "skip":
                skipped.append(start)
                self._hold_present(epochs, grs_present, start)
            elif kind == "gap":
                self._bridge(stop, g_hat)
                if self.filter.fresh:  # a reset: the next segment's initial state
                    segment += 1
                    if segment < len(segments):
                        offset, gain = segments[segment]
                        self.filter.x = offset - gain @ g_hat
                    else:
                        self.filter.x = theta[p:].copy()
            elif kind == "regular":
                u0 = model.input_batch(epochs.diffs[start:stop], g_hat)
                out = self.filter.run_regular(y_all[start:stop], None, u0, None, want_states=True)
                nis_st[start:stop] = out.nis
                states[start:stop] = out.states
                self._hold_present(epochs, grs_present, stop - 1)
            else:
                k = start
                present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k, j])
                diffs = {g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)}
                regressor, q_step, _ = self._step_input(diffs, present)
                result = self.filter.step(y_all[k] if st_present[k] else None, None,
                                          None if regressor is None else regressor @ g_hat, None, q=q_step)
                states[k] = result.state
                if st_present[k]:
                    nis_st[k] = result.post_nis
        self.filter = saved
        # epochs before a segment's first star-tracker epoch: the state propagated back from it,
        # x_{k-1} = F^-1 (x_k - B a_k), a_k the GRS acceleration at the final estimate
        f_inv = np.linalg.inv(model.f)
        for k in reversed(skipped):
            if k + 1 < epochs.count and epochs.index[k + 1] == epochs.index[k] + 1:
                present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k + 1, j])
                diffs = {g: epochs.diffs[k + 1, j] for j, g in enumerate(self.grs_ids)}
                states[k] = f_inv @ (states[k + 1] - model.b @ (model.input_regressor(diffs, present) @ g_hat))
        nis_pair = np.zeros(epochs.count)
        if len(self.grs_ids) == 2:
            both = np.all(epochs.grs_ok, axis=1)
            resid = model.difference_residual(epochs.diffs[both], g_hat)
            # r^T W r = |L^T r|^2
            nis_pair[both] = np.sum((resid @ model.w_diff_chol) ** 2, axis=1)
        return nis_st, nis_pair, states

    # checkpoint ---------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Checkpoint: everything needed to resume (plain lists/numbers, JSON-serialisable)."""
        return {
            "method": self.method, "grs_ids": list(self.grs_ids), "filter": self.filter.state_dict(),
            "validator": self.validator.state_dict(), "attitude": self.attitude.state_dict(),
            "diff_moment": self.diff_moment.tolist(), "n_diff": self.n_diff, "n_gated_grs": self.n_gated_grs,
            "st_correction_sum": self.st_correction_sum.tolist(),
            "determined": self.determined, "last_index": self.last_index, "t0_s": self.t0_s,
            "t_last_s": self.t_last_s,
            "held": None if self._held is None else [self._held[0].tolist(), list(self._held[1])],
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Resume from a :meth:`state_dict` checkpoint (same instrument, GRS and options)."""
        if tuple(state["grs_ids"]) != self.grs_ids or state["method"] != self.method:
            raise ValueError("checkpoint of a different estimator configuration")
        self.filter.load_state_dict(state["filter"])
        self.validator.load_state_dict(state["validator"])
        self.attitude.load_state_dict(state["attitude"])
        self.diff_moment = np.asarray(state["diff_moment"], dtype=np.float64)
        self.n_diff = int(state["n_diff"])
        self.st_correction_sum = np.asarray(state["st_correction_sum"], dtype=np.float64)
        self.n_gated_grs = int(state["n_gated_grs"])
        self.determined = bool(state["determined"])
        self.last_index = state["last_index"]
        self.t0_s = state["t0_s"]
        self.t_last_s = float(state["t_last_s"])
        held = state.get("held")  # absent from checkpoints written before it was kept
        self._held = None if held is None else (np.asarray(held[0], dtype=np.float64), tuple(int(g) for g in held[1]))
        self._cache = None

    @classmethod
    def from_state_dict(cls, instrument: InstrumentModel, state: Mapping[str, Any],
                        options: ScaleFactorOptions | None = None) -> ScaleFactorEstimator:
        """New estimator resumed from a checkpoint."""
        est = cls(instrument, tuple(state["grs_ids"]), options)
        est.load_state_dict(state)
        return est


# ==============================================================================================
# Epoch arrays of a batch
# ==============================================================================================


@dataclass
class _EpochArrays:
    """Per-epoch arrays of a validated record (epochs with at least one usable input)."""

    index: np.ndarray
    t: np.ndarray
    t0: float
    st_ok: np.ndarray
    grs_ok: np.ndarray
    phi: np.ndarray
    diffs: np.ndarray
    sums: np.ndarray
    last_quat: np.ndarray
    last_phi: np.ndarray

    @property
    def count(self) -> int:
        return int(self.index.size)

    @classmethod
    def build(cls, checked: Any, t: np.ndarray, volts: np.ndarray) -> _EpochArrays:
        usable = (checked.grid_index >= 0) & (checked.star_tracker_ok | np.any(checked.grs_ok, axis=1))
        rows = np.flatnonzero(usable)
        phi_all = integrate_attitude(checked.quat_xyzw, checked.star_tracker_ok)
        st_rows = np.flatnonzero(checked.star_tracker_ok)
        last_quat = checked.quat_xyzw[st_rows[-1]] if st_rows.size else np.array([0.0, 0.0, 0.0, 1.0])
        last_phi = phi_all[st_rows[-1]] if st_rows.size else np.zeros(3)
        first_stamp = int(np.flatnonzero(checked.grid_index >= 0)[0]) if np.any(checked.grid_index >= 0) else 0
        t0 = float(t[first_stamp]) if t.size else 0.0
        index = checked.grid_index[rows]
        if rows.size:
            index = index - index[0]
            t0 = float(t[rows[0]])
        st_ok = checked.star_tracker_ok[rows]
        phi = np.where(st_ok[:, None], phi_all[rows], 0.0)
        grs_ok = checked.grs_ok[rows]
        # every row usable (the common case): no copy of the voltages
        usable_volts = volts if rows.size == volts.shape[0] else volts[rows]
        finite = np.isfinite(usable_volts)
        if not finite.all():
            usable_volts = np.where(finite, usable_volts, 0.0)
        diffs, sums = angular_differences(usable_volts), linear_sums(usable_volts)
        if not grs_ok.all():  # a GRS sample rejected: no information from it
            diffs[~grs_ok] = 0.0
            sums[~grs_ok] = 0.0
        return cls(index, t[rows], t0, st_ok, grs_ok, phi, diffs, sums, last_quat, last_phi)


# ==============================================================================================
# The paper's filter
# ==============================================================================================


class PaperScaleFactorFilter:
    """The paper's scale-factor filter, per GRS (3 states, Phi = I, Q = 0, Joseph update).

    Measurement ``Z_k = omega_dot_ST,k`` (CRF) from the Savitzky-Golay acceleration kernel on the
    small-angle attitude; ``H_k = C_i^-1 U~_k`` with U~ filtered by the equivalent GRS kernel;
    ``R = diag(sigma_ST^2 ||c||^2 + ||g||^2 diag(C_i^T Q_rot C_i))`` (per-sample variances, treated
    as white as in the paper). Outputs are delayed by ``window // 2`` samples (centred window).

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal G (initial state) and noise budget.
    grs_ids : sequence of int
        GRS to calibrate (one independent filter each).
    options : PaperScaleFactorOptions, optional
        Window, polynomial order, initial uncertainty, gating.
    """

    method = "paper"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: PaperScaleFactorOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or PaperScaleFactorOptions()
        self.grs_ids = tuple(int(g) for g in grs_ids)
        self.smoother = SmoothingDerivative(self.options.window, self.options.polyorder, instrument.dt_s)
        self.kernel_st = self.smoother.acceleration_kernel()
        self.kernel_grs = self.smoother.grs_kernel()
        st_var = instrument.noise.star_tracker_variance() * float(np.sum(self.kernel_st**2))
        grs_gain = float(np.sum(self.kernel_grs**2))
        self.r = {g: st_var + grs_gain * np.diag(instrument.angular_noise_crf(g)) for g in self.grs_ids}
        gate = None if self.options.gate_probability is None else chi2_gate(3, self.options.gate_probability)
        self.filters = {}
        for g in self.grs_ids:
            g0 = instrument.nominal_scale_factors[g]
            self.filters[g] = KalmanFilter(g0, np.diag((self.options.initial_sigma_fraction * g0) ** 2), gate)
        self.validator = InputValidator(ValidationOptions(**{**self.options.validation.__dict__,
                                                             "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.attitude = AttitudeIntegrator()
        w = self.options.window
        self._buffer_index: list[int] = []
        self._buffer_phi: list[np.ndarray | None] = []
        self._buffer_diff: list[dict[int, np.ndarray]] = []
        self._window = w
        self.t0_s: float | None = None
        self.t_last_s = float("nan")
        self.nis: dict[int, list[float]] = {g: [] for g in self.grs_ids}
        self._last_index: int | None = None

    def start_new_segment(self) -> None:
        """The next epoch starts a new segment: no smoothing window straddles the two (a restarted source)."""
        self._buffer_index.clear()
        self._buffer_phi.clear()
        self._buffer_diff.clear()

    def _measurements(self, phi_window: np.ndarray, diff_window: Mapping[int, np.ndarray]
                      ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """Z (3,) and H per GRS from a complete window (phi: (2m+1, 3); U~: (2m, 3), epochs k-m+1..k+m)."""
        # Z_k = omega_dot_ST,k = sum_j c_j phi_{k+j}
        z = self.kernel_st @ phi_window
        h = {}
        for g in self.grs_ids:
            smoothed = self.kernel_grs @ diff_window[g]
            # H_k = C_i^-1 U~_k (smoothed U~, C_i^-1 = C_i^T)
            h[g] = self.instrument.c(g).T * smoothed[None, :]
        return z, h

    def update(self, t_s: float, quat_xyzw: ArrayLike | None = None,
               voltages: Mapping[int, ArrayLike] | None = None) -> StepReport:
        """Process one epoch; the filters update at the centre of the window (``window // 2`` epochs ago).

        Returns
        -------
        StepReport
            ``nis``: mean over the GRS filters of the NIS of the update made now (3 dof each; NaN if
            none); the per-GRS values are appended to :attr:`nis`.
        """
        rejections: list[tuple[str, str]] = []
        phi = None
        if quat_xyzw is not None:
            check = self.validator.check_star_tracker(t_s, quat_xyzw)
            if check.ok:
                phi = self.attitude.add(check.value)
            else:
                rejections.append(("star_tracker", str(check.reason)))
        diffs = {}
        for gid, v in (voltages or {}).items():
            check = self.validator.check_grs(t_s, int(gid), v)
            if check.ok:
                diffs[int(gid)] = angular_differences(check.value)
            else:
                rejections.append((f"grs{gid}", str(check.reason)))
        nothing = StepReport(float(t_s), float("nan"), float("nan"), False, tuple(rejections))
        if phi is None and not diffs:
            return nothing
        if self.t0_s is None:
            self.t0_s = float(t_s)
        index = round((float(t_s) - self.t0_s) * self.instrument.sample_rate_hz)
        if self._last_index is not None and index <= self._last_index:
            return StepReport(float(t_s), float("nan"), float("nan"), False,
                              (*rejections, ("epoch", "out_of_order_stamp")))
        self._last_index = index
        self.t_last_s = float(t_s)
        self._buffer_index.append(index)
        self._buffer_phi.append(phi)
        self._buffer_diff.append(diffs)
        if len(self._buffer_index) > self._window:
            del self._buffer_index[0], self._buffer_phi[0], self._buffer_diff[0]
        if len(self._buffer_index) < self._window:
            return nothing
        contiguous = self._buffer_index[-1] - self._buffer_index[0] == self._window - 1
        complete = all(p is not None for p in self._buffer_phi) and all(
            all(g in d for g in self.grs_ids) for d in self._buffer_diff[1:])
        if not (contiguous and complete):
            return nothing
        phi_window = np.stack(self._buffer_phi)  # type: ignore[arg-type]
        diff_window = {g: np.stack([d[g] for d in self._buffer_diff[1:]]) for g in self.grs_ids}
        z, h = self._measurements(phi_window, diff_window)
        values, accepted = [], True
        for g in self.grs_ids:
            kf = self.filters[g]
            kf.predict()  # Phi = I, Q = 0
            result = kf.update(z, h[g], self.r[g])
            self.nis[g].append(result.nis)
            values.append(result.nis)
            if not result.accepted:
                accepted = False
                rejections.append((f"grs{g}", "gated"))
        return StepReport(float(t_s), float(np.mean(values)), float("nan"), accepted, tuple(rejections))

    def process_batch(self, t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                      history_every: int = 0) -> ScaleFactorEstimate:
        """Bulk form: the same estimate as sample-by-sample :meth:`update` (closed-form sums).

        With Phi = I and Q = 0 the filter's result after N updates is
        ``P_N = (P_0^-1 + sum H^T R^-1 H)^-1``, ``X_N = P_N (P_0^-1 X_0 + sum H^T R^-1 Z)``.

        Parameters
        ----------
        t_s, quat_xyzw, voltages_v : array_like
            (n,), (n, 4), (n, n_grs, 6) as for :meth:`ScaleFactorEstimator.process_batch`.
        history_every : int
            If > 0, keep the running estimate and sigma every that many updates in
            :attr:`history` (dict: ``t_s``, per GRS ``values``/``sigma``).

        Returns
        -------
        ScaleFactorEstimate
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        checked = validate_batch(t, quat_xyzw, volts, self.validator.options, self.grs_ids)
        epochs = _EpochArrays.build(checked, t, volts)
        z, h_diag, t_mid = self._batch_measurements(epochs)
        self.history: dict[str, Any] = {"t_s": t_mid}
        for j, g in enumerate(self.grs_ids):
            kf = self.filters[g]
            c_t = self.instrument.c(g).T
            r_inv = 1.0 / self.r[g]
            h = c_t[None, :, :] * h_diag[:, j, None, :]  # (L, 3, 3)
            info_terms = np.einsum("kji,j,kjl->kil", h, r_inv, h)
            vec_terms = np.einsum("kji,j,kj->ki", h, r_inv, z)
            p0_inv = np.linalg.inv(kf.p)
            info = p0_inv + info_terms.sum(axis=0)
            vec = p0_inv @ kf.x + vec_terms.sum(axis=0)
            p_n = np.linalg.inv(info)
            if history_every > 0 and z.shape[0]:
                pick = np.arange(history_every - 1, z.shape[0], history_every)
                cum_info = p0_inv[None] + np.cumsum(info_terms, axis=0)[pick]
                cum_vec = (p0_inv @ kf.x)[None] + np.cumsum(vec_terms, axis=0)[pick]
                values = np.linalg.solve(cum_info, cum_vec[..., None])[..., 0]
                sigma = np.sqrt(np.diagonal(np.linalg.inv(cum_info), axis1=1, axis2=2))
                self.history[g] = {"values": values, "sigma": sigma}
                self.history["t_s"] = t_mid[pick]
            kf.x = p_n @ vec
            kf.p = 0.5 * (p_n + p_n.T)
            kf.n_updates += z.shape[0]
        self.t_last_s = float(epochs.t[-1]) if epochs.count else float("nan")
        return self.estimate()

    def _batch_measurements(self, epochs: _EpochArrays) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Z (L, 3), smoothed U~ (L, n_grs, 3) and centre stamps (L,) of every complete window."""
        m = self.smoother.half
        count = epochs.count
        w = self._window
        if count < w:
            return np.zeros((0, 3)), np.zeros((0, len(self.grs_ids), 3)), np.zeros(0)
        # a window is usable if its epochs are contiguous and all inputs present
        good = epochs.st_ok.copy()
        good_grs = np.all(epochs.grs_ok, axis=1)
        contiguous_pairs = np.diff(epochs.index) == 1
        starts = np.arange(count - w + 1)
        cum_st = np.concatenate(([0], np.cumsum(good)))
        cum_grs = np.concatenate(([0], np.cumsum(good_grs)))
        cum_pairs = np.concatenate(([0], np.cumsum(contiguous_pairs)))
        usable = ((cum_st[starts + w] - cum_st[starts]) == w) & \
                 ((cum_grs[starts + w] - cum_grs[starts + 1]) == w - 1) & \
                 ((cum_pairs[starts + w - 1] - cum_pairs[starts]) == w - 1)
        z_all = np.stack([np.correlate(epochs.phi[:, a], self.kernel_st, mode="valid") for a in range(3)], axis=1)
        h_all = np.empty((starts.size, len(self.grs_ids), 3))
        for j in range(len(self.grs_ids)):
            for a in range(3):
                h_all[:, j, a] = np.correlate(epochs.diffs[1:, j, a], self.kernel_grs, mode="valid")
        centre = starts + m
        return z_all[usable], h_all[usable], epochs.t[centre[usable]]

    def estimate(self) -> ScaleFactorEstimate:
        """Estimate with the filter's own (paper) covariance, GRS stacked."""
        values = np.concatenate([self.filters[g].x for g in self.grs_ids])
        cov = np.zeros((3 * len(self.grs_ids),) * 2)
        for j, g in enumerate(self.grs_ids):
            cov[3 * j:3 * j + 3, 3 * j:3 * j + 3] = self.filters[g].p
        n = min(kf.n_updates for kf in self.filters.values())
        nis = [v for g in self.grs_ids for v in self.nis[g]]
        nis_mean = float(np.mean(nis) / 3.0) if nis else float("nan")
        return ScaleFactorEstimate(self.grs_ids, values, cov, n > 0, self.t_last_s, n, nis_mean,
                                   self.validator.count_summary(), self.method)

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint (filters, buffers)."""
        return {
            "method": self.method, "grs_ids": list(self.grs_ids),
            "filters": {str(g): kf.state_dict() for g, kf in self.filters.items()},
            "validator": self.validator.state_dict(), "attitude": self.attitude.state_dict(),
            "buffer_index": list(self._buffer_index),
            "buffer_phi": [None if p is None else p.tolist() for p in self._buffer_phi],
            "buffer_diff": [{str(g): v.tolist() for g, v in d.items()} for d in self._buffer_diff],
            "t0_s": self.t0_s, "t_last_s": self.t_last_s, "last_index": self._last_index,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Resume from a :meth:`state_dict` checkpoint."""
        self.filters = {int(g): KalmanFilter.from_state_dict(s) for g, s in state["filters"].items()}
        self.validator.load_state_dict(state["validator"])
        self.attitude.load_state_dict(state["attitude"])
        self._buffer_index = list(state["buffer_index"])
        self._buffer_phi = [None if p is None else np.asarray(p) for p in state["buffer_phi"]]
        self._buffer_diff = [{int(g): np.asarray(v) for g, v in d.items()} for d in state["buffer_diff"]]
        self.t0_s = state["t0_s"]
        self.t_last_s = float(state["t_last_s"])
        self._last_index = state["last_index"]

