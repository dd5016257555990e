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

from .com_offset import (
    ComOffsetEstimate,
    ComOffsetEstimator,
    ComOffsetOptions,
    PaperComOffsetFilter,
    PaperComOffsetOptions,
)
from .crlb import CrlbResult, crlb, crlb_for_layout
from .instrument import InstrumentModel
from .noise_model import NoiseBudget
from .pipeline import CalibrationResult, calibrate
from .scale_factor import (
    PaperScaleFactorFilter,
    PaperScaleFactorOptions,
    ScaleFactorEstimate,
    ScaleFactorEstimator,
    ScaleFactorOptions,
)
from .validation import InputValidator, ValidationOptions

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
    "crlb_for_layout",
]
