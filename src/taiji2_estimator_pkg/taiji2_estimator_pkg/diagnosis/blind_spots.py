"""Blind spots: how far an effect too small to be found on these data could still move G and d.

"No significant gap" is not "no bias": a catalog effect just below the detection threshold can move the
calibration by several of its sigma (a GRS imbalance biasing G by 5-7 sigma, unseen, in the corrected-
calibration benchmark). This says, for each effect family, how far.

For a variant with parameters theta (p of them) fitted jointly with the final model's columns (G and d
first), let Sigma be that joint fit's covariance. Left out of the model, the variant at theta moves the
calibration by (the regression of the calibration on the omitted columns)

    delta beta = -Sigma_(beta theta) Sigma_(theta theta)^-1 theta,

and it raises the chi-square the selection sees by ``theta^T Sigma_(theta theta)^-1 theta``; the selection
(:mod:`.stages.selection`) names it once that gain passes ``g* = max(floor_p, p ln N)``. Over every theta
with that noncentrality, the largest move of calibration parameter i is

    |delta beta_i| = sqrt(g*) sqrt(Sigma_(i theta) Sigma_(theta theta)^-1 Sigma_(theta i)),

and the calibration's own 1-sigma without the variant in the model is

    sigma_i^2 = Sigma_ii - Sigma_(i theta) Sigma_(theta theta)^-1 Sigma_(theta i).

Their ratio is the blind spot of parameter i: an effect of that variant at the detection threshold (found
about half the time) biases parameter i by that many sigma while the verdict may read "no significant gap".
First order in the effect (its signature linearised at zero); the nominal calibration's sigma, not the
star-tracker method's (``taiji2 calibrate``), which the torque and inertia effects do not reach.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate
from taiji2_estimator_pkg.diagnosis.record import Record

__all__ = ["CALIBRATION_PARAMETERS", "BlindSpot", "blind_spots", "detection_gain"]

CALIBRATION_PARAMETERS = 12
"""G (6, relative) and d (6) lead every fit's columns (:func:`.channels.nuisance_names`)."""


@dataclass(frozen=True)
class BlindSpot:
    """The worst variant of one effect family on these data.

    Attributes
    ----------
    family, variant : str
        The variant.
    parameter : str
        The calibration parameter it moves most (``G.2.psi``, ``d.1.x``).
    bias_sigma : float
        How far an effect of this variant at the detection threshold moves that parameter, in the
        calibration's sigma.
    magnitude, unit : float, str
        The variant's magnitude at the detection threshold (``sqrt(g*)`` of its 1-sigma) and its unit.
    detection_gain : float
        ``g*``: the delta chi2 the selection needs to name it.
    """

    family: str
    variant: str
    parameter: str
    bias_sigma: float
    magnitude: float
    unit: str
    detection_gain: float

    def to_dict(self) -> dict[str, Any]:
        """Report entry."""
        return {"family": self.family, "variant": self.variant, "parameter": self.parameter,
                "bias_sigma": self.bias_sigma, "magnitude_at_threshold": self.magnitude, "unit": self.unit,
                "detection_gain": self.detection_gain}


def detection_gain(n_params: int, floor: Mapping[int, float], log_n: float) -> float:
    """``g*``: the gain a variant of ``n_params`` parameters needs to be named (positive BIC score and the
    Bonferroni floor, :mod:`.stages.selection`)."""
    return max(floor.get(n_params, max(floor.values())), n_params * log_n)


def blind_spots(full: Record, candidates: Sequence[Candidate], current: Sequence[str], floor: Mapping[int, float],
                log_n: float) -> list[BlindSpot]:
    """The worst blind spot of every family not in ``current`` (see the module doc), largest first.

    Parameters
    ----------
    full : Record
        The fitting workspace (final model's signatures).
    candidates : sequence of Candidate
        The catalog's variants; those with columns in ``current`` (named) are skipped.
    current : sequence of str
        Columns of the final model (G and d first).
    floor : mapping of int to float
        The selection's gain floor per parameter count.
    log_n : float
        ln N of the BIC penalty.

    Returns
    -------
    list of BlindSpot
    """
    in_model = set(current)
    worst: dict[str, BlindSpot] = {}
    for candidate in candidates:
        columns = candidate.column_names()
        if in_model.intersection(columns):
            continue
        _, cov, _ = full.fit(list(current) + columns)
        p = len(columns)
        cross = cov[:CALIBRATION_PARAMETERS, -p:]  # Sigma_(beta theta)
        info = np.linalg.pinv(cov[-p:, -p:])  # Sigma_(theta theta)^-1
        explained = np.einsum("ia,ab,ib->i", cross, info, cross)
        own = np.diag(cov)[:CALIBRATION_PARAMETERS] - explained
        gain = detection_gain(candidate.n_params, floor, log_n)
        ratio = np.sqrt(gain * np.maximum(explained, 0.0) / np.maximum(own, 1e-300))
        i = int(np.argmax(ratio))
        _, sigma = candidate.magnitude(np.zeros(p), cov[-p:, -p:])
        spot = BlindSpot(candidate.name, candidate.variant, current[i], float(ratio[i]), math.sqrt(gain) * sigma,
                         candidate.unit, gain)
        if candidate.name not in worst or spot.bias_sigma > worst[candidate.name].bias_sigma:
            worst[candidate.name] = spot
    return sorted(worst.values(), key=lambda spot: -spot.bias_sigma)
