"""The result of a scale-factor estimator, and the report of one per-sample update."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.estimate_blocks import PerGrsBlocks


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
