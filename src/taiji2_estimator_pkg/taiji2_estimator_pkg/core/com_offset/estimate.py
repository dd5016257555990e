"""The result of a c.m.-offset estimator: d of one or two GRS with its covariances."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.estimate_blocks import PerGrsBlocks


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
