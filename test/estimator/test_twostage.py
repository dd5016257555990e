"""Two-stage filter: exact GLS with a diffuse initial state, bulk == per-sample, segments, checkpoints."""

import copy
import json

import numpy as np
from scipy.linalg import solve_discrete_are

from taiji2_estimator_pkg.core.twostage import (
    StateSpaceModel,
    TwoStageFilter,
    solve_information,
    steady_state_prior_covariance,
)

DT = 0.1
N_AX = 2


def _model() -> StateSpaceModel:
    f1 = np.array([[1.0, DT], [0.0, 1.0]])
    b1 = np.array([[DT * DT / 2], [DT]])
    f = np.kron(f1, np.eye(N_AX))
    b = np.kron(b1, np.eye(N_AX))
    h = np.kron(np.array([[1.0, 0.0]]), np.eye(N_AX))
    q = b @ np.diag([0.3**2, 0.7**2]) @ b.T
    return StateSpaceModel(f, b, q, h, np.eye(N_AX), blocks=((0, 2), (1, 3)))


def _data(n: int = 300, p: int = 3, seed: int = 1) -> tuple:
    rng = np.random.default_rng(seed)
    mdl = _model()
    u_reg = rng.normal(size=(n, N_AX, p))
    u0 = rng.normal(size=(n, N_AX))
    x_reg = rng.normal(size=(n, N_AX, p)) * 0.1
    theta = np.array([1.0, -2.0, 0.5])
    x = np.array([3.0, 1.0, 0.2, -0.1])
    y = []
    for k in range(n):
        if k:
            x = mdl.f @ x + mdl.b @ (u0[k] + u_reg[k] @ theta + rng.normal(size=N_AX) * np.array([0.3, 0.7]))
        y.append(mdl.h @ x + x_reg[k] @ theta + rng.normal(size=N_AX))
    return np.array(y), x_reg, u0, u_reg


def _dense_gls(y, x_reg, u0, u_reg):
    """Brute-force GLS with the full covariance of the stacked record and a diffuse x0."""
    mdl = _model()
    n, m = y.shape
    p = u_reg.shape[2]
    nx = mdl.n
    powers = [np.linalg.matrix_power(mdl.f, k) for k in range(n)]
    a_psi = np.zeros((n * m, nx))
    a_th = np.zeros((n * m, p))
    known = np.zeros(n * m)
    l_w = np.zeros((n * m, (n - 1) * N_AX))
    for k in range(n):
        a_psi[k * m:(k + 1) * m] = mdl.h @ powers[k]
        acc, kn = np.zeros((nx, p)), np.zeros(nx)
        for j in range(1, k + 1):
            gain = powers[k - j] @ mdl.b
            acc += gain @ u_reg[j]
            kn += gain @ u0[j]
            l_w[k * m:(k + 1) * m, (j - 1) * N_AX:j * N_AX] = mdl.h @ gain
        a_th[k * m:(k + 1) * m] = mdl.h @ acc + x_reg[k]
        known[k * m:(k + 1) * m] = mdl.h @ kn
    sigma = l_w @ np.kron(np.eye(n - 1), np.diag([0.3**2, 0.7**2])) @ l_w.T + np.eye(n * m)
    a = np.hstack([a_th, a_psi])
    s_inv = np.linalg.inv(sigma)
    info = a.T @ s_inv @ a
    vec = a.T @ s_inv @ (y.reshape(-1) - known)
    marginal = info[:p, :p] - info[:p, p:] @ np.linalg.solve(info[p:, p:], info[p:, :p])
    return np.linalg.solve(info, vec)[:p], np.linalg.inv(marginal)


def test_equals_dense_gls_with_diffuse_initial_state():
    y, x_reg, u0, u_reg = _data()
    filt = TwoStageFilter(_model(), 3)
    for k in range(y.shape[0]):
        filt.step(y[k], x_reg[k], u0[k], u_reg[k])
    theta, cov, determined = filt.parameter_estimate()
    theta_d, cov_d = _dense_gls(y, x_reg, u0, u_reg)
    assert determined
    np.testing.assert_allclose(theta, theta_d, rtol=1e-9)
    np.testing.assert_allclose(cov, cov_d, rtol=1e-9)


