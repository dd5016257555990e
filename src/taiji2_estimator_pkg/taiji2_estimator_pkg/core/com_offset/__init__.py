"""Test-mass c.m. offsets d_i (CRF) from the GRS linear accelerations.

Two methods:

``paper`` (:class:`PaperComOffsetFilter`)
    The paper's filter: per GRS a 3-state Kalman filter (Phi = I, Q = 0, Joseph update) on the
    TMRF linear acceleration ``a_out = G_lin (v1 + v2)`` (scale factors from a scale-factor
    estimate), ``H = C_i A~`` with A~ from the star tracker's smoothed rate and acceleration, the
    same smoothing applied to a_out, and the paper's detrending (``Gamma t + Lambda``) done for
    regressor and data together (as extra diffuse states, which by Frisch-Waugh-Lovell is the same
    as detrending both sides). Diagonal R. Its covariance is too small (reported, not fixed).

``gls`` (:class:`ComOffsetEstimator`, default)
    Per epoch and GRS i, in CRF::

        z_i = C_i^T a_lin,i = A~(omega_dot, omega) d_i + a_SC + n_i,

    with A~ built from the *calibrated GRS* angular acceleration ``omega_dot^ = sum_i W_i C_i^T
    diag(u_i) G_i`` (far less noisy than the star tracker's) and omega from the attitude filter.
    ``a_SC`` is common to both GRS: white thruster noise (in R, fully correlated between the GRS)
    plus SRP, an AR(1) state of a Kalman filter; bias and trend per GRS are regression parameters
    (the paper's detrending, applied to regressor and data together by construction). The noise
    of omega_dot^ enters as ``[d_i x] e`` (errors in variables): it is in R (with the cross-GRS
    correlation), and its bias on the normal matrix is removed (corrected least squares). d_1, d_2
    are estimated jointly with their cross-covariance; d_1 - d_2 is reported with its covariance.

    Data and regressors are linear in the scale factors G, so the filter runs on a basis of series
    (one per component of G) and accumulates their full cross-product: d(G) and dd/dG are then
    exact for any G, which lets a node follow a running G estimate and still agree with the bulk
    result. By default d is then estimated jointly with G from every channel
    (:mod:`.joint`, the full Cramer-Rao bound); ``joint: false`` gives the two-stage
    ``d(G^)`` with ``P_d = P_d|G + J P_G J^T``.

One method per file, imports one way (model <- estimator; joint and noise level are leaves):

- :mod:`.estimate`: the result (:class:`ComOffsetEstimate`);
- :mod:`.model`: options, noise model, basis of series (:class:`ComOffsetModel`);
- :mod:`.gls`: the default estimator (:class:`ComOffsetEstimator`);
- :mod:`.joint`: the joint (G, d) equations, shared with the bound (:mod:`taiji2_estimator_pkg.core.crlb`);
- :mod:`taiji2_estimator_pkg.core.noise_level`: the noise of the linear channels in the band that carries d;
- :mod:`.paper`: the paper's filter.

This module is the public entry point: it re-exports those classes.
"""

from __future__ import annotations

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.com_offset.gls import ComOffsetEstimator, ComOffsetStepReport
from taiji2_estimator_pkg.core.com_offset.model import ComOffsetModel, ComOffsetOptions, cross_matrix
from taiji2_estimator_pkg.core.com_offset.paper import PaperComOffsetFilter, PaperComOffsetOptions

__all__ = [
    "ComOffsetEstimate",
    "ComOffsetEstimator",
    "ComOffsetModel",
    "ComOffsetOptions",
    "ComOffsetStepReport",
    "PaperComOffsetFilter",
    "PaperComOffsetOptions",
    "cross_matrix",
]
