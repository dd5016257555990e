"""Two-stage (separate-bias) Kalman filter: a bias-free filter plus an innovations GLS.

Length (over 600 lines): one class, :class:`TwoStageFilter`, whose two evaluation paths (``step`` and
``run_regular``) must give the same numbers (tests hold them equal) and share its state and steady state;
split, the two paths would drift apart.

Model (linear Gaussian state space with constant unknown parameters theta)::

    x_k = F x_{k-1} + B (u0_k + U_k theta) + w_k,      w_k ~ N(0, Q)
    y_k = H x_k + X_k theta + v_k,                      v_k ~ N(0, R)

with the initial state of each segment diffuse. Friedland's decomposition: the filter run with
theta = 0 (the *bias-free* filter) has gains that do not depend on the data; its innovations
e0_k and the sensitivities S_k of the innovations to theta (the same filter run on the
regressors) give the exact innovations of the filter for any theta, ``e_k(theta) = e0_k - S_k
theta``, with covariance ``Lambda_k``. Hence

    theta^ = (sum S_k^T Lambda_k^-1 S_k)^-1 sum S_k^T Lambda_k^-1 e0_k,
    Cov(theta^) = (sum S_k^T Lambda_k^-1 S_k)^-1,

identical to the Kalman filter on the state augmented with theta under a diffuse prior, and equal
to the Fisher information when evaluated on noise-free regressors. The segment's initial state is
part of theta (``n`` extra parameters), so the bias-free filter can start at its steady-state
covariance: a diffuse parameter plus any Gaussian is still diffuse, and the filter is then
linear time-invariant from the first sample.

Two evaluation paths give the same numbers (to rounding):

- :meth:`TwoStageFilter.step`: one sample, O(1), general (missing or partial measurements,
  a different process noise for one step, chi-square gating); after irregular steps the covariance
  is recomputed by the Riccati recursion until it is back at the steady state within
  ``snap_tolerance`` (then it is set to it exactly);
- :meth:`TwoStageFilter.run_regular`: a run of regular samples at the steady state in bulk: the
  closed loop ``A = F (I - K H)`` is diagonalised block by block (the model supplies coordinates
  in which it is block diagonal) and each mode is a first-order recursion evaluated in bulk by
  :func:`first_order_recursion` (blocked scaled prefix sums: numpy only, so that importing the
  estimators does not import scipy.signal, which costs more than a whole calibration's filtering).

Length (over 900 lines): the one filter both estimators run, in its per-sample, bulk and steady-state
forms, which tests hold equal to rounding; its state layout and segment rules are shared by all three, so they
stay in one module.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.factored_steady import RegressorFactors, run_steady_factored
from taiji2_estimator_pkg.core.first_order import first_order_recursion
from taiji2_estimator_pkg.core.gate_estimate import GateEstimate
from taiji2_estimator_pkg.core.small_spd import spd_inverse, spd_solve

__all__ = [
    "RegularRunOutput",
    "StateSpaceModel",
    "StepInfo",
    "TwoStageFilter",
    "first_order_recursion",
    "solve_information",
    "steady_state_prior_covariance",
]

_CHUNK = 4096  # samples per block of the bulk path (memory, not numerics)
_TRANSIENT_CHUNK = 8192  # samples per vectorised piece of a transient (memory, not numerics)


def _affine_recursion(transition: np.ndarray, drive: np.ndarray, initial: np.ndarray) -> np.ndarray:
    """``z_i = T_i z_{i-1} + D_i`` (i = 0..N-1, ``z_-1 = initial``) for time-varying T, in blocks.

    The N steps are cut into ~sqrt(N) blocks of ~sqrt(N) steps: the recursion inside every block
    (from a zero state) and the block's transition product run as one stacked product per step
    position, vectorised over the blocks; the states carried from block to block follow in a short
    loop over the blocks; then ``z = Phi c + local`` for all steps at once. About 2 sqrt(N)
    vectorised operations instead of N per-step ones.
    """
    steps, n = transition.shape[0], transition.shape[1]
    if steps == 0:
        return np.zeros((0, *initial.shape))
    block = max(1, int(np.sqrt(steps)))
    n_blocks = -(-steps // block)
    pad = n_blocks * block - steps
    t = np.concatenate((transition, np.broadcast_to(np.eye(n), (pad, n, n)))) if pad else transition
    d = np.concatenate((drive, np.zeros((pad, *drive.shape[1:])))) if pad else drive
    t = t.reshape(n_blocks, block, n, n)
    d = d.reshape(n_blocks, block, *drive.shape[1:])
    local = np.empty_like(d)
    phi = np.empty_like(t)
    local[:, 0] = d[:, 0]
    phi[:, 0] = t[:, 0]
    for j in range(1, block):
        local[:, j] = t[:, j] @ local[:, j - 1] + d[:, j]
        phi[:, j] = t[:, j] @ phi[:, j - 1]
    carry = np.empty((n_blocks, *initial.shape))
    carry[0] = initial
    for b in range(1, n_blocks):
        carry[b] = phi[b - 1, -1] @ carry[b - 1] + local[b - 1, -1]
    out = phi @ carry[:, None] + local
    return out.reshape(n_blocks * block, *drive.shape[1:])[:steps]


def _rows(array: np.ndarray | RegressorFactors | None, start: int, stop: int) -> np.ndarray | None:
    """Samples start..stop-1 (dense: the per-sample paths take (L, m, p) regressors)."""
    if isinstance(array, RegressorFactors):
        return array.rows(start, stop).dense()
    return None if array is None else array[start:stop]


@dataclass(frozen=True)
class StateSpaceModel:
    """Nominal (regular-sample) model of a :class:`TwoStageFilter`.

    Attributes
    ----------
    f : numpy.ndarray
        (n, n) transition F.
    b : numpy.ndarray
        (n, n_u) input matrix B.
    q : numpy.ndarray
        (n, n) process noise covariance per step (already mapped into the state).
    h : numpy.ndarray
        (m, n) observation matrix H.
    r : numpy.ndarray
        (m, m) measurement noise covariance R.
    blocks : tuple of tuple of int
        State index groups in which ``F (I - K H)`` is block diagonal (None: one block).
    """

    f: np.ndarray
    b: np.ndarray
    q: np.ndarray
    h: np.ndarray
    r: np.ndarray
    blocks: tuple[tuple[int, ...], ...] | None = None

    @property
    def n(self) -> int:
        """State dimension."""
        return self.f.shape[0]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.h.shape[0]


@dataclass(frozen=True)
class StepInfo:
    """Diagnostics of one :meth:`TwoStageFilter.step`.

    Attributes
    ----------
    nis : float
        Pre-fit normalised innovation squared (with the parameter uncertainty), NaN if no
        measurement or the parameters are not yet determined.
    dof : int
        Measurement dimension used.
    accepted : bool
        False if gated out.
    post_nis : float
        ``r^T Lambda^-1 r`` of the innovation ``r = e0 - S theta`` for a given theta (evaluation).
    state : numpy.ndarray or None
        Posterior state for the given theta (evaluation).
    """

    nis: float
    dof: int
    accepted: bool
    post_nis: float = float("nan")
    state: np.ndarray | None = None


@dataclass
class RegularRunOutput:
    """Optional per-sample outputs of :meth:`TwoStageFilter.run_regular`.

    Attributes
    ----------
    nis : numpy.ndarray or None
        (L,) post-fit NIS ``r^T Lambda^-1 r``, ``r = e0 - S theta`` (theta given).
    states : numpy.ndarray or None
        (L, n) posterior state estimates for the given theta.
    innovations : numpy.ndarray or None
        (L, m) post-fit innovations r.
    """

    nis: np.ndarray | None = None
    states: np.ndarray | None = None
    innovations: np.ndarray | None = None


def steady_state_prior_covariance(f: np.ndarray, h: np.ndarray, q: np.ndarray, r: np.ndarray,
                                  max_iterations: int = 200) -> np.ndarray:
    """Steady-state prior covariance of the Kalman filter by the structured doubling algorithm.

    Solves ``P = F P F^T - F P H^T (H P H^T + R)^-1 H P F^T + Q``, written as
    ``P = A^T P (I + G P)^-1 A + Q`` with ``A = F^T``, ``G = H^T R^-1 H``, by the doubling
    iteration (Chu, Fan, Lin 2005)::

        A_{k+1} = A_k (I + G_k H_k)^-1 A_k
        G_{k+1} = G_k + A_k (I + G_k H_k)^-1 G_k A_k^T
        H_{k+1} = H_k + A_k^T H_k (I + G_k H_k)^-1 A_k        (H_0 = Q, H_k -> P)

    Quadratic convergence, accurate for the tiny process-to-measurement noise ratios met here
    (down to 1e-8), and it keeps any block structure of the problem exactly.
    """
    n = f.shape[0]
    a_k = f.T.copy()
    g_k = h.T @ np.linalg.solve(r, h)
    g_k = 0.5 * (g_k + g_k.T)
    h_k = np.asarray(q, dtype=np.float64).copy()
    eye = np.eye(n)
    for _ in range(max_iterations):
        w = np.linalg.inv(eye + g_k @ h_k)
        a_w = a_k @ w
        h_next = h_k + a_k.T @ h_k @ w @ a_k
        g_next = g_k + a_w @ g_k @ a_k.T
        a_k = a_w @ a_k
        h_next = 0.5 * (h_next + h_next.T)
        g_k = 0.5 * (g_next + g_next.T)
        change = np.max(np.abs(h_next - h_k))
        h_k = h_next
        if change <= 1e-15 * np.max(np.abs(h_k)) and np.max(np.abs(a_k)) < 1e-8:
            return h_k
    from scipy.linalg import solve_discrete_are  # fallback only (rarely reached; a slow import)

    return solve_discrete_are(f.T, h.T, q, r)


def solve_information(info: np.ndarray, vector: np.ndarray, rcond: float = 1e-13, positive: bool = False
                      ) -> tuple[np.ndarray, np.ndarray, bool]:
    """Solve ``info theta = vector`` for a symmetric PSD information matrix, robustly.

    Jacobi scaling, then an eigen-decomposition; directions with eigenvalue below ``rcond`` times
    the largest are treated as undetermined (pseudo-inverse).

    With ``positive`` (the caller knows the matrix is well conditioned) a plain inverse of the
    scaled matrix is used (faster; falls back to the eigen-decomposition if it fails).

    Returns
    -------
    theta : numpy.ndarray
        Solution (minimum norm in the undetermined directions).
    covariance : numpy.ndarray
        Pseudo-inverse of ``info``.
    full_rank : bool
        Whether every direction is determined.
    """
    diag = np.diag(info).copy()
    scale = np.where(diag > 0.0, 1.0 / np.sqrt(np.where(diag > 0.0, diag, 1.0)), 0.0)
    scaled = info * scale[:, None] * scale[None, :]
    scaled = 0.5 * (scaled + scaled.T)
    if positive and np.all(diag > 0.0):
        try:
            np.linalg.cholesky(scaled)
            covariance = np.linalg.inv(scaled) * scale[:, None] * scale[None, :]
            return covariance @ vector, covariance, True
        except np.linalg.LinAlgError:
            pass
    values, vectors = np.linalg.eigh(scaled)
    top = float(values[-1]) if values.size else 0.0
    keep = values > rcond * max(top, 0.0)
    inverse_values = np.where(keep, 1.0 / np.where(keep, values, 1.0), 0.0)
    pinv = (vectors * inverse_values) @ vectors.T
    covariance = pinv * scale[:, None] * scale[None, :]
    theta = covariance @ vector
    return theta, covariance, bool(np.all(keep) and np.all(diag > 0.0))


class TwoStageFilter:
    """Bias-free filter with parameter sensitivities and an information-form GLS.

    Parameters
    ----------
    model : StateSpaceModel
        Nominal model.
    n_params : int
        Number p of constant parameters of interest (the columns of U and X); the n initial-state
        parameters of the current segment follow them in theta.
    snap_tolerance : float
        Relative distance to the steady-state covariance below which the covariance is set to it.
    """

    def __init__(self, model: StateSpaceModel, n_params: int, snap_tolerance: float = 1e-10) -> None:
        self.model = model
        self.p = int(n_params)
        self.snap_tolerance = float(snap_tolerance)
        n, m = model.n, model.m
        self.q_total = self.p + n
        self._steady_state()
        # filter state: posterior of the last step, or the prior of the next one when fresh
        self.x = np.zeros(n)
        self.sens = np.zeros((n, self.q_total))
        self.cov = self.p_prior_ss.copy()
        self.fresh = True
        self.steady = True
        self.sens[:, self.p:] = np.eye(n)
        self.info = np.zeros((self.q_total, self.q_total))
        self.vector = np.zeros(self.q_total)
        self.chi2 = 0.0  # sum of e0^T Lambda^-1 e0 (post-fit chi-square = chi2 - vector^T theta)
        self.n_updates = 0
        self.n_rejected = 0
        self.dof_total = 0
        self.n_segments = 1
        self.segment_x0: list[tuple[np.ndarray, np.ndarray]] = []
        self.evaluation = False
        self._m = m

    # steady state ---------------------------------------------------------------------------
    def _steady_state(self) -> None:
        mdl = self.model
        f, h, q, r = mdl.f, mdl.h, mdl.q, mdl.r
        p_prior = steady_state_prior_covariance(f, h, q, r)
        p_prior = 0.5 * (p_prior + p_prior.T)
        blocks = mdl.blocks or (tuple(range(mdl.n)),)
        mask = np.zeros((mdl.n, mdl.n), dtype=bool)
        for block in blocks:
            mask[np.ix_(block, block)] = True
        # in the model's coordinates the steady state is block diagonal: remove the rounding of the
        # Riccati solver off the blocks, so that gain and closed loop are exactly block structured
        scale = np.sqrt(np.abs(np.diag(p_prior)))
        off = np.abs(p_prior) / np.maximum(np.outer(scale, scale), np.finfo(float).tiny)
        if np.any(~mask) and np.max(off[~mask]) > 1e-6:
            raise ValueError(f"steady state not block diagonal in the given coordinates "
                             f"(off-block correlation {np.max(off[~mask]):.3g})")
        p_prior = np.where(mask, p_prior, 0.0)
        lam = h @ p_prior @ h.T + r
        lam = 0.5 * (lam + lam.T)
        gain = np.linalg.solve(lam, h @ p_prior).T
        i_kh = np.eye(mdl.n) - gain @ h
        p_post = i_kh @ p_prior @ i_kh.T + gain @ r @ gain.T
        closed = f @ i_kh
        off = np.max(np.abs(closed[~mask])) if np.any(~mask) else 0.0
        if off > 1e-12 * np.max(np.abs(closed)):
            raise ValueError(f"closed loop not block diagonal in the given coordinates (off-block {off:.3g})")
        closed = np.where(mask, closed, 0.0)
        eigvals = np.zeros(mdl.n, dtype=complex)
        eigvecs = np.zeros((mdl.n, mdl.n), dtype=complex)
        for block in blocks:
            idx = np.asarray(block)
            values, vectors = np.linalg.eig(closed[np.ix_(idx, idx)])
            eigvals[idx] = values
            eigvecs[np.ix_(idx, idx)] = vectors
        self.p_prior_ss = p_prior
        self.p_post_ss = 0.5 * (p_post + p_post.T)
        self.gain_ss = gain
        self.lambda_ss = lam
        self.lambda_inv_ss = np.linalg.inv(lam)
        self.lambda_inv_ss = 0.5 * (self.lambda_inv_ss + self.lambda_inv_ss.T)
        #: the snap test's scale max |P+_ss| and the identity of (I - K H): constants of :meth:`step`
        self.p_post_scale = float(np.max(np.abs(self.p_post_ss)))
        self.identity_n = np.eye(mdl.n)
        self.closed_loop = closed
        # one lfilter per conjugate pair: the partner mode is the complex conjugate
        filtered, partner = [], {}
        for block in blocks:
            idx = list(block)
            if len(idx) == 2 and abs(eigvals[idx[0]].imag) > 0.0 and \
                    np.isclose(eigvals[idx[0]], np.conj(eigvals[idx[1]]), rtol=1e-12, atol=0.0):
                eigvecs[:, idx[1]] = np.conj(eigvecs[:, idx[0]])
                eigvals[idx[1]] = np.conj(eigvals[idx[0]])
                filtered.append(idx[0])
                partner[idx[1]] = idx[0]
            else:
                filtered.extend(idx)
        self._filtered_modes = filtered
        self._conjugate_partner = partner
        self._real_modes = bool(np.all(eigvals.imag == 0.0) and np.all(eigvecs.imag == 0.0))
        self.modes = eigvals
        self.mode_vectors = eigvecs
        self.mode_vectors_inv = np.linalg.inv(eigvecs)
        self._whiten = np.linalg.cholesky(self.lambda_inv_ss)  # Lambda^-1 = L L^T

    def innovation_gramian(self) -> np.ndarray:
        """``X = sum_l (A^T)^l H^T Lambda^-1 H A^l`` at the steady state (A = F (I - K H)).

        ``(B u)^T X (B u)`` is the energy ``sum_l e_l^T Lambda^-1 e_l`` of the innovations that a unit
        input u at one step leaves in all later innovations (computed by doubling).
        """
        closed = self.closed_loop
        gram = self.model.h.T @ self.lambda_inv_ss @ self.model.h
        power = closed.copy()
        for _ in range(200):
            increment = power.T @ gram @ power
            gram = gram + increment
            power = power @ power
            if np.max(np.abs(increment)) <= 1e-17 * np.max(np.abs(gram)) and np.max(np.abs(power)) < 1e-9:
                break
        return 0.5 * (gram + gram.T)

    # parameters -------------------------------------------------------------------------------
    def solve(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """Current GLS solution over all of theta (parameters of interest first, then x0)."""
        return solve_information(self.info, self.vector)

    def parameter_estimate(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """Estimate and covariance of the p parameters of interest (x0 marginalised).

        Returns
        -------
        theta : numpy.ndarray
            (p,) estimate.
        covariance : numpy.ndarray
            (p, p) covariance.
        determined : bool
            Whether all p parameters (and x0) are determined by the data so far.
        """
        theta, cov, full = self.solve()
        return theta[:self.p], cov[:self.p, :self.p], full

    def post_fit_chi2(self) -> float:
        """Sum of post-fit NIS at the current estimate (expected ``dof_total - q``)."""
        theta, _, _ = self.solve()
        return float(self.chi2 - self.vector @ theta)

    def segment_theta(self, segment: int, theta_p: np.ndarray, theta_last: np.ndarray) -> np.ndarray:
        """Full theta (parameters, x0) of segment ``segment`` (0-based) for parameters ``theta_p``.

        Finished segments use their conditional x0 estimate; the current one uses ``theta_last``.
        """
        if segment < len(self.segment_x0):
            offset, gain = self.segment_x0[segment]
            return np.concatenate((theta_p, offset - gain @ theta_p))
        return theta_last

    def reset_segment(self) -> None:
        """Start a new segment: the state becomes diffuse again (after a long gap).

        The initial-state parameters of the finished segment are marginalised out of the
        information (they no longer influence future innovations); their conditional estimate
        given the parameters is kept in :attr:`segment_x0`.
        """
        p, n = self.p, self.model.n
        info, vec = self.info, self.vector
        if self.evaluation:
            self.x = np.zeros(n)
            self.cov = self.p_prior_ss.copy()
            self.fresh = True
            self.steady = True
            self.n_segments += 1
            return
        if np.any(info[p:, p:] != 0.0):
            _, c_pinv, _ = solve_information(info[p:, p:], np.zeros(n))
            coupling = info[:p, p:]
            # conditional estimate of the finished segment's x0 given the parameters:
            # x0^ = C^+ (b_x - B^T theta_p)  (kept for evaluation passes)
            self.segment_x0.append((c_pinv @ vec[p:], c_pinv @ coupling.T))
            reduced = info[:p, :p] - coupling @ c_pinv @ coupling.T
            vec_p = vec[:p] - coupling @ c_pinv @ vec[p:]
            self.chi2 -= float(vec[p:] @ c_pinv @ vec[p:])
            info = np.zeros_like(info)
            info[:p, :p] = 0.5 * (reduced + reduced.T)
            vec = np.zeros_like(vec)
            vec[:p] = vec_p
            self.info, self.vector = info, vec
        else:
            self.segment_x0.append((np.zeros(n), np.zeros((n, p))))
        self.x = np.zeros(n)
        self.sens = np.zeros((n, self.q_total))
        self.sens[:, p:] = np.eye(n)
        self.cov = self.p_prior_ss.copy()
        self.fresh = True
        self.steady = True
        self.n_segments += 1

    # per-sample path -----------------------------------------------------------------------------
    def step(self, y: ArrayLike | None = None, x_reg: ArrayLike | None = None, u0: ArrayLike | None = None,
             u_reg: ArrayLike | None = None, rows: ArrayLike | None = None, q: ArrayLike | None = None,
             gate: float | None = None, estimate: GateEstimate | None = None,
             r: ArrayLike | None = None) -> StepInfo:
        """Process one sample: predict (unless first of a segment), then update.

        Parameters
        ----------
        y : array_like, optional
            (m,) measurement (None: missing, predict only).
        x_reg : array_like, optional
            (m, p) measurement regressor X_k (None: zero).
        u0 : array_like, optional
            (n_u,) known input (None: zero).
        u_reg : array_like, optional
            (n_u, p) input regressor U_k (None: zero).
        rows : array_like of bool, optional
            (m,) measurement rows present (None: all).
        q : array_like, optional
            (n, n) process noise of this step if not the nominal one.
        gate : float, optional
            NIS threshold (None: no gating; gating needs ``estimate``).
        estimate : GateEstimate, optional
            Current estimate of all q_total parameters and its covariance (as a factor), for the pre-fit
            NIS ``e^T (Lambda + S Cov S^T)^-1 e``, ``e = e0 - S theta`` (None: no NIS).
        r : array_like, optional
            (m, m) measurement noise of this step if not the nominal one (rows are selected from it).

        Returns
        -------
        StepInfo
            In evaluation mode (:meth:`evaluation_copy`) ``post_nis`` and ``state`` are filled.
        """
        mdl = self.model
        p = self.p
        regular = q is None and rows is None and r is None and y is not None
        if not self.fresh:
            # x^_k = F x_{k-1} + B (u0_k + U_k theta): the theta part is carried by the sensitivities M
            self.x = mdl.f @ self.x
            if u0 is not None:
                self.x = self.x + mdl.b @ np.asarray(u0, dtype=np.float64)
            if not self.evaluation:
                self.sens = mdl.f @ self.sens
                if u_reg is not None:
                    self.sens[:, :p] += mdl.b @ np.asarray(u_reg, dtype=np.float64)
            if not (self.steady and regular):
                # P^_k = F P_{k-1} F^T + Q
                self.cov = mdl.f @ self.cov @ mdl.f.T + (mdl.q if q is None else np.asarray(q, dtype=np.float64))
        else:
            # first sample of a segment: its state is the parameter x0, any input is ignored
            self.fresh = False
        if y is None:
            self.steady = False
            return StepInfo(float("nan"), 0, True, float("nan"), self.x.copy() if self.evaluation else None)
        y = np.asarray(y, dtype=np.float64)
        r_full = mdl.r if r is None else np.asarray(r, dtype=np.float64)
        if rows is None:
            h, r, yy = mdl.h, r_full, y
            xr = None if x_reg is None else np.asarray(x_reg, dtype=np.float64)
        else:
            sel = np.asarray(rows, dtype=bool)
            h, r, yy = mdl.h[sel], r_full[np.ix_(sel, sel)], y[sel]
            xr = None if x_reg is None else np.asarray(x_reg, dtype=np.float64)[sel]
        use_ss = self.steady and regular
        # innovation e0 = y - H x^ and, unless evaluating, its sensitivity S = H M + X
        e0 = yy - h @ self.x
        if use_ss:
            lam_inv, lam = self.lambda_inv_ss, self.lambda_ss
        else:
            lam = h @ self.cov @ h.T + r
            lam = 0.5 * (lam + lam.T)
            lam_inv = spd_inverse(lam)
        if self.evaluation:
            s = None
            post_nis = float(e0 @ lam_inv @ e0)
        else:
            s = h @ self.sens
            if xr is not None:
                s[:, :p] += xr
            post_nis = float("nan")
        nis_value = float("nan")
        if estimate is not None and s is not None:
            resid = e0 - s @ estimate.theta
            total = lam + estimate.spread(s)
            nis_value = float(resid @ spd_solve(total, resid))
        if gate is not None and np.isfinite(nis_value) and nis_value > gate:
            self.n_rejected += 1
            self.steady = False
            return StepInfo(nis_value, yy.size, False)
        if s is not None:
            # information of the innovations: sum S^T Lambda^-1 S, sum S^T Lambda^-1 e0
            s_w = s.T @ lam_inv
            self.info += s_w @ s
            self.vector += s_w @ e0
            self.chi2 += float(e0 @ lam_inv @ e0)
            self.n_updates += 1
            self.dof_total += yy.size
        if use_ss:
            gain = self.gain_ss
            self.cov = self.p_post_ss
        else:
            # K = P^ H^T Lambda^-1
            gain = self.cov @ h.T @ lam_inv
            # P = (I - K H) P^ (I - K H)^T + K R K^T   (Joseph form)
            i_kh = self.identity_n - gain @ h
            self.cov = i_kh @ self.cov @ i_kh.T + gain @ r @ gain.T
            self.cov = 0.5 * (self.cov + self.cov.T)
        # x = x^ + K e0 ; M = M^ - K S
        self.x = self.x + gain @ e0
        if s is not None:
            self.sens = self.sens - gain @ s
        if not use_ss:
            self.steady = False
            if regular:
                if np.abs(self.cov - self.p_post_ss).max() <= self.snap_tolerance * self.p_post_scale:
                    self.cov = self.p_post_ss.copy()
                    self.steady = True
        return StepInfo(nis_value, yy.size, True, post_nis, self.x.copy() if self.evaluation else None)

    # bulk path -------------------------------------------------------------------------------------
    def run_regular(self, y: ArrayLike, x_reg: ArrayLike | None = None, u0: ArrayLike | None = None,
                    u_reg: ArrayLike | None = None, want_states: bool = False,
                    want_innovations: bool = False) -> RegularRunOutput:
        """Process L regular samples in bulk (same result as L :meth:`step`).

        At the steady state the closed loop is time invariant (modal recursions). After an
        irregular sample the covariance is off its steady state: the first samples then go through
        :meth:`_run_transient` (the exact time-varying gains in closed form and the time-varying
        recursion by a parallel prefix scan, both vectorised) until the covariance is back at the
        steady state within ``snap_tolerance``, exactly where :meth:`step` would snap.

        Parameters
        ----------
        y : array_like
            (L, m) measurements (all present).
        x_reg : array_like or RegressorFactors, optional
            (L, m, p) measurement regressors, or their factors ``X_k = sum_s c_k,s P_s`` (at the
            steady state the cost per sample is then that of the few scalar series; see
            :mod:`~taiji2_estimator_pkg.core.factored_steady`).
        u0 : array_like, optional
            (L, n_u) known inputs of each step (the input of a segment's first sample is ignored).
        u_reg : array_like, optional
            (L, n_u, p) input regressors of each step.
        want_states, want_innovations : bool
            Evaluation mode only (see :meth:`evaluation_copy`): return the posterior states and
            the innovations; the NIS ``e^T Lambda^-1 e`` is always returned in evaluation mode.

        Returns
        -------
        RegularRunOutput
        """
        m = self.model.m
        y = np.asarray(y, dtype=np.float64).reshape(-1, m)
        if not isinstance(x_reg, RegressorFactors):
            x_reg = None if x_reg is None else np.asarray(x_reg, dtype=np.float64)
        u0 = None if u0 is None else np.asarray(u0, dtype=np.float64)
        if not isinstance(u_reg, RegressorFactors):
            u_reg = None if u_reg is None else np.asarray(u_reg, dtype=np.float64)
        parts: list[RegularRunOutput] = []
        start = 0
        while start < y.shape[0]:
            if self.steady and isinstance(x_reg, RegressorFactors) and self._real_modes and u0 is None \
                    and u_reg is None and not self.evaluation:
                run_steady_factored(self, y[start:], x_reg.rows(start, y.shape[0]))
                break
            if self.steady:
                stop = y.shape[0]
                u_rows = u_reg.rows(start, stop) if isinstance(u_reg, RegressorFactors) else _rows(u_reg, start, stop)
                parts.append(self._run_steady(y[start:], _rows(x_reg, start, stop), _rows(u0, start, stop),
                                              u_rows, want_states, want_innovations))
            else:
                stop = min(start + _TRANSIENT_CHUNK, y.shape[0])
                taken = self._run_transient(y[start:stop], _rows(x_reg, start, stop), _rows(u0, start, stop),
                                            _rows(u_reg, start, stop), want_states, want_innovations, parts)
                stop = start + taken
            start = stop
        out = RegularRunOutput()
        if self.evaluation and parts:
            out.nis = np.concatenate([part.nis for part in parts if part.nis is not None])
            if want_states:
                out.states = np.concatenate([part.states for part in parts if part.states is not None])
            if want_innovations:
                out.innovations = np.concatenate([part.innovations for part in parts
                                                  if part.innovations is not None])
        return out

    def _transient_covariances(self, p_first: np.ndarray, length: int) -> np.ndarray:
        """Prior covariances P_k, k = 0..length-1, of regular samples after P_0 = ``p_first``.

        With ``dP_k = P_k - P_ss`` (P_ss the steady-state prior), ``Abar = F (I - K_ss H)`` and
        ``M = H^T Lambda_ss^-1 H``, the Riccati recursion is exactly
        ``dP_{k+1} = Abar dP_k (I + M dP_k)^-1 Abar^T``, hence in closed form::

            dP_k = Abar^k dP_0 (I + W_k dP_0)^-1 Abar^kT,   W_k = sum_{j<k} Abar^jT M Abar^j,

        evaluated for all k at once (powers and sums by doubling, then one stacked solve).
        """
        mdl = self.model
        n = mdl.n
        closed = self.closed_loop
        # Abar^k and W_k for k = 0..L-1 by doubling (log2 L stacked real products):
        # Abar^(h+j) = Abar^j Abar^h, W_(h+j) = W_h + Abar^hT W_j Abar^h  (j < h)
        a_k = np.empty((length, n, n))
        w_k = np.empty((length, n, n))
        a_k[0] = np.eye(n)
        w_k[0] = 0.0
        if length > 1:
            a_k[1] = closed
            w_k[1] = mdl.h.T @ self.lambda_inv_ss @ mdl.h
        half = 2 if length > 2 else length
        while half < length:
            a_half = a_k[half // 2] @ a_k[half // 2]
            w_half = w_k[half // 2] + a_k[half // 2].T @ w_k[half // 2] @ a_k[half // 2]
            stop = min(2 * half, length)
            count = stop - half
            a_k[half:stop] = a_k[:count] @ a_half[None]
            w_k[half:stop] = w_half[None] + a_half.T[None] @ w_k[:count] @ a_half[None]
            half *= 2
        d0 = p_first - self.p_prior_ss
        d0 = 0.5 * (d0 + d0.T)
        eye = np.eye(mdl.n)
        # dP_0 (I + W_k dP_0)^-1 = [(I + dP_0 W_k)^-1 dP_0]^T  (dP_0, W_k symmetric)
        inner = np.linalg.solve(eye[None] + d0[None] @ w_k, np.broadcast_to(d0, w_k.shape))
        delta = a_k @ np.swapaxes(inner, 1, 2) @ np.swapaxes(a_k, 1, 2)
        delta = 0.5 * (delta + np.swapaxes(delta, 1, 2))
        return self.p_prior_ss[None] + delta

    def _run_transient(self, y: np.ndarray, x_reg: np.ndarray | None, u0: np.ndarray | None,
                       u_reg: np.ndarray | None, want_states: bool, want_innovations: bool,
                       parts: list[RegularRunOutput]) -> int:
        """Regular samples off the steady state, vectorised; returns how many were processed.

        Stops after the sample whose posterior covariance is within ``snap_tolerance`` of the
        steady state (the filter is then set to it, as :meth:`step` does), or at the end.
        """
        mdl = self.model
        n, m, p = mdl.n, mdl.m, self.p
        evaluation = self.evaluation
        f, h, b, r = mdl.f, mdl.h, mdl.b, mdl.r
        # prior of the first sample (a segment's first sample has no prediction)
        if self.fresh:
            p_first = self.cov
            z_first = np.column_stack((self.x, self.sens)) if not evaluation else self.x[:, None].copy()
        else:
            p_first = f @ self.cov @ f.T + mdl.q
            z_first = f @ (np.column_stack((self.x, self.sens)) if not evaluation else self.x[:, None])
            if u0 is not None:
                z_first[:, 0] += b @ u0[0]
            if u_reg is not None and not evaluation:
                z_first[:, 1:1 + p] += b @ u_reg[0]
        priors = self._transient_covariances(p_first, y.shape[0])
        # Lambda_k = H P_k H^T + R ; K_k = P_k H^T Lambda_k^-1 ; P+_k (Joseph)
        lam = h[None] @ priors @ h.T[None] + r[None]
        lam = 0.5 * (lam + np.swapaxes(lam, 1, 2))
        lam_inv = np.linalg.inv(lam)
        gains = priors @ h.T[None] @ lam_inv
        i_kh = np.eye(n)[None] - gains @ h[None]
        post = i_kh @ priors @ np.swapaxes(i_kh, 1, 2) + gains @ r[None] @ np.swapaxes(gains, 1, 2)
        close = np.max(np.abs(post - self.p_post_ss[None]), axis=(1, 2)) <= self.snap_tolerance * self.p_post_scale
        snapped = bool(np.any(close))
        count = int(np.argmax(close)) + 1 if snapped else y.shape[0]
        yc, gains, i_kh, lam_inv, post = y[:count], gains[:count], i_kh[:count], lam_inv[:count], post[:count]
        xc = None if (x_reg is None or evaluation) else x_reg[:count]
        # priors z_k = A_{k-1} z_{k-1} + D_k, A = F (I - K H), D_k = F K_{k-1} (y - X theta)_{k-1} + B (u0 + U theta)_k
        cols = z_first.shape[1]
        transition = f[None] @ i_kh[:-1]
        fk = f[None] @ gains[:-1]
        drive = np.zeros((count - 1, n, cols))
        drive[:, :, 0] = np.einsum("kij,kj->ki", fk, yc[:-1])
        if u0 is not None:
            drive[:, :, 0] += u0[1:count] @ b.T
        if not evaluation:
            if xc is not None:
                drive[:, :, 1:1 + p] -= fk @ xc[:-1]
            if u_reg is not None:
                drive[:, :, 1:1 + p] += b[None] @ u_reg[1:count]
        z = np.empty((count, n, cols))
        z[0] = z_first
        z[1:] = _affine_recursion(transition, drive, z_first)
        states = z[:, :, 0]
        e0 = yc - states @ h.T  # (count, m)
        ew = np.einsum("kij,kj->ki", lam_inv, e0)
        if evaluation:
            part = RegularRunOutput(nis=np.einsum("ki,ki->k", e0, ew))
            if want_states:
                part.states = states + np.einsum("kij,kj->ki", gains, e0)
            if want_innovations:
                part.innovations = e0.copy()
            parts.append(part)
            self.x = states[-1] + gains[-1] @ e0[-1]
        else:
            s = h[None] @ z[:, :, 1:]  # (count, m, qt)
            if xc is not None:
                s[:, :, :p] += xc
            sl = lam_inv @ s
            self.info += s.reshape(count * m, -1).T @ sl.reshape(count * m, -1)
            self.info = 0.5 * (self.info + self.info.T)
            self.vector += np.einsum("kiq,ki->q", s, ew)
            self.chi2 += float(np.sum(e0 * ew))
            self.n_updates += count
            self.dof_total += count * m
            self.x = states[-1] + gains[-1] @ e0[-1]
            self.sens = z[-1, :, 1:] - gains[-1] @ s[-1]
        self.fresh = False
        if snapped:
            self.cov = self.p_post_ss.copy()
            self.steady = True
        else:
            self.cov = 0.5 * (post[-1] + post[-1].T)
        return count

    def _run_steady(self, y: np.ndarray, x_reg: np.ndarray | None, u0: np.ndarray | None,
                    u_reg: np.ndarray | RegressorFactors | None, want_states: bool,
                    want_innovations: bool) -> RegularRunOutput:
        """Regular samples at the steady state: time-invariant closed loop, modal recursions.

        Only one mode of each conjugate pair is computed: its partner is the complex conjugate, so a
        real output ``X V w`` is ``sum_i c_i Re(X V[:, i] w_i)`` over the computed modes (c_i = 2 for
        a pair, 1 for a real mode). The columns of the initial-state parameters have no drive after
        the first sample: their modal coordinates are ``lambda_i^k w_0`` in closed form. Input
        regressors may come as factors ``U_k = sum_s c_k,s P_s``: their modal drive ``V^-1 B U_k``
        is then the few series times the constant ``V^-1 B P_s`` (one matrix product), without
        forming the (L, n_u, p) regressors."""
        mdl = self.model
        m, p, qt = mdl.m, self.p, self.q_total
        length = y.shape[0]
        out = RegularRunOutput()
        if length == 0:
            return out
        evaluation = self.evaluation
        # columns: data (0), parameters (1..p, driven by the regressors), initial state (p+1.., no drive)
        cols = 1 if evaluation else 1 + qt
        driven = 1 if evaluation else 1 + p
        nis_parts, state_parts, innov_parts = [], [], []
        gain, fk = self.gain_ss, mdl.f @ self.gain_ss
        i_kh = np.eye(mdl.n) - gain @ mdl.h
        computed = list(self._filtered_modes)
        paired = set(self._conjugate_partner.values())
        weight = np.array([2.0 if i in paired else 1.0 for i in computed])
        # V c (n, n_f): real outputs are Re(V c w); V^-1 rows of the computed modes (n_f, n)
        v_out, v_inv, modes = self.mode_vectors[:, computed] * weight, self.mode_vectors_inv[computed], \
            self.modes[computed]
        dtype: type = complex
        if self._real_modes:
            v_out, v_inv, modes, dtype = v_out.real, v_inv.real, modes.real, float
        n_f = len(computed)
        whiten_t = self._whiten.T
        v_b, v_fk, w_hv = v_inv @ mdl.b, v_inv @ fk, whiten_t @ mdl.h @ v_out
        xr_all = None if (x_reg is None or evaluation) else np.asarray(x_reg, dtype=np.float64)
        u0_all = None if u0 is None else np.asarray(u0, dtype=np.float64)
        ur_all = ur_series = vb_patterns = None
        if isinstance(u_reg, RegressorFactors) and not evaluation:
            ur_series, ur_patterns = u_reg.series, u_reg.patterns
            n_s = ur_patterns.shape[0]
            vb_patterns = np.einsum("nu,sup->snp", v_b, ur_patterns).reshape(n_s, n_f * p)
        elif u_reg is not None and not evaluation:
            ur_all = np.asarray(u_reg, dtype=np.float64)
        # lambda_i^k, k < chunk: the undriven columns
        powers = modes[:, None] ** np.arange(min(_CHUNK, length)) if cols > driven else None
        start = 0
        while start < length:
            stop = min(start + _CHUNK, length)
            count = stop - start
            yc = y[start:stop]
            xc = None if xr_all is None else xr_all[start:stop]
            # modal drive (n_f, count, driven) of w_k = lambda w_{k-1} + V^-1 D_k (index 0 unused), with
            # D_k = B (u0_k + U_k theta) + F K (y_{k-1} - X_{k-1} theta): built in modal coordinates
            modal_drive = np.empty((n_f, count, driven), dtype=dtype)
            modal_drive[:, 1:, 0] = v_fk @ yc[:-1].T
            if u0_all is not None:
                modal_drive[:, 1:, 0] += v_b @ u0_all[start + 1:stop].T
            # regressors measurement-major once per chunk: (m, count, p)
            xt = None if xc is None else np.ascontiguousarray(np.moveaxis(xc, 1, 0))
            if not evaluation:
                if xt is not None:
                    modal_drive[:, 1:, 1:] = -(v_fk @ xt.reshape(m, -1)).reshape(n_f, count, p)[:, :-1]
                if ur_all is not None:
                    input_drive = np.tensordot(v_b, ur_all[start + 1:stop], axes=([1], [1]))
                elif ur_series is not None:
                    input_drive = np.moveaxis(
                        (ur_series[start + 1:stop] @ vb_patterns).reshape(count - 1, n_f, p), 1, 0)
                else:
                    input_drive = None
                if input_drive is None and xt is None:
                    modal_drive[:, 1:, 1:] = 0.0
                elif input_drive is not None and xt is None:
                    modal_drive[:, 1:, 1:] = input_drive
                elif input_drive is not None:
                    modal_drive[:, 1:, 1:] += input_drive
            first = np.empty((mdl.n, cols))
            if self.fresh:
                first[:, 0] = self.x
                if not evaluation:
                    first[:, 1:] = self.sens
                self.fresh = False
            else:
                first[:, 0] = mdl.f @ self.x
                if u0_all is not None:
                    first[:, 0] += mdl.b @ u0_all[start]
                if not evaluation:
                    first[:, 1:] = mdl.f @ self.sens
                    if ur_all is not None:
                        first[:, 1:1 + p] += mdl.b @ ur_all[start]
                    elif ur_series is not None:
                        first[:, 1:1 + p] += mdl.b @ u_reg.rows(start, start + 1).dense()[0]
            w_first = v_inv @ first
            modal = np.empty((n_f, count, cols), dtype=dtype)
            modal[:, 0, :] = w_first
            if count > 1:
                for r in range(n_f):
                    first_order_recursion(modes[r], modal_drive[r, 1:], w_first[r, :driven],
                                          out=modal[r, 1:, :driven])
                if powers is not None:
                    modal[:, 1:, driven:] = powers[:, 1:count, None] * w_first[:, None, driven:]
            # prior states x^_k = Re(V c w_k) (data column) and innovations e0 = y - H x^
            states = v_out @ modal[:, :, 0]
            if dtype is complex:
                states = states.real
            e0 = yc.T - mdl.h @ states  # (m, count)
            if evaluation:
                ew = whiten_t @ e0
                nis_parts.append(np.sum(ew * ew, axis=0))
                if want_innovations:
                    innov_parts.append(e0.T)
                if want_states:
                    state_parts.append((states + gain @ e0).T)
                last = states[:, -1:]
            else:
                # whitened sensitivities L^T S, S = H M + X = Re(H V c w) + X (data column computed along)
                sw = np.tensordot(w_hv, modal, axes=([1], [0]))[:, :, 1:]  # (m, count, qt)
                sw = np.ascontiguousarray(sw.real if dtype is complex else sw)
                if xt is not None:
                    sw[:, :, :p] += (whiten_t @ xt.reshape(m, -1)).reshape(m, count, p)
                sw = sw.reshape(m * count, qt)
                ew = (whiten_t @ e0).reshape(-1)
                self.info += sw.T @ sw
                self.vector += sw.T @ ew
                self.chi2 += float(ew @ ew)
                self.n_updates += count
                self.dof_total += count * m
                last = v_out @ modal[:, -1, :]
                if dtype is complex:
                    last = last.real
            # posterior of the last step of the chunk
            self.x = i_kh @ last[:, 0] + gain @ yc[-1]
            if not evaluation:
                self.sens = i_kh @ last[:, 1:]
                if xc is not None:
                    self.sens[:, :p] -= gain @ xc[-1]
            start = stop
        self.cov = self.p_post_ss.copy()
        if evaluation:
            out.nis = np.concatenate(nis_parts)
            if want_states:
                out.states = np.concatenate(state_parts)
            if want_innovations:
                out.innovations = np.concatenate(innov_parts)
        return out

    def evaluation_copy(self, theta: ArrayLike) -> TwoStageFilter:
        """A copy that only propagates the state for fixed parameters ``theta`` (q_total,).

        In it the sensitivities are folded into the state (``x <- x + M theta``): the caller feeds
        the known inputs ``u0 + U theta_p`` and measurements ``y - X theta_p``; each update then
        yields the innovation of the full filter at ``theta`` and its NIS, at the cost of a single
        column. No information is accumulated. After :meth:`reset_segment` set :attr:`x` to the
        new segment's initial state.
        """
        clone = copy.copy(self)
        clone.x = self.x + self.sens @ np.asarray(theta, dtype=np.float64)
        clone.sens = np.zeros_like(self.sens)
        clone.cov = self.cov.copy()
        clone.info = self.info.copy()
        clone.vector = self.vector.copy()
        clone.segment_x0 = list(self.segment_x0)
        clone.evaluation = True
        return clone

    # checkpoint -------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Checkpoint (plain lists and numbers)."""
        return {
            "x": self.x.tolist(), "sens": self.sens.tolist(), "cov": self.cov.tolist(),
            "fresh": self.fresh, "steady": self.steady, "info": self.info.tolist(),
            "vector": self.vector.tolist(), "chi2": self.chi2, "n_updates": self.n_updates,
            "n_rejected": self.n_rejected, "dof_total": self.dof_total, "n_segments": self.n_segments,
            "segment_x0": [[a.tolist(), b.tolist()] for a, b in self.segment_x0],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a checkpoint of :meth:`state_dict` (same model and p)."""
        self.x = np.asarray(state["x"], dtype=np.float64)
        self.sens = np.asarray(state["sens"], dtype=np.float64)
        self.cov = np.asarray(state["cov"], dtype=np.float64)
        self.fresh = bool(state["fresh"])
        self.steady = bool(state["steady"])
        if self.steady:
            self.cov = (self.p_prior_ss if self.fresh else self.p_post_ss).copy()
        self.info = np.asarray(state["info"], dtype=np.float64)
        self.vector = np.asarray(state["vector"], dtype=np.float64)
        self.chi2 = float(state["chi2"])
        self.n_updates = int(state["n_updates"])
        self.n_rejected = int(state["n_rejected"])
        self.dof_total = int(state["dof_total"])
        self.n_segments = int(state["n_segments"])
        self.segment_x0 = [(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
                           for a, b in state.get("segment_x0", [])]
