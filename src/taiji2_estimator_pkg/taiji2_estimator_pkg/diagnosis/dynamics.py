"""High-frequency response of the command-to-GRS chain: calibrated above the fit band, not diagnosed.

The nominal model predicts each GRS angular sample as the integrating (boxcar) readout of the
thrust. A real readout is an anti-alias filter of its own, and real thrusters have rise times the
timing candidates describe only to first order: predicted and measured angular accelerations then
differ at the maneuver's harmonics above ~0.3 Hz by a few percent of a signal that is tens of sigma
per bin there, and a timing magnitude fitted in the fit band (below ``f_max``, where it is robust)
leaves, at a few hundred microseconds off, a residual of the same kind. Like the scale factor (the
chain's response at 0 Hz), the response above the fit band is instrument calibration: per axis,

    R(f) - 1 = b1 x - b2 x^2 + b3 x^3 - i (delta + delta_x x + delta_xx x^2) sin(2 pi f dt) / dt,
    x = (2 sin(pi f dt))^2,

centred differences of the predicted angular acceleration (even part: the 2nd, 4th and 6th; odd part, a
residual delay that may change across the band: the 1st, 3rd and 5th), fitted by weighted least squares to
the torque channel's bins above ``f_max`` only, and removed there before the location scan. The terms beyond
b1, b2 and delta are what an anti-alias FIR after a thruster latency of a fraction of a sample needs (the
reference fidelity), the same on the three axes as a property of the chain should be: blind seed 16, set 87,
b3 = -0.059 to -0.062 (+- 0.0016 on z, the axis with the largest steps) and delta_xx = 0.0134-0.0141 s
(+- 0.0003 s); set 104, b3 = 0.023-0.032 and delta_xx = 0.0086-0.0102 s; in the standard fidelity (the
model's own chain) they are 0 within 1.6 sigma. Without them each command change of z left a residual of
-8.6, +4.3, -2 sigma in its samples, read as a 0.3-1 or 1-5 Hz torque_z gap in 6 of the 9 reference pairs of
blind seed 16 that were not fully explained; with them none of the 6 leaves a gap (5 have both effects
named; set 76 misses its 4.4-sigma c.m. drift). Below ``f_max`` nothing changes: the
timing and physical candidates are selected and located there, and a delay the model lacks still
shows as a gap in the torque channel at the maneuver's harmonics below f_max. The cost: an effect
that only shows in the torque channel above f_max is not located. The coefficients (delays in
seconds) are reported with the calibration (:data:`TERMS`).
"""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS

__all__ = ["TERMS", "ResponseFit", "fit_response"]

TERMS = ("b1", "b2", "b3", "delay_s", "delay_x_s", "delay_xx_s")
"""The response's coefficients, in the order of ``ResponseFit.coefficients`` (the delays [s])."""

_HALF_WIDTH = 4  # samples either side that the widest term (the 5th difference's x^2 D) reads, plus one

_TORQUE = CHANNELS.index("torque_x")


class ResponseFit:
    """Fitted response coefficients per axis.

    Attributes
    ----------
    coefficients : numpy.ndarray
        (3, 6) the :data:`TERMS` per CRF axis.
    sigma : numpy.ndarray
        (3, 6) their 1-sigma.
    dt_s : float
        Sample interval [s].
    """

    def __init__(self, coefficients: np.ndarray, sigma: np.ndarray, dt_s: float) -> None:
        self.coefficients = coefficients
        self.sigma = sigma
        self.dt_s = dt_s

    def amplitude_minus_one(self, frequency_hz: float) -> np.ndarray:
        """(3,) |R(f)| - 1 per axis, to first order (the real part of R - 1), at ``frequency_hz``."""
        return self.frequency_response_minus_one(np.array([frequency_hz]))[:, 0].real

    def frequency_response_minus_one(self, frequency_hz: np.ndarray) -> np.ndarray:
        """(3, m) R(f) - 1 per axis at the frequencies (m,) [Hz]."""
        f = np.asarray(frequency_hz, dtype=np.float64)
        x = (2.0 * np.sin(np.pi * f * self.dt_s)) ** 2
        b1, b2, b3, delta, delta_x, delta_xx = (self.coefficients[:, j, None] for j in range(len(TERMS)))
        odd = (delta + delta_x * x + delta_xx * x * x) * np.sin(2.0 * np.pi * f * self.dt_s) / self.dt_s
        return b1 * x - b2 * x * x + b3 * x ** 3 - 1j * odd

    def to_dict(self) -> dict[str, object]:
        """Report entry: each of :data:`TERMS` and its sigma (``b1_sigma``, ``delay_sigma_s``, ...)."""
        out: dict[str, object] = {}
        for j, name in enumerate(TERMS):
            sigma_name = name[:-2] + "_sigma_s" if name.endswith("_s") else name + "_sigma"
            out[name] = self.coefficients[:, j].tolist()
            out[sigma_name] = self.sigma[:, j].tolist()
        out["amplitude_minus_one_at_1hz"] = self.amplitude_minus_one(1.0).tolist()
        return out


def _x(a: np.ndarray) -> np.ndarray:
    """The operator of x = 2 - z - 1/z: ``2 a[k] - a[k+1] - a[k-1]`` (zero at the ends)."""
    out = np.zeros_like(a)
    out[1:-1] = 2.0 * a[1:-1] - a[2:] - a[:-2]
    return out


def _columns(acc: np.ndarray, dt_s: float) -> np.ndarray:
    """(n, 6) the terms of R(f) - 1 (:data:`TERMS`) applied to one axis: x a, -x^2 a, x^3 a, D a, x D a, x^2 D a,
    with D = -(z - 1/z) / (2 dt), the operator of -i sin(2 pi f dt) / dt (each zero near the ends)."""
    d = np.zeros_like(acc)
    d[1:-1] = -(acc[2:] - acc[:-2]) / (2.0 * dt_s)
    x1, xd = _x(acc), _x(d)
    x2 = _x(x1)
    return np.stack([x1, -x2, _x(x2), d, xd, _x(xd)], axis=1)


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
    coefficients = np.zeros((3, len(TERMS)))
    sigma = np.zeros((3, len(TERMS)))
    bins = np.arange(1, n // 2 + 1)
    high = bins * (1.0 / (n * dt_s)) > f_max_hz
    if n < 8 or not np.any(high):
        return out, ResponseFit(coefficients, sigma, dt_s)
    head, tail = edges
    keep = np.ones(n, dtype=bool)
    keep[:head + _HALF_WIDTH] = False
    keep[n - tail - _HALF_WIDTH:] = False
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
        if np.linalg.matrix_rank(gram) < len(TERMS):
            continue
        beta = np.linalg.solve(gram, design.T @ target)
        coefficients[axis] = beta
        # real rows of unit variance per complex bin half: 1/2 each (the weights make |Y|^2 ~ 1)
        sigma[axis] = np.sqrt(np.maximum(np.diag(np.linalg.inv(gram)) * 0.5, 0.0))
        y_full[1:][high] -= x_fft @ beta
        out[:, _TORQUE + axis] = np.fft.irfft(y_full, n=n)
    return out, ResponseFit(coefficients, sigma, dt_s)
