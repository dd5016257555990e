"""High-frequency response of the command-to-GRS chain: calibrated above the fit band, not diagnosed.

The nominal model predicts each GRS angular sample as the integrating (boxcar) readout of the
thrust. A real readout is an anti-alias filter of its own, and real thrusters have rise times the
timing candidates describe only to first order: predicted and measured angular accelerations then
differ at the maneuver's harmonics above ~0.3 Hz by a few percent of a signal that is tens of sigma
per bin there, and a timing magnitude fitted in the fit band (below ``f_max``, where it is robust)
leaves, at a few hundred microseconds off, a residual of the same kind. Like the scale factor (the
chain's response at 0 Hz), the response above the fit band is instrument calibration: per axis,

    R(f) - 1 = b1 x - b2 x^2 - i delta sin(2 pi f dt) / dt,   x = (2 sin(pi f dt))^2,

the centred second and fourth differences and the centred first difference of the predicted
angular acceleration, is fitted by weighted least squares to the torque channel's bins above
``f_max`` only, and removed there before the location scan. Below ``f_max`` nothing changes: the
timing and physical candidates are selected and located there, and a delay the model lacks still
shows as a gap in the torque channel at the maneuver's harmonics below f_max. The cost: an effect
that only shows in the torque channel above f_max is not located. b1, b2 and delta (a residual
delay of the chain above f_max [s]) are reported with the calibration.
"""

from __future__ import annotations

import math

import numpy as np

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS

__all__ = ["ResponseFit", "fit_response"]

_TORQUE = CHANNELS.index("torque_x")


class ResponseFit:
    """Fitted response coefficients per axis.

    Attributes
    ----------
    coefficients : numpy.ndarray
        (3, 3) b1, b2, delta [s] per CRF axis.
    sigma : numpy.ndarray
        (3, 3) their 1-sigma.
    dt_s : float
        Sample interval [s].
    """

    def __init__(self, coefficients: np.ndarray, sigma: np.ndarray, dt_s: float) -> None:
        self.coefficients = coefficients
        self.sigma = sigma
        self.dt_s = dt_s

    def amplitude_minus_one(self, frequency_hz: float) -> np.ndarray:
        """(3,) |R(f)| - 1 per axis, to first order, at ``frequency_hz``."""
        x = (2.0 * math.sin(math.pi * frequency_hz * self.dt_s)) ** 2
        return self.coefficients[:, 0] * x - self.coefficients[:, 1] * x * x

    def to_dict(self) -> dict[str, object]:
        """Report entry."""
        return {"b1": self.coefficients[:, 0].tolist(), "b2": self.coefficients[:, 1].tolist(),
                "delay_s": self.coefficients[:, 2].tolist(), "b1_sigma": self.sigma[:, 0].tolist(),
                "b2_sigma": self.sigma[:, 1].tolist(), "delay_sigma_s": self.sigma[:, 2].tolist(),
                "amplitude_minus_one_at_1hz": self.amplitude_minus_one(1.0).tolist()}


def _columns(acc: np.ndarray, dt_s: float) -> np.ndarray:
    """(n, 3) -second difference, -fourth difference, -first difference / dt of one axis (zero at the ends)."""
    n = acc.shape[0]
    out = np.zeros((n, 3))
    out[1:-1, 0] = -(acc[2:] - 2.0 * acc[1:-1] + acc[:-2])
    out[2:-2, 1] = -(acc[4:] - 4.0 * acc[3:-1] + 6.0 * acc[2:-2] - 4.0 * acc[1:-3] + acc[:-4])
    out[1:-1, 2] = -(acc[2:] - acc[:-2]) / (2.0 * dt_s)
    return out


def fit_response(residual: np.ndarray, acc_pred: np.ndarray, edges: tuple[int, int], dt_s: float,
                 f_max_hz: float, torque_psd: np.ndarray) -> tuple[np.ndarray, ResponseFit]:
    """Fit the chain's response to the torque channel above ``f_max_hz`` and remove it there.

    Parameters
    ----------
    residual : numpy.ndarray
        (n, 15) residual channels (all frequencies).
    acc_pred : numpy.ndarray
        (n, 3) angular acceleration the model predicts (commands, timing and fitted columns) [rad s^-2].
    edges : tuple of int
        Samples at the start and end left out of the torque channel.
    dt_s : float
        Sample interval [s].
    f_max_hz : float
        Upper edge of the fit band [Hz]: only bins above it are fitted and changed.
    torque_psd : numpy.ndarray
        (n // 2, 3) nominal spectrum of the torque channels at bins 1 .. n // 2 (weights).

    Returns
    -------
    residual : numpy.ndarray
        A copy with the fitted response removed from the torque channel above ``f_max_hz``.
    fit : ResponseFit
    """
    out = residual.copy()
    n = residual.shape[0]
    coefficients = np.zeros((3, 3))
    sigma = np.zeros((3, 3))
    bins = np.arange(1, n // 2 + 1)
    high = bins * (1.0 / (n * dt_s)) > f_max_hz
    if n < 8 or not np.any(high):
        return out, ResponseFit(coefficients, sigma, dt_s)
    head, tail = edges
    keep = np.ones(n, dtype=bool)
    keep[:head + 2] = False
    keep[n - tail - 2:] = False
    for axis in range(3):
        x = _columns(acc_pred[:, axis], dt_s)
        x[~keep] = 0.0
        x_fft = np.fft.rfft(x, axis=0)[1:][high]
        y_full = np.fft.rfft(residual[:, _TORQUE + axis])
        y_fft = y_full[1:][high]
        weight = 1.0 / np.sqrt(np.maximum(torque_psd[high, axis] * n, 1e-300))
        design = np.concatenate(((x_fft * weight[:, None]).real, (x_fft * weight[:, None]).imag))
        target = np.concatenate(((y_fft * weight).real, (y_fft * weight).imag))
        gram = design.T @ design
        if np.linalg.matrix_rank(gram) < 3:
            continue
        beta = np.linalg.solve(gram, design.T @ target)
        coefficients[axis] = beta
        # real rows of unit variance per complex bin half: 1/2 each (the weights make |Y|^2 ~ 1)
        sigma[axis] = np.sqrt(np.maximum(np.diag(np.linalg.inv(gram)) * 0.5, 0.0))
        y_full[1:][high] -= x_fft @ beta
        out[:, _TORQUE + axis] = np.fft.irfft(y_full, n=n)
    return out, ResponseFit(coefficients, sigma, dt_s)
