"""Middleware-free numerical core of the Taiji-2 GRS calibration estimators (numpy/scipy only).

Modules:

- :mod:`.instrument`: geometry, nominal values, voltage conversions (:class:`InstrumentModel`)
- :mod:`.noise_model`: the noise budget (:class:`NoiseBudget`)
- :mod:`.attitude`: star-tracker quaternions to small-angle attitude; smoothing derivative
- :mod:`.validation`: input checks with counted rejection reasons
- :mod:`.kalman`: textbook Kalman filter with Joseph update (the paper's filters)
- :mod:`.twostage`: two-stage (separate-bias) Kalman filter + innovations GLS, per sample and bulk
- :mod:`.scale_factor`: scale factors G (``gls`` default, ``paper``)
- :mod:`.com_offset`: c.m. offsets d (``gls`` default, ``paper``)
- :mod:`.crlb`: Cramer-Rao bounds
- :mod:`.parameters`: the documented parameter file
- :mod:`.pipeline`: offline calibration of a whole record
"""

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.com_offset.gls import ComOffsetEstimator
from taiji2_estimator_pkg.core.com_offset.model import ComOffsetOptions
from taiji2_estimator_pkg.core.com_offset.paper import PaperComOffsetFilter, PaperComOffsetOptions
from taiji2_estimator_pkg.core.crlb import CrlbResult, crlb
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.noise_model import NoiseBudget
from taiji2_estimator_pkg.core.pipeline import CalibrationResult, calibrate
from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate
from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorOptions
from taiji2_estimator_pkg.core.scale_factor.paper import PaperScaleFactorFilter, PaperScaleFactorOptions
from taiji2_estimator_pkg.core.validation import InputValidator, ValidationOptions

__all__ = [
    "CalibrationResult",
    "ComOffsetEstimate",
    "ComOffsetEstimator",
    "ComOffsetOptions",
    "CrlbResult",
    "InputValidator",
    "InstrumentModel",
    "NoiseBudget",
    "PaperComOffsetFilter",
    "PaperComOffsetOptions",
    "PaperScaleFactorFilter",
    "PaperScaleFactorOptions",
    "ScaleFactorEstimate",
    "ScaleFactorEstimator",
    "ScaleFactorOptions",
    "ValidationOptions",
    "calibrate",
    "crlb",
]