def test_bulk_equals_per_sample():
    y, x_reg, u0, u_reg = _data(1500)
    per_sample = TwoStageFilter(_model(), 3)
    bulk = copy.deepcopy(per_sample)
    for k in range(y.shape[0]):
        per_sample.step(y[k], x_reg[k], u0[k], u_reg[k])
    bulk.run_regular(y, x_reg, u0, u_reg)
    np.testing.assert_allclose(bulk.info, per_sample.info, rtol=1e-11, atol=1e-11 * np.max(np.abs(bulk.info)))
    np.testing.assert_allclose(bulk.parameter_estimate()[0], per_sample.parameter_estimate()[0], rtol=1e-10)
    np.testing.assert_allclose(bulk.x, per_sample.x, rtol=1e-10, atol=1e-12)


def test_missing_samples_and_snap_back():
    y, x_reg, u0, u_reg = _data(2000)
    filt = TwoStageFilter(_model(), 3)
    for k in range(y.shape[0]):
        filt.step(None if k in (100, 101, 300) else y[k], x_reg[k], u0[k], u_reg[k])
        if k == 101:
            assert not filt.steady
    assert filt.steady  # back at the steady state, bulk path usable again
    theta, cov, _ = filt.parameter_estimate()
    assert np.all(np.abs(theta - np.array([1.0, -2.0, 0.5])) < 5 * np.sqrt(np.diag(cov)))


def test_segment_reset_marginalises_the_old_initial_state():
    y, x_reg, u0, u_reg = _data(800)
    joined = TwoStageFilter(_model(), 3)
    first, second = TwoStageFilter(_model(), 3), TwoStageFilter(_model(), 3)
    joined.run_regular(y[:400], x_reg[:400], u0[:400], u_reg[:400])
    joined.reset_segment()
    joined.run_regular(y[400:], x_reg[400:], u0[400:], u_reg[400:])
    first.run_regular(y[:400], x_reg[:400], u0[:400], u_reg[:400])
    second.run_regular(y[400:], x_reg[400:], u0[400:], u_reg[400:])

    def marginal(f):
        info = f.info
        return info[:3, :3] - info[:3, 3:] @ np.linalg.solve(info[3:, 3:], info[3:, :3])

    np.testing.assert_allclose(marginal(joined), marginal(first) + marginal(second), rtol=1e-9)


def test_checkpoint_round_trip_resumes_identically():
    y, x_reg, u0, u_reg = _data(400)
    full = TwoStageFilter(_model(), 3)
    full.run_regular(y, x_reg, u0, u_reg)
    half = TwoStageFilter(_model(), 3)
    half.run_regular(y[:200], x_reg[:200], u0[:200], u_reg[:200])
    state = json.loads(json.dumps(half.state_dict()))
    resumed = TwoStageFilter(_model(), 3)
    resumed.load_state_dict(state)
    resumed.run_regular(y[200:], x_reg[200:], u0[200:], u_reg[200:])
    np.testing.assert_allclose(resumed.parameter_estimate()[0], full.parameter_estimate()[0], rtol=1e-12)


def test_steady_state_covariance_and_solver():
    mdl = _model()
    reference = solve_discrete_are(mdl.f.T, mdl.h.T, mdl.q, mdl.r)
    np.testing.assert_allclose(steady_state_prior_covariance(mdl.f, mdl.h, mdl.q, mdl.r), reference, rtol=1e-9,
                               atol=1e-12)
    # tiny process-to-measurement ratio (SRP-like): fixed point of the Riccati map to 1e-12
    f, h, q, r = 0.99999 * np.eye(1), np.ones((1, 1)), np.array([[1e-27]]), np.array([[1e-20]])
    p = steady_state_prior_covariance(f, h, q, r)
    riccati = f @ p @ f.T - f @ p @ h.T @ np.linalg.solve(h @ p @ h.T + r, h @ p @ f.T) + q
    assert abs(riccati[0, 0] - p[0, 0]) < 1e-12 * p[0, 0]
    # information solver: undetermined direction reported
    theta, cov, full = solve_information(np.diag([1.0, 0.0]), np.array([2.0, 0.0]))
    assert not full and theta[0] == 2.0 and cov[1, 1] == 0.0
