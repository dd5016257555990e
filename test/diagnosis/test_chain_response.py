"""The chain's high-frequency response (diagnosis/dynamics.py): its six terms recovered from a square-wave torque
residual above f_max, and removed there.

Seeded; tolerances are stated where they are used.
"""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS
from taiji2_estimator_pkg.diagnosis.dynamics import _columns, fit_response

DT_S = 0.1
N = 36000
F_MAX_HZ = 0.2
SIGMA = 1e-10  # white torque-channel noise per sample [rad s^-2]
TORQUE = CHANNELS.index("torque_x")


def _square_waves() -> np.ndarray:
    """(N, 3) predicted angular acceleration: 250-s square waves of 5, 5 and 20 sigma, z's steps between samples
    of the others' (its phase 31.25 s)."""
    t = DT_S * np.arange(N)
    phases = np.array([0.0, 62.5, 31.25])
    levels = np.array([5.0, 5.0, 20.0]) * SIGMA
    return levels * np.where(((t[:, None] - phases) % 250.0) < 125.0, 1.0, -1.0)


def test_the_six_response_terms_are_recovered_and_removed_above_f_max():
    """Each axis's residual is the predicted acceleration through R(f) - 1 with all six terms (the values the
    reference fidelity gave in blind seed 16, set 87) plus white noise: every coefficient within 4 sigma of the
    truth, and the torque channel above f_max left white (its whitened power per real degree of freedom within
    5 sigma of 1: 1 +- 5 sqrt(2 / dof))."""
    rng = np.random.default_rng(12)
    acc = _square_waves()
    truth = np.array([[0.100, -0.135, -0.059, 0.0018, -0.0031, 0.0134],  # TERMS: b1, b2, b3, delays [s]
                      [0.109, -0.129, -0.058, 0.0021, -0.0048, 0.0141],
                      [0.112, -0.140, -0.062, 0.0026, -0.0044, 0.0136]])
    residual = np.zeros((N, 15))
    for axis in range(3):
        residual[:, TORQUE + axis] = _columns(acc[:, axis], DT_S) @ truth[axis] + SIGMA * rng.standard_normal(N)
    psd = np.full((N // 2, 3), SIGMA ** 2)
    cleaned, fit = fit_response(residual, acc, (0, 0), DT_S, F_MAX_HZ, psd)
    assert np.all(np.abs(fit.coefficients - truth) < 4.0 * fit.sigma), (fit.coefficients, fit.sigma)
    assert np.all(fit.sigma[2, [2, 5]] < 0.2 * np.abs(truth[2, [2, 5]])), fit.sigma  # resolved (5 sigma), not bounded
    high = np.arange(1, N // 2 + 1) / (N * DT_S) > F_MAX_HZ
    for axis in range(3):
        power = np.abs(np.fft.rfft(cleaned[:, TORQUE + axis])[1:][high]) ** 2 / (N * SIGMA ** 2)
        dof = 2 * int(high.sum())
        assert abs(2.0 * power.sum() / dof - 1.0) < 5.0 * np.sqrt(2.0 / dof), axis


def test_without_the_higher_terms_their_residual_is_left():
    """The same z data fitted with b1, b2 and delta only leave the higher terms' residual above f_max: its
    chi-square exceeds the six-term fit's by more than 100 (about 10 sigma for three parameters): the terms are
    needed, not decorative."""
    rng = np.random.default_rng(13)
    columns = _columns(_square_waves()[:, 2], DT_S)
    y = columns @ np.array([0.112, -0.140, -0.062, 0.0026, -0.0044, 0.0136]) + SIGMA * rng.standard_normal(N)
    high = np.arange(1, N // 2 + 1) / (N * DT_S) > F_MAX_HZ
    x = np.fft.rfft(columns, axis=0)[1:][high] / np.sqrt(N * SIGMA ** 2 / 2.0)  # unit variance per real part
    target = np.fft.rfft(y)[1:][high] / np.sqrt(N * SIGMA ** 2 / 2.0)

    def chi2(terms: list[int]) -> float:
        design = np.concatenate((x[:, terms].real, x[:, terms].imag))
        stacked = np.concatenate((target.real, target.imag))
        beta, *_ = np.linalg.lstsq(design, stacked, rcond=None)
        return float(np.sum((stacked - design @ beta) ** 2))

    assert chi2([0, 1, 3]) - chi2(list(range(6))) > 100.0, (chi2([0, 1, 3]), chi2(list(range(6))))
