"""Angular scale factors G = (G_Pphi, G_Ptheta, G_Ppsi) of one or both GRS.

Two methods:

``paper`` (:class:`PaperScaleFactorFilter`)
    The paper's filter: per GRS a 3-state Kalman filter, Phi = I, Q = 0, Joseph update,
    ``H_k = C_i^-1 U~_k``, measurement = star-tracker angular acceleration from a smoothing
    derivative (Savitzky-Golay) of the attitude, the GRS side filtered with the equivalent kernel,
    diagonal R = the per-sample variance of the smoothed noise. Kept as the paper wrote it; its
    covariance treats strongly correlated samples as white and is far too small (reported, not
    fixed).

``gls`` (:class:`ScaleFactorEstimator`, default)
    A linear-Gaussian state space whose state is the small-angle attitude phi and rate omega
    (CRF), driven by the GRS angular acceleration ``a_k = sum_i W_i C_i^T diag(u_i,k) G_i``
    (fused over the GRS with the information weights ``W_i = Q_f Q_i^-1``), process noise = the
    GRS angular readout noise mapped to CRF (``Q_f``, per sample), measurement = the raw
    small-angle attitude phi from the star tracker, white R. G is constant and enters linearly:
    the two-stage filter of :mod:`taiji2_estimator_pkg.core.twostage` gives the exact GLS estimate and covariance (= the
    augmented Kalman filter with a diffuse prior on G and on the initial attitude and rate).
    With two GRS the readout difference ``B_1 G_1 - B_2 G_2 = e_1 - e_2`` (independent of the
    fused acceleration) adds a static regression on the six parameters; its regressor holds the
    readout noise, so its normal matrix is bias-corrected (corrected least squares, exact in
    expectation): the estimate stays unbiased.

One method per file, imports one way:

- :mod:`.estimate`: the result (:class:`ScaleFactorEstimate`) and :class:`StepReport`;
- :mod:`.model`: options and model (:class:`ScaleFactorModel`);
- :mod:`.gls`: the default estimator (:class:`ScaleFactorEstimator`);
- :mod:`taiji2_estimator_pkg.core.epoch_arrays`: a validated record as arrays per epoch (both bulk paths);
- :mod:`.paper`: the paper's filter.

This module is the public entry point: it re-exports those classes.
"""

from __future__ import annotations

from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate, StepReport
from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorModel, ScaleFactorOptions
from taiji2_estimator_pkg.core.scale_factor.paper import PaperScaleFactorFilter, PaperScaleFactorOptions

__all__ = [
    "PaperScaleFactorFilter",
    "PaperScaleFactorOptions",
    "ScaleFactorEstimate",
    "ScaleFactorEstimator",
    "ScaleFactorModel",
    "ScaleFactorOptions",
    "StepReport",
]
