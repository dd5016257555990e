"""Test-mass c.m. offsets d_i (CRF) from the GRS linear accelerations.

Two methods, their equations in ``docs/estimators.md`` (the one place that holds them):

- ``paper`` (:class:`PaperComOffsetFilter`): the paper's filter as written (section 3); its covariance is
  too small (reported, not fixed);
- ``gls`` (:class:`ComOffsetEstimator`, default): section 5, with an honest covariance (section 6).

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
