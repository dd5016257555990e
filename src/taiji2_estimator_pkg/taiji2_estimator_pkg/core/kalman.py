"""Textbook linear Kalman filter with the Joseph-form update, in the paper's symbols.

The paper (Sec. "calibration method") writes, with state X, transition Phi, observation H,
measurement noise covariance R and process noise covariance Q:

    X^_k = Phi_{k,k-1} X_{k-1}
    P^_k = Phi_{k,k-1} P_{k-1} Phi_{k,k-1}^T + Q_{k-1}
    Z^_k = H_k X^_k
    K_k  = P^_k H_k^T (H_k P^_k H_k^T + R_k)^-1
    X_k  = X^_k + K_k (Z_k - Z^_k)
    P_k  = (I - K_k H_k) P^_k (I - K_k H_k)^T + K_k R_k K_k^T          (Joseph form)

Each update also returns the normalised innovation squared
``NIS = nu^T (H P^ H^T + R)^-1 nu`` (chi-square with dim(Z) degrees of freedom if the model is
right) and can gate it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["KalmanFilter", "UpdateResult", "chi2_gate"]


def chi2_gate(dof: int, probability: float) -> float:
    """Chi-square threshold exceeded with ``probability`` by a consistent NIS of ``dof`` degrees.

    Parameters
    ----------
    dof : int
        Degrees of freedom (measurement dimension).
    probability : float
        False-alarm probability per update (e.g. 1e-6).

    Returns
    -------
    float
        Threshold on the NIS.
    """
    # Q(x) = P(chi2_dof > x) is decreasing: bisection on [0, hi] to the last bit (equals
    # scipy.stats.chi2.isf to rounding; computed here because importing scipy.stats costs more
    # than a whole offline calibration)
    if not 0.0 < probability < 1.0 or dof < 1:
        raise ValueError(f"chi2_gate: need dof >= 1 and 0 < probability < 1, got {dof}, {probability}")
    lo, hi = 0.0, float(dof) + 10.0
    while chi2_survival(hi, dof) > probability:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if chi2_survival(mid, dof) > probability:
            lo = mid
        else:
            hi = mid
    return hi


def chi2_survival(x: float, dof: int) -> float:
    """``P(chi2_dof > x)``: the regularised upper incomplete gamma function ``Q(dof/2, x/2)``.

    Closed forms for integer and half-integer ``a = dof/2``::

        Q(a, y) = exp(-y) sum_{k<a} y^k / k!                                  (a integer)
        Q(a, y) = erfc(sqrt y) + exp(-y) sum_{k=1}^{a-1/2} y^(k-1/2) / Gamma(k+1/2)   (a half-integer)
    """
    y = 0.5 * float(x)
    if y <= 0.0:
        return 1.0
    if dof % 2 == 0:
        terms = [k * math.log(y) - y - math.lgamma(k + 1.0) for k in range(dof // 2)]
        head = 0.0
    else:
        terms = [(k - 0.5) * math.log(y) - y - math.lgamma(k + 0.5) for k in range(1, (dof - 1) // 2 + 1)]
        head = math.erfc(math.sqrt(y))
    return head + math.fsum(math.exp(t) for t in terms)


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update.

    Attributes
    ----------
    nis : float
        Normalised innovation squared.
    accepted : bool
        False if the gate rejected the measurement (state and covariance unchanged).
    innovation : numpy.ndarray
        nu = Z - H X^.
    """

    nis: float
    accepted: bool
    innovation: np.ndarray


class KalmanFilter:
    """Linear Kalman filter (state X, covariance P) with Joseph-form update.

    Parameters
    ----------
    x0 : array_like
        (n,) initial state X_0.
    p0 : array_like
        (n, n) initial covariance P_0.
    gate_threshold : float or None
        NIS above which a measurement is rejected (None: no gating).
    """

    def __init__(self, x0: ArrayLike, p0: ArrayLike, gate_threshold: float | None = None) -> None:
        self.x = np.array(x0, dtype=np.float64, copy=True).reshape(-1)
        self.p = np.array(p0, dtype=np.float64, copy=True).reshape(self.x.size, self.x.size)
        self.gate_threshold = gate_threshold
        self.n_updates = 0
        self.n_rejected = 0

    def predict(self, phi: ArrayLike | None = None, q: ArrayLike | None = None) -> None:
        """Time update. ``phi`` defaults to I and ``q`` to 0 (the paper's choice)."""
        if phi is not None:
            phi = np.asarray(phi, dtype=np.float64)
            # X^_k = Phi_{k,k-1} X_{k-1}
            self.x = phi @ self.x
            # P^_k = Phi_{k,k-1} P_{k-1} Phi_{k,k-1}^T + Q_{k-1}
            self.p = phi @ self.p @ phi.T
        if q is not None:
            self.p = self.p + np.asarray(q, dtype=np.float64)

    def update(self, z: ArrayLike, h: ArrayLike, r: ArrayLike) -> UpdateResult:
        """Measurement update with Z_k = H_k X_k + V_k, Cov(V_k) = R_k (Joseph form).

        Parameters
        ----------
        z : array_like
            (m,) measurement Z_k.
        h : array_like
            (m, n) observation matrix H_k.
        r : array_like
            (m, m) measurement noise covariance R_k (or (m,) diagonal).

        Returns
        -------
        UpdateResult
        """
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        h = np.asarray(h, dtype=np.float64).reshape(z.size, self.x.size)
        r = np.asarray(r, dtype=np.float64)
        if r.ndim == 1:
            r = np.diag(r)
        # Z^_k = H_k X^_k
        z_pred = h @ self.x
        nu = z - z_pred
        # H_k P^_k H_k^T + R_k  (innovation covariance)
        s = h @ self.p @ h.T + r
        nis = float(nu @ np.linalg.solve(s, nu))
        if self.gate_threshold is not None and nis > self.gate_threshold:
            self.n_rejected += 1
            return UpdateResult(nis, False, nu)
        # K_k = P^_k H_k^T (H_k P^_k H_k^T + R_k)^-1
        k = np.linalg.solve(s, h @ self.p).T
        # X_k = X^_k + K_k (Z_k - Z^_k)
        self.x = self.x + k @ nu
        # P_k = (I - K_k H_k) P^_k (I - K_k H_k)^T + K_k R_k K_k^T
        i_kh = np.eye(self.x.size) - k @ h
        self.p = i_kh @ self.p @ i_kh.T + k @ r @ k.T
        self.n_updates += 1
        return UpdateResult(nis, True, nu)

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint."""
        return {"x": self.x.tolist(), "p": self.p.tolist(), "gate_threshold": self.gate_threshold,
                "n_updates": self.n_updates, "n_rejected": self.n_rejected}

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> KalmanFilter:
        """Restore a checkpoint of :meth:`state_dict`."""
        kf = cls(state["x"], state["p"], state["gate_threshold"])
        kf.n_updates = int(state["n_updates"])
        kf.n_rejected = int(state["n_rejected"])
        return kf
