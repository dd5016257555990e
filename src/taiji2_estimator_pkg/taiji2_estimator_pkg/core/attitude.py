"""Ground processing of the star tracker: attitude quaternions to small angles, rate, acceleration.

Small-angle attitude
--------------------
The star tracker reads q_k, the orientation of the CRF in the inertial frame (Hamilton, xyzw),
with a white small-angle error eps_k about the CRF axes: ``q_meas = q exp(eps / 2)``. The body
increment between consecutive readouts,

    delta_k = log(q_{k-1}^* q_k),

is the rotation ``omega_mid dt`` of the step (exact for the simulator's midpoint propagation, to
O(|omega|^2 dt^2) otherwise) plus ``eps_k - eps_{k-1}`` (to O(|eps| |delta|)). Their running sum

    phi_k = sum_{j <= k} delta_j        (phi_0 = 0 at the first accepted readout)

is therefore the integral of the body rate plus ``eps_k - eps_0``: a *linear* measurement of the
double integral of omega_dot, however far the attitude drifts (the rotation vector of
``q_0^* q_k`` is not: it differs from the integral by O(|phi|^2) coning terms, 1e-6 rad after 3 h
of the nominal maneuver). Sign continuity is automatic (``log`` takes the shortest rotation, q and
-q give the same increment); a gap is bridged by the increment across it.

Smoothing derivative (the paper's method)
-----------------------------------------
Rate and acceleration from phi by Savitzky-Golay derivative filters (least-squares polynomial of
order ``polyorder`` over a centred window of ``window`` samples). The acceleration kernel c
annihilates constants and ramps, so ``sum_j c_j phi_{k+j} = sum_i g_i a_{k+i}`` exactly, where a_i
is the mean angular acceleration over (t_{i-1}, t_i] (what a GRS sample is) and

    g_i = dt^2 sum_{j >= i} c_j (j - i + 1/2),   i = -m+1 .. m.

Filtering the GRS side with g (not with a plain smoother) gives both sides of the paper's
regression exactly the same transfer function. White star-tracker noise sigma propagates to a
per-sample standard deviation ``sigma ||c||`` (correlated over the window; the paper's filter
treats it as white, which is why its covariance is too small).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "AttitudeIntegrator",
    "SmoothingDerivative",
    "attitude_increments",
    "increment_scalar",
    "integrate_attitude",
    "quat_conjugate",
    "quat_multiply",
    "rotvec_from_quat",
]


def quat_multiply(q_a: ArrayLike, q_b: ArrayLike) -> np.ndarray:
    """Hamilton product ``q_a q_b`` of (..., 4) xyzw quaternions."""
    a = np.asarray(q_a, dtype=np.float64)
    b = np.asarray(q_b, dtype=np.float64)
    ax, ay, az, aw = (a[..., i] for i in range(4))
    bx, by, bz, bw = (b[..., i] for i in range(4))
    return np.stack((aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz), axis=-1)


def quat_conjugate(q: ArrayLike) -> np.ndarray:
    """Conjugate of (..., 4) xyzw quaternions."""
    out = np.array(q, dtype=np.float64, copy=True)
    out[..., :3] *= -1.0
    return out


def rotvec_from_quat(q: ArrayLike) -> np.ndarray:
    """Rotation vector [rad] of (..., 4) unit quaternions, angle in [0, pi]; q and -q agree."""
    q = np.asarray(q, dtype=np.float64)
    sign = np.where(q[..., 3:4] < 0.0, -1.0, 1.0)
    vector = q[..., :3] * sign
    scalar = q[..., 3] * sign[..., 0]
    sine = np.sqrt(np.sum(vector * vector, axis=-1))
    safe = np.where(sine > 0.0, sine, 1.0)
    ratio = np.where(sine > 0.0, np.arctan2(sine, scalar) / safe, 1.0 / np.where(scalar > 0, scalar, 1.0))
    return 2.0 * ratio[..., None] * vector


def attitude_increments(quat_xyzw: ArrayLike) -> np.ndarray:
    """Body increments ``log(q_{k-1}^* q_k)`` of consecutive quaternions.

    Parameters
    ----------
    quat_xyzw : array_like
        (n, 4) attitude readouts (any sign, unit norm).

    Returns
    -------
    numpy.ndarray
        (n - 1, 3) increments in CRF [rad].
    """
    q = np.asarray(quat_xyzw, dtype=np.float64)
    return rotvec_from_quat(quat_multiply(quat_conjugate(q[:-1]), q[1:]))


def increment_scalar(q_prev: tuple[float, ...] | np.ndarray, q: tuple[float, ...] | np.ndarray
                     ) -> tuple[float, float, float]:
    """``log(q_prev^* q)`` of two single quaternions, in plain floats (fast per-sample path).

    Same formulas as :func:`attitude_increments` (and, to rounding, the same numbers).
    """
    ax, ay, az, aw = -float(q_prev[0]), -float(q_prev[1]), -float(q_prev[2]), float(q_prev[3])
    bx, by, bz, bw = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    w = aw * bw - ax * bx - ay * by - az * bz
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    sine = math.sqrt(x * x + y * y + z * z)
    ratio = math.atan2(sine, w) / sine if sine > 0.0 else (1.0 / w if w > 0.0 else 1.0)
    return 2.0 * ratio * x, 2.0 * ratio * y, 2.0 * ratio * z


def integrate_attitude(quat_xyzw: ArrayLike, valid: ArrayLike | None = None) -> np.ndarray:
    """Small-angle attitude phi (running sum of body increments) of a readout series.

    Parameters
    ----------
    quat_xyzw : array_like
        (n, 4) readouts; rows not ``valid`` are ignored.
    valid : array_like of bool, optional
        (n,) accepted readouts (default: all finite rows).

    Returns
    -------
    numpy.ndarray
        (n, 3) phi in CRF [rad], zero at the first valid readout, NaN on invalid rows; a gap is
        bridged by the increment across it.
    """
    q = np.asarray(quat_xyzw, dtype=np.float64)
    ok = np.all(np.isfinite(q), axis=-1) if valid is None else np.asarray(valid, dtype=bool)
    phi = np.full((q.shape[0], 3), np.nan)
    index = np.flatnonzero(ok)
    if index.size == 0:
        return phi
    increments = attitude_increments(q[index])
    phi[index[0]] = 0.0
    phi[index[1:]] = np.cumsum(increments, axis=0)
    return phi


class AttitudeIntegrator:
    """Per-sample version of :func:`integrate_attitude` (same numbers, sample by sample).

    Examples
    --------
    >>> integrator = AttitudeIntegrator()
    >>> phi = integrator.add([0.0, 0.0, 0.0, 1.0])   # first readout: phi = 0
    """

    def __init__(self) -> None:
        self._last: np.ndarray | None = None
        self._phi = np.zeros(3)
        self._sum = np.zeros(3)

    @property
    def initialised(self) -> bool:
        """Whether a reference readout was accepted."""
        return self._last is not None

    @property
    def last_quaternion(self) -> np.ndarray | None:
        """Last accepted readout (4,) or None."""
        return None if self._last is None else self._last.copy()

    def add(self, quat_xyzw: ArrayLike) -> np.ndarray:
        """Accept one (already validated) readout; returns phi (3,) [rad] in CRF."""
        q = np.asarray(quat_xyzw, dtype=np.float64).reshape(4)
        if self._last is None:
            self._phi = np.zeros(3)
        else:
            # same arithmetic as the cumulative sum of the batch version
            self._phi = self._phi + np.array(increment_scalar(self._last, q))
        self._last = q.copy()
        return self._phi.copy()

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint."""
        return {"last": None if self._last is None else self._last.tolist(), "phi": self._phi.tolist()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a checkpoint of :meth:`state_dict`."""
        self._last = None if state["last"] is None else np.asarray(state["last"], dtype=np.float64)
        self._phi = np.asarray(state["phi"], dtype=np.float64)


@dataclass(frozen=True)
class SmoothingDerivative:
    """Savitzky-Golay smoothing derivative of the small-angle attitude (the paper's method).

    Parameters
    ----------
    window : int
        Odd window length 2m + 1 [samples].
    polyorder : int
        Polynomial order (>= 2).
    dt_s : float
        Sample interval [s].
    """

    window: int
    polyorder: int
    dt_s: float

    def __post_init__(self) -> None:
        if self.window < 5 or self.window % 2 == 0:
            raise ValueError(f"window: must be odd and >= 5, got {self.window}")
        if not 2 <= self.polyorder < self.window:
            raise ValueError(f"polyorder: must be in [2, window), got {self.polyorder}")
        # numerical self-check: the kernels must differentiate every monomial up to the order
        # exactly (long windows with high orders make the least-squares fit ill-conditioned)
        scale = self.half * self.dt_s
        s_norm = (np.arange(self.window) - self.half) * self.dt_s / scale
        acc, rate = self.acceleration_kernel(), self.rate_kernel()
        for power in range(self.polyorder + 1):
            monomial = s_norm**power
            if abs(float(acc @ monomial) * scale**2 - (2.0 if power == 2 else 0.0)) > 1e-6 or \
                    abs(float(rate @ monomial) * scale - (1.0 if power == 1 else 0.0)) > 1e-6:
                raise ValueError(f"window {self.window} with polyorder {self.polyorder}: Savitzky-Golay "
                                 "kernels numerically inaccurate, use a lower order or a shorter window")

    @property
    def half(self) -> int:
        """m: the output at sample k needs readouts up to k + m (delay m samples)."""
        return self.window // 2

    def rate_kernel(self) -> np.ndarray:
        """(2m + 1,) weights on phi_{k-m..k+m} giving omega_k [s^-1]."""
        from scipy.signal import savgol_coeffs  # the paper's method only

        return savgol_coeffs(self.window, self.polyorder, deriv=1, delta=self.dt_s, use="dot")

    def acceleration_kernel(self) -> np.ndarray:
        """(2m + 1,) weights on phi_{k-m..k+m} giving omega_dot_k [s^-2]."""
        from scipy.signal import savgol_coeffs  # the paper's method only

        return savgol_coeffs(self.window, self.polyorder, deriv=2, delta=self.dt_s, use="dot")

    def grs_kernel(self) -> np.ndarray:
        """(2m,) weights on the step-mean accelerations a_{k-m+1..k+m} equal to the acceleration kernel.

        ``sum_j c_j phi_{k+j} = sum_i g_i a_{k+i}`` exactly (see the module docstring).
        """
        c = self.acceleration_kernel()
        m = self.half
        j = np.arange(-m, m + 1, dtype=np.float64)
        g = np.empty(2 * m)
        for n, i in enumerate(range(-m + 1, m + 1)):
            mask = j >= i
            g[n] = np.sum(c[mask] * (j[mask] - i + 0.5))
        return g * self.dt_s**2

    def acceleration_noise_gain(self) -> float:
        """||c||: white phi noise sigma [rad] gives the per-sample std sigma ||c|| [rad s^-2]."""
        return float(np.linalg.norm(self.acceleration_kernel()))

    def rate_noise_gain(self) -> float:
        """||c_1||: white phi noise sigma [rad] gives the per-sample rate std sigma ||c_1|| [rad/s]."""
        return float(np.linalg.norm(self.rate_kernel()))

    # bulk ---------------------------------------------------------------------------------------
    def apply_attitude(self, phi: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Rate and acceleration of a contiguous phi series.

        Parameters
        ----------
        phi : array_like
            (n, 3) small-angle attitude [rad] (no gaps).

        Returns
        -------
        rate : numpy.ndarray
            (n, 3) [rad/s]; NaN within m samples of either end.
        acceleration : numpy.ndarray
            (n, 3) [rad s^-2]; NaN within m samples of either end.
        """
        phi = np.asarray(phi, dtype=np.float64)
        return (_centred_dot(phi, self.rate_kernel(), self.half, self.half),
                _centred_dot(phi, self.acceleration_kernel(), self.half, self.half))

    def apply_grs(self, samples: ArrayLike) -> np.ndarray:
        """GRS-side smoothing: ``sum_i g_i x_{k+i}``, i = -m+1..m, of a contiguous (n, ...) series.

        Returns NaN where the window is incomplete (first m - 1 and last m samples).
        """
        return _centred_dot(np.asarray(samples, dtype=np.float64), self.grs_kernel(), self.half - 1, self.half)


def _centred_dot(x: np.ndarray, kernel: np.ndarray, before: int, after: int) -> np.ndarray:
    """``out_k = sum_i kernel[i] x[k - before + i]``; NaN where the window leaves the series."""
    n = x.shape[0]
    out = np.full(x.shape, np.nan)
    length = kernel.size
    if n < length:
        return out
    flat = x.reshape(n, -1)
    valid = np.empty((n - length + 1, flat.shape[1]))
    for column in range(flat.shape[1]):
        # correlate: sum_i kernel[i] x[k + i]
        valid[:, column] = np.correlate(flat[:, column], kernel, mode="valid")
    out.reshape(n, -1)[before:n - after] = valid
    return out
