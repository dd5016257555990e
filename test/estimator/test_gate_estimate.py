"""The gates' factored estimate (core/gate_estimate.py) equals the solve by inverse it replaces, and declines
where the information has no Cholesky factor or is too ill-conditioned to be certainly determined."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.core.gate_estimate import MIN_EIGENVALUE_RATIO, GateEstimate, gate_estimate
from taiji2_estimator_pkg.core.twostage import solve_information


def _information(rng: np.random.Generator, size: int, spread_decades: float) -> np.ndarray:
    rows = rng.normal(size=(4 * size, size)) * np.logspace(-spread_decades, spread_decades, size)
    return rows.T @ rows


def test_factored_estimate_equals_the_inverse():
    rng = np.random.default_rng(23)
    for size, decades in ((12, 6.0), (21, 3.0)):
        info, vector = _information(rng, size, decades), rng.normal(size=size)
        theta, covariance, full = solve_information(info, vector, positive=True)
        solved = gate_estimate(info, vector, MIN_EIGENVALUE_RATIO)
        assert full and solved is not None
        np.testing.assert_allclose(solved[0], theta, rtol=1e-10, atol=0)
        rows = rng.normal(size=(3, size))
        estimate = GateEstimate(*solved)
        np.testing.assert_allclose(estimate.spread(rows), rows @ covariance @ rows.T, rtol=1e-10, atol=0)
        # through a mapping (the c.m.-offset's engine parameters as a function of its solved coordinates)
        mapping = rng.normal(size=(size + 5, size))
        rows = rng.normal(size=(6, size + 5))
        mapped = GateEstimate(mapping @ solved[0], solved[1], solved[2], mapping)
        expected = rows @ (mapping @ covariance @ mapping.T) @ rows.T
        np.testing.assert_allclose(mapped.spread(rows), expected, rtol=1e-9, atol=0)
        given = GateEstimate.from_covariance(mapping @ theta, covariance, mapping)
        np.testing.assert_allclose(given.spread(rows), expected, rtol=1e-12, atol=0)


def test_declines_without_a_factor_or_near_the_pseudo_inverse_cut():
    rng = np.random.default_rng(24)
    info = _information(rng, 6, 1.0)
    vector = rng.normal(size=6)
    singular = info.copy()
    singular[:, 0] = singular[0, :] = 0.0
    assert gate_estimate(singular, vector) is None  # a zero diagonal: undetermined
    indefinite = np.array([[1.0, 2.0], [2.0, 1.0]])  # a positive diagonal, eigenvalues -1 and 3
    assert gate_estimate(indefinite, vector[:2]) is None  # no Cholesky factor
    # an eigenvalue ratio of 1e-14 (after the Jacobi scaling): positive definite, but below the cut
    q, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    close = (q * np.array([1e-14, 0.5, 1.0, 1.5, 2.0, 1.0])) @ q.T
    assert np.min(np.linalg.eigvalsh(close)) > 0.0
    assert gate_estimate(close, vector) is not None
    assert gate_estimate(close, vector, MIN_EIGENVALUE_RATIO) is None
