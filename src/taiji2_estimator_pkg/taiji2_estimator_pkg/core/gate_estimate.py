"""The running estimate a per-sample pre-fit chi-square gate needs, with its covariance kept as a Cholesky factor.

The gate of an epoch asks for ``e^T (Lambda + S Cov S^T)^-1 e`` with ``e = e0 - S theta``: the estimate and
the covariance of the information accumulated before that epoch, i.e. one solve of the information per
epoch. Forming ``Cov`` (an inverse, or an eigen-decomposition) and the product ``S Cov S^T`` over all
parameters cost most of each estimator's per-epoch time; ``S Cov S^T = W^T W`` with ``W = L^-1 (S D)^T``
needs only the Cholesky factor ``L`` of the Jacobi-scaled information ``D I D`` and a triangular solve of
the few rows of ``S`` (LAPACK called directly: at these sizes numpy's per-call overhead exceeds the
arithmetic). The same algebra as the inverse: the gate's NIS differs from it by rounding only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: smallest over largest eigenvalue of the scaled information below which :func:`gate_estimate` declines
#: where asked to check it (the caller then solves by its eigen-decomposition, as before): 10 % above
#: the cut of :func:`~.twostage.solve_information`'s pseudo-inverse (1e-13), which declares the directions
#: below it undetermined. Eigenvalues computed without eigenvectors differ from those computed with them
#: by rounding (~1e-16 of the largest times the size), so nearer the cut the caller's own solve decides
#: whether the estimate is determined, and a factored estimate is used only where it certainly is.
#: (The c.m.-offset's (beta, x0) information is that ill-conditioned: 1e-13 to 2e-12 on a Type-1 run.)
MIN_EIGENVALUE_RATIO = 1.1e-13

_LAPACK: Any = None


def _lapack() -> Any:
    """scipy's LAPACK wrappers, imported on first use (importing scipy.linalg costs ~0.3 s, and the bulk
    path, e.g. ``taiji2 calibrate``, never gates per sample)."""
    global _LAPACK
    if _LAPACK is None:
        from scipy.linalg import lapack

        _LAPACK = lapack
    return _LAPACK


@dataclass(frozen=True)
class GateEstimate:
    """Estimate of the filter's parameters and its covariance, as a factor.

    Attributes
    ----------
    theta : numpy.ndarray
        (q_total,) estimate of the filter's parameters (those of interest, then the segment's x0).
    factor : numpy.ndarray
        (r, r) lower Cholesky factor ``L`` of the Jacobi-scaled information ``D I D`` over the solved
        coordinates.
    scale : numpy.ndarray
        (r,) the Jacobi scaling ``D`` (``1 / sqrt(diag I)``).
    mapping : numpy.ndarray or None
        (q_total, r) the filter's parameters as a linear function of the solved coordinates (None: the
        same coordinates); the covariance of ``theta`` is ``mapping I^-1 mapping^T``.
    """

    theta: np.ndarray
    factor: np.ndarray | None
    scale: np.ndarray | None
    mapping: np.ndarray | None = None
    #: (r, r) covariance of the solved coordinates instead of ``factor`` and ``scale``: where the caller
    #: solved its information otherwise (an estimate it had already, or a pseudo-inverse)
    covariance: np.ndarray | None = None

    @classmethod
    def from_covariance(cls, theta: np.ndarray, covariance: np.ndarray, mapping: np.ndarray | None = None
                        ) -> GateEstimate:
        """An estimate whose covariance over the solved coordinates is given."""
        return cls(theta, None, None, mapping, covariance)

    def spread(self, rows: np.ndarray) -> np.ndarray:
        """``rows Cov(theta) rows^T`` (k, k) for (k, q_total) ``rows`` (e.g. the innovation sensitivities S)."""
        mapped = rows if self.mapping is None else rows @ self.mapping
        if self.covariance is not None:
            return mapped @ self.covariance @ mapped.T
        w, info = _lapack().dtrtrs(self.factor, (mapped * self.scale).T, lower=1)
        if info != 0:
            raise np.linalg.LinAlgError(f"triangular solve failed (LAPACK info {info})")
        return w.T @ w


def gate_estimate(info: np.ndarray, vector: np.ndarray, min_eigenvalue_ratio: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Solve ``info x = vector`` by a Cholesky factor of the Jacobi-scaled ``info``.

    Returns ``(x, factor, scale)`` for a :class:`GateEstimate`, or None where ``info`` is not positive
    definite (or, with ``min_eigenvalue_ratio``, where the smallest eigenvalue of the scaled ``info`` is
    not above that ratio times its largest): the caller then solves as before.
    """
    diag = np.diagonal(info)
    if not np.all(diag > 0.0):
        return None
    scale = 1.0 / np.sqrt(diag)
    scaled = info * scale[:, None] * scale[None, :]
    lapack = _lapack()
    factor, failed = lapack.dpotrf(scaled, lower=1, clean=1)
    if failed != 0:
        return None
    if min_eigenvalue_ratio is not None:
        values = np.linalg.eigvalsh(scaled)
        if not values[0] > min_eigenvalue_ratio * values[-1]:
            return None
    solution, failed = lapack.dpotrs(factor, vector * scale, lower=1)
    if failed != 0:
        return None
    return solution * scale, factor, scale
