"""Taiji-2 GRS in-orbit calibration: scale-factor and c.m.-offset estimators.

The numerical core (:mod:`taiji2_estimator_pkg.core`) is middleware-free (numpy/scipy only) and
runs on simulated or real data; the nodes wrap it.
"""

__version__ = "0.1.0"
