"""Inverse and solve of the small symmetric positive definite matrices of a per-sample filter step.

The per-sample filters invert the innovation covariance ``Lambda`` (3 x 3 or 6 x 6) and solve the gate's
``(Lambda + S Cov S^T) x = e`` at every epoch. At these sizes numpy's ``inv`` / ``solve`` spend most of their
time in per-call overhead (type checks, LU with pivoting, error-state handling): LAPACK's Cholesky driver
``dposv`` called directly (scipy's wrapper, imported on first use as in :mod:`.gate_estimate`) does the same
algebra in a quarter of the time. The results differ from numpy's by rounding only. A matrix that is not
positive definite (never expected: both are covariances) goes to numpy's LU, which raises where it is
singular, as before.
"""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.core.gate_estimate import _lapack

__all__ = ["spd_inverse", "spd_solve"]

_IDENTITIES: dict[int, np.ndarray] = {}


def spd_inverse(a: np.ndarray) -> np.ndarray:
    """``a^-1`` of a symmetric positive definite (n, n) ``a``, symmetric to rounding."""
    n = a.shape[0]
    identity = _IDENTITIES.get(n)
    if identity is None:
        identity = _IDENTITIES[n] = np.eye(n)
    _, inverse, failed = _lapack().dposv(a, identity, lower=1)
    if failed != 0:
        return np.linalg.inv(a)
    return inverse


def spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x`` with ``a x = b`` for a symmetric positive definite (n, n) ``a`` and (n,) ``b``."""
    _, x, failed = _lapack().dposv(a, b, lower=1)
    if failed != 0:
        return np.linalg.solve(a, b)
    return x
