"""Star-tracker measurement model.

The star tracker reads the instantaneous attitude q (orientation of the CRF in the inertial frame)
at the sample time with a white small-angle error delta about the CRF axes:
``q_meas = q_true exp(delta / 2)``, i.e. the error rotation acts in the body frame, which is what
the contract's covariance "about CRF X, Y, Z" describes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.frames import quat_conjugate, quat_from_rotvec, quat_multiply, rotvec_from_quat

__all__ = ["attitude_error_rad", "star_tracker_covariance_rad2", "star_tracker_measurement"]


def star_tracker_measurement(quat_true_xyzw: ArrayLike, error_rad: ArrayLike) -> np.ndarray:
    """Measured attitude ``q_true exp(delta / 2)``.

    Parameters
    ----------
    quat_true_xyzw : array_like
        (..., 4) true attitude.
    error_rad : array_like
        (..., 3) small-angle error delta about CRF X, Y, Z [rad].

    Returns
    -------
    numpy.ndarray
        (..., 4) measured attitude (unit norm).
    """
    return quat_multiply(quat_true_xyzw, quat_from_rotvec(error_rad))


def attitude_error_rad(quat_measured_xyzw: ArrayLike, quat_true_xyzw: ArrayLike) -> np.ndarray:
    """Inverse of :func:`star_tracker_measurement`: ``delta = log(q_true* q_meas)`` [rad], (..., 3)."""
    return rotvec_from_quat(quat_multiply(quat_conjugate(quat_true_xyzw), quat_measured_xyzw))


def star_tracker_covariance_rad2(sigma_rad: ArrayLike) -> np.ndarray:
    """Reported covariance ``diag(sigma^2)`` about CRF X, Y, Z, row-major (9,) [rad^2]."""
    sigma = np.asarray(sigma_rad, dtype=np.float64).reshape(3)
    return np.diag(sigma * sigma).reshape(9)
