"""Angular scale factors G = (G_Pphi, G_Ptheta, G_Ppsi) of one or both GRS.

Two methods, their equations in ``docs/estimators.md`` (the one place that holds them):

- ``paper`` (:class:`PaperScaleFactorFilter`): the paper's filter as written (section 3); its covariance is
  too small (reported, not fixed);
- ``gls`` (:class:`ScaleFactorEstimator`, default): section 4, with an honest covariance (section 6).

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
