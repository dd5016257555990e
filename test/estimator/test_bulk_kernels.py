"""Numerical kernels written to keep scipy.signal / scipy.stats out of the estimators' imports."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import chi2

from taiji2_estimator_pkg.core.kalman import chi2_gate, chi2_survival
from taiji2_estimator_pkg.core.twostage import _affine_recursion, first_order_recursion


@pytest.mark.parametrize("lam", [0.99957701 + 0.00042281j, 0.99968919, 0.5, 0.3 - 0.2j, 1e-3, 0.0, 0.999999])
@pytest.mark.parametrize("length", [1, 2, 7, 5000, 40000])
def test_first_order_recursion_equals_lfilter(lam, length):
    # tolerance: 1e-12 relative (the blocks bound the growth of rounding to ~100 eps)
    rng = np.random.default_rng(length)
    x = rng.normal(size=(length, 5)) + (1j * rng.normal(size=(length, 5)) if isinstance(lam, complex) else 0.0)
    initial = rng.normal(size=5)
    reference, _ = lfilter([1.0], [1.0, -lam], x, axis=0, zi=(lam * initial)[None, :])
    result = first_order_recursion(lam, x, initial)
    assert np.max(np.abs(result - reference)) <= 1e-12 * np.max(np.abs(reference))


@pytest.mark.parametrize("steps", [1, 2, 5, 97, 1000])
def test_affine_recursion_equals_the_loop(steps):
    rng = np.random.default_rng(steps)
    transition = 0.3 * rng.normal(size=(steps, 4, 4))
    drive = rng.normal(size=(steps, 4, 3))
    initial = _initial(steps)
    np.testing.assert_allclose(_affine_recursion(transition, drive, initial), _loop(transition, drive, initial),
                               rtol=1e-12, atol=1e-12)


def _initial(seed):
    return np.random.default_rng(seed + 1).normal(size=(4, 3))


def _loop(transition, drive, z):
    out = np.empty_like(drive)
    for i in range(drive.shape[0]):
        z = transition[i] @ z + drive[i]
        out[i] = z
    return out


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 9, 63])
def test_chi2_gate_equals_scipy(dof):
    for probability in (1e-12, 1e-6, 1e-3, 0.5):
        assert chi2_gate(dof, probability) == pytest.approx(chi2.isf(probability, dof), rel=1e-12)
    for x in (0.1, 1.0, 5.0, 30.0, 100.0):
        assert chi2_survival(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-12, abs=1e-300)
