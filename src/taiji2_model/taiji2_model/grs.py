"""Gravitational reference sensor readout model and voltage conversion.

In accelerometer mode each GRS reads, in its TMRF_i (physics.md):

- angular ``(G_Pphi (vy1 - vy2), G_Ptheta (vz1 - vz2), G_Ppsi (vx1 - vx2)) = C_i omega_dot``
- linear ``(G_Px (vx1 + vx2), G_Py (vy1 + vy2), G_Pz (vz1 + vz2))
  = C_i (a_SC + omega_dot x d_i + omega x (omega x d_i))``

plus readout noise. Voltage channels are ordered ``vx1, vx2, vy1, vy2, vz1, vz2``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.frames import cross

__all__ = [
    "VOLTAGE_CHANNELS",
    "a_tilde_matrix",
    "accelerations_from_voltages",
    "coupling_acceleration_m_s2",
    "linear_scale_factors_from_angular",
    "saturate_linear_readout",
    "voltages_from_accelerations",
]

VOLTAGE_CHANNELS = ("vx1", "vx2", "vy1", "vy2", "vz1", "vz2")
"""Order of the six electrode channels in every voltage array."""


def linear_scale_factors_from_angular(angular_scale_factors: ArrayLike, ratio_m: float) -> np.ndarray:
    """The paper's consistent linear conversion of the scale factors.

    Parameters
    ----------
    angular_scale_factors : array_like
        (..., 3) (G_Pphi, G_Ptheta, G_Ppsi) [rad s^-2 V^-1].
    ratio_m : float
        r = J_TM / (m_TM l) = a^2 / (6 l) [m].

    Returns
    -------
    numpy.ndarray
        (..., 3) (G_Px, G_Py, G_Pz) = r (G_Ppsi, G_Pphi, G_Ptheta) [m s^-2 V^-1]: each linear axis
        shares its electrode pair with the angle whose difference uses that pair.
    """
    angular = np.asarray(angular_scale_factors, dtype=np.float64)
    return ratio_m * angular[..., [2, 0, 1]]


def coupling_acceleration_m_s2(omega_dot_rad_s2: ArrayLike, omega_rad_s: ArrayLike,
                               com_offset_m: ArrayLike) -> np.ndarray:
    """Rotational coupling ``A~ d = omega_dot x d + omega x (omega x d)`` in CRF.

    Parameters
    ----------
    omega_dot_rad_s2 : array_like
        (..., 3) angular acceleration in CRF [rad s^-2].
    omega_rad_s : array_like
        (..., 3) angular rate in CRF [rad/s].
    com_offset_m : array_like
        (..., 3) d: TM c.m. relative to the spacecraft c.m., CRF [m].

    Returns
    -------
    numpy.ndarray
        (..., 3) acceleration [m s^-2] in CRF.
    """
    omega = np.asarray(omega_rad_s, dtype=np.float64)
    offset = np.asarray(com_offset_m, dtype=np.float64)
    return cross(omega_dot_rad_s2, offset) + cross(omega, cross(omega, offset))


def a_tilde_matrix(omega_rad_s: ArrayLike, omega_dot_rad_s2: ArrayLike) -> np.ndarray:
    """The paper's matrix A~ with ``A~ d = omega_dot x d + omega x (omega x d)``.

    Parameters
    ----------
    omega_rad_s : array_like
        (..., 3) angular rate in CRF [rad/s].
    omega_dot_rad_s2 : array_like
        (..., 3) angular acceleration in CRF [rad s^-2].

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) [s^-2].
    """
    w = np.asarray(omega_rad_s, dtype=np.float64)
    a = np.asarray(omega_dot_rad_s2, dtype=np.float64)
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    rows = (
        (-wy * wy - wz * wz, wx * wy - az, wx * wz + ay),
        (wx * wy + az, -wx * wx - wz * wz, wz * wy - ax),
        (wx * wz - ay, wz * wy + ax, -wy * wy - wx * wx),
    )
    out = np.empty((*np.broadcast_shapes(w.shape, a.shape)[:-1], 3, 3))
    for i, row in enumerate(rows):
        for j, entry in enumerate(row):
            out[..., i, j] = entry
    return out


def voltages_from_accelerations(angular_rad_s2: ArrayLike, linear_m_s2: ArrayLike,
                                angular_scale_factors: ArrayLike,
                                linear_scale_factors: ArrayLike) -> np.ndarray:
    """Electrode voltages that read the given TMRF accelerations (noise-free conversion).

    Solves ``(vy1 - vy2) = phi/G_Pphi``, ``(vz1 - vz2) = theta/G_Ptheta``,
    ``(vx1 - vx2) = psi/G_Ppsi``, ``(vx1 + vx2) = x/G_Px``, ``(vy1 + vy2) = y/G_Py``,
    ``(vz1 + vz2) = z/G_Pz`` for the six channels.

    Parameters
    ----------
    angular_rad_s2 : array_like
        (..., 3) (phi, theta, psi) angular acceleration in TMRF [rad s^-2].
    linear_m_s2 : array_like
        (..., 3) (x, y, z) linear acceleration in TMRF [m s^-2].
    angular_scale_factors : array_like
        (..., 3) (G_Pphi, G_Ptheta, G_Ppsi) [rad s^-2 V^-1].
    linear_scale_factors : array_like
        (..., 3) (G_Px, G_Py, G_Pz) [m s^-2 V^-1].

    Returns
    -------
    numpy.ndarray
        (..., 6) vx1, vx2, vy1, vy2, vz1, vz2 [V].
    """
    angular = np.asarray(angular_rad_s2, dtype=np.float64)
    linear = np.asarray(linear_m_s2, dtype=np.float64)
    # differences per electrode axis x, y, z: psi, phi, theta
    angular_sf = np.asarray(angular_scale_factors, dtype=np.float64)
    difference_v = angular[..., [2, 0, 1]] / angular_sf[..., [2, 0, 1]]
    sum_v = linear / np.asarray(linear_scale_factors, dtype=np.float64)
    out = np.empty((*np.broadcast_shapes(sum_v.shape, difference_v.shape)[:-1], 6))
    out[..., 0::2] = 0.5 * (sum_v + difference_v)  # vx1, vy1, vz1
    out[..., 1::2] = 0.5 * (sum_v - difference_v)  # vx2, vy2, vz2
    return out


def accelerations_from_voltages(voltages_v: ArrayLike, angular_scale_factors: ArrayLike,
                                linear_scale_factors: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """The paper's conversion of electrode voltages to TMRF accelerations.

    Parameters
    ----------
    voltages_v : array_like
        (..., 6) vx1, vx2, vy1, vy2, vz1, vz2 [V].
    angular_scale_factors : array_like
        (..., 3) (G_Pphi, G_Ptheta, G_Ppsi) [rad s^-2 V^-1].
    linear_scale_factors : array_like
        (..., 3) (G_Px, G_Py, G_Pz) [m s^-2 V^-1].

    Returns
    -------
    angular_rad_s2 : numpy.ndarray
        (..., 3) ``(G_Pphi (vy1 - vy2), G_Ptheta (vz1 - vz2), G_Ppsi (vx1 - vx2))``.
    linear_m_s2 : numpy.ndarray
        (..., 3) ``(G_Px (vx1 + vx2), G_Py (vy1 + vy2), G_Pz (vz1 + vz2))``.
    """
    volts = np.asarray(voltages_v, dtype=np.float64)
    first = volts[..., 0::2]  # vx1, vy1, vz1
    second = volts[..., 1::2]  # vx2, vy2, vz2
    difference_v = first - second  # per electrode axis x, y, z
    sum_v = first + second
    angular = np.asarray(angular_scale_factors, dtype=np.float64) * difference_v[..., [1, 2, 0]]
    linear = np.asarray(linear_scale_factors, dtype=np.float64) * sum_v
    return angular, linear


def saturate_linear_readout(voltages_v: np.ndarray, linear_scale_factors: ArrayLike, range_m_s2: float) -> np.ndarray:
    """Clip the linear readout of every axis at the range, in place: the GRS saturates there.

    On each electrode axis the sum ``s = v1 + v2`` (the linear readout ``G_P,lin s``) is limited to
    ``|G_P,lin s| <= range``; both channels move by half the excess, so the difference ``v1 - v2``
    (the angular readout) is unchanged. Samples inside the range are untouched (bitwise).

    Parameters
    ----------
    voltages_v : numpy.ndarray
        (..., 6) vx1, vx2, vy1, vy2, vz1, vz2 [V], writeable; modified in place.
    linear_scale_factors : array_like
        (..., 3) true (G_Px, G_Py, G_Pz) [m s^-2 V^-1], broadcastable to ``voltages_v[..., :3]``.
    range_m_s2 : float
        The range, +-range [m s^-2].

    Returns
    -------
    numpy.ndarray
        ``voltages_v``.
    """
    first = voltages_v[..., 0::2]  # vx1, vy1, vz1 (views)
    second = voltages_v[..., 1::2]
    total = first + second
    limit = range_m_s2 / np.abs(np.asarray(linear_scale_factors, dtype=np.float64))
    excess = total - np.clip(total, -limit, limit)
    outside = excess != 0.0
    if np.any(outside):
        half = 0.5 * excess
        first -= np.where(outside, half, 0.0)
        second -= np.where(outside, half, 0.0)
    return voltages_v
