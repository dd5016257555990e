"""Cramer-Rao lower bounds of the scale factors G and c.m. offsets d.

Computed from noise-free signals (true angular acceleration and rate of the maneuver) and the noise
budget, with the same linear-Gaussian models as the default estimators, evaluated on the true
regressors: for a linear-Gaussian model with known covariances the Fisher information of the
parameters is the GLS normal matrix ``sum S_k^T Lambda_k^-1 S_k`` of the whitened (innovation)
regressors, which the two-stage filter computes exactly (the diffuse initial state and the
nuisance parameters are marginalised by Schur complement).

Scale factors
    Data: star tracker (white, sigma per axis) and the GRS angular readouts (white LFS rotational
    and voltage noise per GRS); the true angular acceleration is a nuisance known only through the
    GRS (eliminated exactly by using the GRS as the input of the attitude dynamics). With two GRS
    the readout difference adds ``sum D_k^T (Q_1 + Q_2)^-1 D_k``. The information the linear
    readouts carry on G through the common-mode spacecraft acceleration and the *assumed* geometry
    ratio r is deliberately not used (r is not known to 1e-4 on real hardware).

c.m. offsets
    Data: GRS linear readouts (white readout noise), common spacecraft acceleration (white thruster
    force noise, SRP Ornstein-Uhlenbeck), bias and trend per GRS, and the angular acceleration known
    only through the GRS (its noise enters as ``[d x] e``). Three bounds:

    - **full** (default, ``com_offset_covariance``): G1, G2, d1, d2 and the nuisances jointly from
      the star tracker and every GRS channel: the information of the scale-factor stage on G plus
      that of the linear channels on (G, d) (:mod:`.joint_com_offset`, the same equations as the
      joint estimator). The linear channels see G through ``omega_dot^(G) x d`` and the data scale
      ``r G``: they pin ratios of the components of G jointly with d.
    - **two-stage** (``com_offset_covariance_two_stage``): ``P_d|G + J P_G J^T``, J = dd/dG, what an
      estimator reaches that takes G from the angular channels alone and then d.
    - **G exact** (``com_offset_covariance_given_scale_factors``).

An independent frequency-domain (Whittle) approximation of the single-GRS scale-factor information
is given for cross-checking (:func:`whittle_scale_factor_information`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.com_offset.gls import ComOffsetEstimator
from taiji2_estimator_pkg.core.com_offset.joint import joint_information
from taiji2_estimator_pkg.core.com_offset.model import ComOffsetOptions, cross_matrix
from taiji2_estimator_pkg.core.instrument import InstrumentModel, linear_scale_factors
from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorOptions
from taiji2_estimator_pkg.core.twostage import solve_information
from taiji2_estimator_pkg.core.validation import ValidationOptions

__all__ = [
    "CrlbResult",
    "crlb",
    "noise_free_voltages",
    "whittle_scale_factor_information",
]


@dataclass
class CrlbResult:
    """Cramer-Rao bounds for one configuration.

    Attributes
    ----------
    grs_ids : tuple of int
        GRS ids (parameter order).
    duration_s : float
        Record length [s].
    scale_factors : numpy.ndarray
        (3 n,) true G [rad s^-2 V^-1].
    scale_factor_covariance : numpy.ndarray
        (3 n, 3 n) bound on Cov(G) [rad^2 s^-4 V^-2].
    com_offsets : numpy.ndarray
        (3 n,) true d [m].
    com_offset_covariance_given_scale_factors : numpy.ndarray
        (3 n, 3 n) bound on Cov(d) with G exact [m^2].
    com_offset_covariance : numpy.ndarray
        (3 n, 3 n) full bound: G and d jointly from every channel [m^2].
    scale_factor_jacobian : numpy.ndarray
        (3 n, 3 n) dd/dG at the truth.
    com_offset_covariance_two_stage : numpy.ndarray
        (3 n, 3 n) two-stage bound ``P_d|G + J P_G J^T`` [m^2].
    scale_factor_covariance_full : numpy.ndarray
        (3 n, 3 n) full bound on G (the linear channels' information added); ``scale_factor_covariance``
        is the bound of the scale-factor stage (star tracker and angular channels), which the
        published G reaches.
    """

    grs_ids: tuple[int, ...]
    duration_s: float
    scale_factors: np.ndarray
    scale_factor_covariance: np.ndarray
    com_offsets: np.ndarray
    com_offset_covariance_given_scale_factors: np.ndarray
    com_offset_covariance: np.ndarray
    scale_factor_jacobian: np.ndarray
    com_offset_covariance_two_stage: np.ndarray
    scale_factor_covariance_full: np.ndarray

    @property
    def scale_factor_sigma(self) -> np.ndarray:
        """(3 n,) [rad s^-2 V^-1]."""
        return np.sqrt(np.diag(self.scale_factor_covariance))

    @property
    def scale_factor_relative_sigma(self) -> np.ndarray:
        """(3 n,) sigma / G."""
        return self.scale_factor_sigma / self.scale_factors

    @property
    def com_offset_sigma(self) -> np.ndarray:
        """(3 n,) [m], full bound (G and d jointly)."""
        return np.sqrt(np.diag(self.com_offset_covariance))

    @property
    def com_offset_sigma_two_stage(self) -> np.ndarray:
        """(3 n,) [m], two-stage bound (G from the angular channels, then d)."""
        return np.sqrt(np.diag(self.com_offset_covariance_two_stage))

    def scaled(self, factor: float, duration_s: float) -> CrlbResult:
        """The bounds of a record ``1/factor`` times as informative (every covariance times factor)."""
        return CrlbResult(self.grs_ids, duration_s, self.scale_factors, factor * self.scale_factor_covariance,
                          self.com_offsets, factor * self.com_offset_covariance_given_scale_factors,
                          factor * self.com_offset_covariance, self.scale_factor_jacobian,
                          factor * self.com_offset_covariance_two_stage, factor * self.scale_factor_covariance_full)

    @property
    def com_offset_sigma_given_scale_factors(self) -> np.ndarray:
        """(3 n,) [m], G exact."""
        return np.sqrt(np.diag(self.com_offset_covariance_given_scale_factors))

    def difference_sigma(self, given_scale_factors: bool = False, bound: str = "full") -> np.ndarray:
        """(3,) bound on the sigma of d_1 - d_2 [m] (two GRS); ``bound`` ``"full"`` or ``"two_stage"``
        (``given_scale_factors``: G exact)."""
        t = np.hstack((np.eye(3), -np.eye(3)))
        if given_scale_factors:
            cov = self.com_offset_covariance_given_scale_factors
        elif bound == "two_stage":
            cov = self.com_offset_covariance_two_stage
        elif bound == "full":
            cov = self.com_offset_covariance
        else:
            raise ValueError(f"bound: 'full' or 'two_stage', got {bound!r}")
        return np.sqrt(np.diag(t @ cov @ t.T))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        out = {"grs_ids": list(self.grs_ids), "duration_s": self.duration_s,
               "scale_factor_sigma": self.scale_factor_sigma.tolist(),
               "scale_factor_relative_sigma": self.scale_factor_relative_sigma.tolist(),
               "scale_factor_relative_sigma_full": (np.sqrt(np.diag(self.scale_factor_covariance_full))
                                                    / self.scale_factors).tolist(),
               "com_offset_sigma_m": self.com_offset_sigma.tolist(),
               "com_offset_sigma_two_stage_m": self.com_offset_sigma_two_stage.tolist(),
               "com_offset_sigma_given_scale_factors_m": self.com_offset_sigma_given_scale_factors.tolist()}
        if len(self.grs_ids) == 2:
            out["difference_sigma_m"] = self.difference_sigma().tolist()
            out["difference_sigma_two_stage_m"] = self.difference_sigma(bound="two_stage").tolist()
            out["difference_sigma_given_scale_factors_m"] = self.difference_sigma(True).tolist()
        return out


def noise_free_voltages(instrument: InstrumentModel, omega_dot: np.ndarray, omega: np.ndarray,
                        grs_ids: Sequence[int], scale_factors: Mapping[int, ArrayLike],
                        com_offsets: Mapping[int, ArrayLike]) -> np.ndarray:
    """Noise-free electrode voltages (n, n_grs, 6) reading ``C_i omega_dot`` and ``C_i A~ d_i``.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry.
    omega_dot : numpy.ndarray
        (n, 3) step-mean angular acceleration, CRF [rad s^-2].
    omega : numpy.ndarray
        (n, 3) body rate, CRF [rad/s].
    grs_ids : sequence of int
        GRS.
    scale_factors, com_offsets : mapping of int to array_like
        True G and d per GRS.
    """
    out = np.zeros((omega_dot.shape[0], len(grs_ids), 6))
    a_tilde = cross_matrix(omega_dot) + cross_matrix(omega) @ cross_matrix(omega)
    for i, g in enumerate(grs_ids):
        c = instrument.c(g)
        gi = np.asarray(scale_factors[g], dtype=np.float64)
        angular = omega_dot @ c.T
        linear = (a_tilde @ np.asarray(com_offsets[g], dtype=np.float64)) @ c.T
        difference = angular[:, [2, 0, 1]] / gi[[2, 0, 1]]  # electrode axes x, y, z
        total = linear / linear_scale_factors(gi, instrument.linear_ratio_m)
        out[:, i, 0::2] = 0.5 * (total + difference)
        out[:, i, 1::2] = 0.5 * (total - difference)
    return out


def crlb(instrument: InstrumentModel, t_s: ArrayLike, omega_dot: ArrayLike, omega: ArrayLike,
         grs_ids: Sequence[int], scale_factors: Mapping[int, ArrayLike], com_offsets: Mapping[int, ArrayLike],
         detrend: str = "linear") -> CrlbResult:
    """Cramer-Rao bounds of G and d from noise-free signals.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry and noise budget (``instrument.nominal_com_offsets`` set the errors-in-variables
        noise, as in the estimator).
    t_s : array_like
        (n,) sample times [s] (regular grid).
    omega_dot : array_like
        (n, 3) true step-mean angular acceleration, CRF [rad s^-2].
    omega : array_like
        (n, 3) true body rate, CRF [rad/s].
    grs_ids : sequence of int
        GRS (joint bound for two).
    scale_factors, com_offsets : mapping of int to array_like
        True G [rad s^-2 V^-1] and d [m] per GRS.
    detrend : str
        Nuisance model of d (as :class:`~.com_offset.ComOffsetOptions`).

    Returns
    -------
    CrlbResult
    """
    t = np.asarray(t_s, dtype=np.float64)
    wd = np.asarray(omega_dot, dtype=np.float64)
    w = np.asarray(omega, dtype=np.float64)
    grs_ids = tuple(int(g) for g in grs_ids)
    volts = noise_free_voltages(instrument, wd, w, grs_ids, scale_factors, com_offsets)
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))  # the information does not depend on the data
    no_checks = ValidationOptions(saturation_v=None, max_rate_rad_s=1e9)
    sf = ScaleFactorEstimator(instrument, grs_ids, ScaleFactorOptions(gate_probability=None, validation=no_checks))
    sf.process_batch(t, quats, volts)
    p = sf.model.n_params
    info = sf.filter.info.copy()
    if sf.n_diff:
        info[:p, :p] += sf.diff_moment  # noise-free regressors: no errors-in-variables correction
    _, cov_all, _ = solve_information(info, np.zeros(info.shape[0]))
    cov_g = cov_all[:p, :p]
    g_true = np.concatenate([np.asarray(scale_factors[g], dtype=np.float64) for g in grs_ids])
    d_true = np.concatenate([np.asarray(com_offsets[g], dtype=np.float64) for g in grs_ids])
    # the noise budget as given: no measured band noise on noise-free signals
    co = ComOffsetEstimator(instrument, grs_ids, ComOffsetOptions(detrend=detrend, gate_probability=None,
                                                                  adapt_noise=False, validation=no_checks))
    co.process_batch(t, volts, w, (g_true, np.zeros((p, p))))
    co.eiv_sum[:] = 0.0  # Fisher information of the true regressors
    beta_info, _, _, _ = co._beta_system(g_true)
    _, cov_beta, _ = solve_information(beta_info, np.zeros(beta_info.shape[0]))
    n_d = co.model.n_d
    cov_d_given = cov_beta[:n_d, :n_d]
    jac = co.jacobian(g_true)
    cov_d = cov_d_given + jac @ cov_g @ jac.T
    # full bound: the joint information on (G, beta) at the truth, the G stage's information as prior
    beta_true, _, _ = co.solve(g_true)
    g_information, _, _ = solve_information(cov_g, np.eye(p))
    hessian, _, _ = joint_information(co.model, co.corrected_information(), g_true, beta_true, g_information)
    _, cov_joint, _ = solve_information(hessian, np.zeros(hessian.shape[0]))
    cov_joint = 0.5 * (cov_joint + cov_joint.T)
    return CrlbResult(grs_ids, float(t[-1] - t[0] + (t[1] - t[0] if t.size > 1 else 0.0)), g_true, cov_g, d_true,
                      cov_d_given, cov_joint[p:p + n_d, p:p + n_d], jac, 0.5 * (cov_d + cov_d.T), cov_joint[:p, :p])


def whittle_scale_factor_information(instrument: InstrumentModel, omega_dot: ArrayLike, grs_id: int,
                                     scale_factors: ArrayLike) -> np.ndarray:
    """Frequency-domain (Whittle) approximation of the single-GRS information on G (cross-check).

    Works on the second difference of the star-tracker small angle, which removes exactly the
    diffuse initial attitude and rate: ``Delta^2 y_k = dt^2 (a_k + a_{k-1}) / 2 + Delta^2 eps_k``
    with ``a = B G + w``. Per Fourier bin (``z = exp(-2 pi i f dt)``) the mean is
    ``dt^2 (1 + z) / 2 * DFT(B G)`` and the spectral covariance (per-sample units)
    ``dt^4 |1 + z|^2 / 4 Q_f + |1 - z|^4 R``; the Whittle information is
    ``2 sum_{f > 0} Re[dmu^H S^-1 dmu] / n``. Exact up to end effects for a record holding a whole
    number of maneuver periods.

    Returns
    -------
    numpy.ndarray
        (3, 3) information [per (rad s^-2 V^-1)^2].
    """
    a = np.asarray(omega_dot, dtype=np.float64)
    n = a.shape[0]
    c = instrument.c(grs_id)
    g = np.asarray(scale_factors, dtype=np.float64)
    u = (a @ c.T) / g[None, :]  # noise-free voltage differences (TMRF phi, theta, psi order)
    dt = instrument.dt_s
    freq = np.fft.rfftfreq(n, dt)
    z = np.exp(-2j * np.pi * freq * dt)
    mean_gain = dt * dt * 0.5 * (1.0 + z)
    q_f = instrument.angular_noise_crf(grs_id)
    r = np.diag(instrument.noise.star_tracker_variance())
    spectra = np.stack([np.fft.rfft(np.outer(u[:, j], c.T[:, j]), axis=0) for j in range(3)], axis=2)  # (f, 3, 3)
    info = np.zeros((3, 3))
    for k in range(1, freq.size - (1 if n % 2 == 0 else 0)):
        s = abs(mean_gain[k]) ** 2 * q_f + abs(1.0 - z[k]) ** 4 * r
        d_mu = mean_gain[k] * spectra[k]
        info += 2.0 * np.real(d_mu.conj().T @ np.linalg.solve(s, d_mu)) / n
    return 0.5 * (info + info.T)
