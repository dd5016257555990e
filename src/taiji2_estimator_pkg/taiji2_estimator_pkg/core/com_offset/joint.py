"""Joint estimate of the c.m. offsets d and the scale factors G from every channel.

The scale-factor stage (star tracker + GRS angular readouts, :mod:`.scale_factor`) gives
``G^`` with covariance ``P_G``; the linear readouts also carry information on G, because the
regressor ``A~ d = omega_dot^(G) x d + ...`` and the data ``z(G) = C^T diag(r G_perm) s`` both
depend on it (on the ratios of its components: a common scale of G cancels). The two-stage
estimate ``d(G^)``, ``P_d = P_d|G + J P_G J^T`` leaves that information unused; this module takes
it. Unknowns ``theta = (G, beta)``, beta = (d, per-GRS bias and trend, SRP initial state).

Objective (Gaussian likelihood of the G prior and of the whitened linear residuals)::

    Phi(theta) = (G - G^)^T P_G^-1 (G - G^) + w(theta)^T I_c w(theta),
    w(theta)   = a_y(G) - A_x(G) beta          (combination of the whitened basis columns),

``I_c`` the cross-product of the whitened basis columns less its expected errors-in-variables
part (:meth:`.com_offset.ComOffsetModel.eiv_correction`). Gauss-Newton on theta with the *mean*
Jacobian ``T``::

    dw/dbeta = -A_x(G)
    dw/dG_j  = J_j - X^(j) beta_d      (J_j: mean of the data column, X^(j): the regressor block)
    H = T^T I_c T + blkdiag(P_G^-1, 0)
    g = T^T I_c w + (P_G^-1 (G - G^), 0)
    theta <- theta - H^-1 g

converges in 2-3 steps (bilinear, G known to 5e-4). ``H^-1`` is the covariance of the joint
estimate, the G-d cross-covariance included; evaluated on noise-free signals at the truth it is
the Cramer-Rao bound of the full model (:func:`.crlb.crlb`).

Why the mean Jacobian for the data column: the data column is ``C^T e_a r s_a``, whose noise
(the common spacecraft acceleration, seen by both GRS) would add information on G through the
noise level and the assumed linear/angular ratio r. That is second-moment information: neither
the Fisher bound of the means nor real hardware (r is not known to 1e-4) supports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taiji2_estimator_pkg.core.twostage import solve_information

__all__ = ["JointSolution", "joint_information", "solve_joint"]

#: Gauss-Newton stops when every step is below this fraction of its parameter's sigma. The steps contract
#: quadratically (0.3 -> 7e-4 -> 3e-6 sigma on a 1,200-s Type-1 record) down to a rounding floor of ~1e-6 sigma
#: (the (beta, x0) information has condition numbers up to 1e13): a tolerance at that floor (1e-6, before
#: 2026-11-28) ran a third of the estimates to _MAX_STEPS on rounding noise; at 1e-4 the iteration takes 3 steps
#: and leaves the fixed point by ~contraction x 1e-4 sigma (estimates moved by a median 4e-8 sigma, at most
#: 2e-4 sigma in the first minute after d is determined)
_STEP_TOLERANCE_SIGMA = 1e-4
_MAX_STEPS = 12


@dataclass(frozen=True)
class JointSolution:
    """Joint estimate of (G, beta).

    Attributes
    ----------
    g : numpy.ndarray
        (n_g,) scale factors [rad s^-2 V^-1] (the linear channels' information included).
    beta : numpy.ndarray
        (n_beta + 3,) d, nuisance, SRP initial state.
    covariance : numpy.ndarray
        (n_g + n_beta + 3, n_g + n_beta + 3) covariance of (G, beta).
    steps : int
        Gauss-Newton steps taken.
    converged : bool
        Whether the last step was below tolerance.
    """

    g: np.ndarray
    beta: np.ndarray
    covariance: np.ndarray
    steps: int
    converged: bool


def joint_information(model: object, info_columns: np.ndarray, g: np.ndarray, beta: np.ndarray,
                      g_information: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton system of the joint problem at (g, beta).

    Parameters
    ----------
    model : ComOffsetModel
        Column layout (``col_data``, ``col_jac``, ``col_xj``, ``combination``).
    info_columns : numpy.ndarray
        (q, q) whitened cross-product of the basis columns (EIV-corrected), SRP initial state last.
    g : numpy.ndarray
        (n_g,) scale factors.
    beta : numpy.ndarray
        (n_beta + 3,) d, nuisance, SRP initial state.
    g_information : numpy.ndarray
        (n_g, n_g) information of the scale-factor stage on G, ``P_G^-1``.

    Returns
    -------
    hessian : numpy.ndarray
        (p, p) ``T^T I_c T + blkdiag(P_G^-1, 0)``: the information on (G, beta).
    score : numpy.ndarray
        (p,) ``T^T I_c w`` (the prior's part is the caller's: it needs G^).
    t : numpy.ndarray
        (q, p) the mean Jacobian T.
    """
    n_g, n_d = model.n_g, model.n_d
    q = info_columns.shape[0]
    a_y, a_x = model.combination(g)
    n_b = beta.size
    a_xx = np.zeros((q, n_b))
    a_xx[:model.n_columns, :model.n_beta] = a_x
    a_xx[model.n_columns:, model.n_beta:] = np.eye(n_b - model.n_beta)
    a_yy = np.zeros(q)
    a_yy[:model.n_columns] = a_y
    w = a_yy - a_xx @ beta
    t = np.zeros((q, n_g + n_b))
    for j in range(n_g):
        t[model.col_jac.start + j, j] = 1.0              # mean of the data column: dz/dG_j
        t[model.col_xj[j], j] -= beta[:n_d]             # regressor: -X^(j) beta_d
    t[:, n_g:] = -a_xx
    it = info_columns @ t
    hessian = t.T @ it
    hessian[:n_g, :n_g] += g_information
    return 0.5 * (hessian + hessian.T), it.T @ w, t


def solve_joint(model: object, info_columns: np.ndarray, g_prior: np.ndarray, p_g: np.ndarray,
                beta_start: np.ndarray) -> JointSolution:
    """Gauss-Newton solution of the joint problem from the two-stage solution.

    Parameters
    ----------
    model : ComOffsetModel
        Column layout.
    info_columns : numpy.ndarray
        (q, q) EIV-corrected whitened cross-product of the basis columns.
    g_prior : numpy.ndarray
        (n_g,) scale factors of the scale-factor stage.
    p_g : numpy.ndarray
        (n_g, n_g) their covariance.
    beta_start : numpy.ndarray
        (n_beta + 3,) the two-stage beta at ``g_prior``.
    """
    n_g = g_prior.size
    g_information, _, _ = solve_information(p_g, np.eye(n_g))
    g = np.array(g_prior, dtype=np.float64)
    beta = np.array(beta_start, dtype=np.float64)
    converged = False
    steps = 0
    while steps < _MAX_STEPS and not converged:
        steps += 1
        hessian, score, _ = joint_information(model, info_columns, g, beta, g_information)
        score[:n_g] += g_information @ (g - g_prior)
        step, covariance, _ = solve_information(hessian, -score)
        g = g + step[:n_g]
        beta = beta + step[n_g:]
        sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0))
        converged = bool(np.all(np.abs(step) <= _STEP_TOLERANCE_SIGMA * np.where(sigma > 0.0, sigma, np.inf)))
    # the covariance at the solution (the last step's is at the point before it)
    hessian, _, _ = joint_information(model, info_columns, g, beta, g_information)
    _, covariance, _ = solve_information(hessian, np.zeros(hessian.shape[0]))
    return JointSolution(g, beta, 0.5 * (covariance + covariance.T), steps, converged)
