"""The noise level of the linear channels, measured in the band that carries d.

The c.m.-offset estimator weights and bounds d with a noise model (thruster force noise common to
both GRS, SRP, readout, errors in variables). In flight that model is known to a factor of about
two, and data from elsewhere may differ in ways no switch names. The d information sits at the
maneuver's low harmonics (for a 250-s square wave 96 % of it below 0.04 Hz), so what matters is
the noise level *there*, not the per-sample variance (an anti-alias filter that removes the noise
between 4 and 5 Hz lowers the latter by 20 % and changes nothing for d).

Measured from the post-fit innovations ``e_k`` of the steady-state filter, whitened with its
innovation covariance ``Lambda`` (``nu_k = L^T e_k``, ``Lambda^-1 = L L^T``; white with unit
covariance when the model is right). Means over blocks of B samples keep the band below about
``1 / (2 B dt)``; their covariance times B is the band covariance::

    C_band = B cov_blocks(mean nu)        (I when the model is right; 1/sqrt(n_blocks/2) scatter)

A ``C_band`` outside the scatter means the noise in that band differs from the model. The model's
R is then changed so that the whitened band covariance becomes I::

    R' = R + W^-1 (C_band - I) W^-T          (nu = W e, W = L^T)

(the SRP state part of Lambda is left as it is), and d is estimated again with R' (weights and
covariance follow the data). A filter whose R is too small lets its slow SRP state take up part of
the excess, so one measurement sees only part of it: the estimator repeats the step until the band
is white within its scatter (2-3 passes for a force noise at 2x PSD). The band NIS ``tr(C_band) / m`` is reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BLOCK_S", "BandNoise", "band_noise", "r_adjustment"]

#: length of a block mean [s] (the band below ~0.05 Hz, where d's information lies)
BLOCK_S = 10.0
#: an adjustment needs a departure beyond this many standard errors of the band covariance ...
SIGNIFICANCE = 5.0
#: ... and beyond this fraction (smaller departures change sigma by < 5 %)
MIN_DEPARTURE = 0.1


@dataclass(frozen=True)
class BandNoise:
    """Noise of the whitened post-fit innovations in the band that carries d.

    Attributes
    ----------
    covariance : numpy.ndarray
        (m, m) ``C_band`` (I if the model is right).
    n_blocks : int
        Blocks it was estimated from.
    nis : float
        ``tr(C_band) / m`` (band NIS per dof; 1 if consistent).
    significant : bool
        Whether an eigenvalue of ``C_band`` departs from 1 by more than both its scatter
        (``SIGNIFICANCE / sqrt(n_blocks / 2)``) and ``MIN_DEPARTURE``.
    """

    covariance: np.ndarray
    n_blocks: int
    nis: float
    significant: bool


def band_noise(whitened: np.ndarray, block_samples: int) -> BandNoise | None:
    """Band covariance of whitened innovations.

    Parameters
    ----------
    whitened : numpy.ndarray
        (L, m) whitened post-fit innovations, one row per consecutive epoch (NaN rows: not a regular
        epoch; a block containing one is not used).
    block_samples : int
        B: :data:`BLOCK_S` times the sample rate (100 at 10 Hz).

    Returns
    -------
    BandNoise or None
        None with fewer than 2 m usable blocks.
    """
    length, m = whitened.shape
    n_blocks = length // block_samples
    blocks = whitened[:n_blocks * block_samples].reshape(n_blocks, block_samples, m)
    usable = np.all(np.isfinite(blocks), axis=(1, 2))
    if np.count_nonzero(usable) < 2 * m:
        return None
    means = blocks[usable].mean(axis=1)
    count = means.shape[0]
    # the post-fit mean over all blocks is ~0 by construction: second moments about zero
    covariance = block_samples * (means.T @ means) / count
    covariance = 0.5 * (covariance + covariance.T)
    eig = np.linalg.eigvalsh(covariance)
    scatter = SIGNIFICANCE * math.sqrt(2.0 / count)
    departure = float(np.max(np.abs(eig - 1.0)))
    return BandNoise(covariance, count, float(np.trace(covariance) / m),
                     departure > max(scatter, MIN_DEPARTURE))


def r_adjustment(whitening: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``W^-1 (C_band - I) W^-T``: the change of R that whitens the band (m, m).

    ``W`` is the whitening the innovations were taken with (``nu = W e``, ``W Lambda W^T = I``), so
    the band covariance of e is ``W^-1 C_band W^-T``. ``C_band``'s eigenvalues are floored at 0.1 to
    keep R positive definite.
    """
    c_values, c_vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    c_floor = (c_vectors * np.maximum(c_values, 0.1)) @ c_vectors.T
    inverse = np.linalg.inv(whitening)
    out = inverse @ (c_floor - np.eye(covariance.shape[0])) @ inverse.T
    return 0.5 * (out + out.T)
