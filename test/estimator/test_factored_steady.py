"""The factored steady-state accumulation equals the dense one (the c.m.-offset estimator's bulk path)."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.core.com_offset import ComOffsetModel, ComOffsetOptions
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.twostage import TwoStageFilter


def _epochs(length: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Voltage sums/differences [V], rates [rad/s] and trend of the scales a calibration sees."""
    rng = np.random.default_rng(seed)
    sums = 1e-3 * rng.normal(size=(length, 2, 3))
    diffs = 1e-2 * rng.normal(size=(length, 2, 3))
    omega = 1e-5 * rng.normal(size=(length, 3))
    tau = np.arange(length) * 0.1 / 1000.0
    return sums, diffs, omega, tau


@pytest.fixture(scope="module", params=["linear", "constant", "none"])
def model(request):
    return ComOffsetModel(InstrumentModel.from_layout("type2"), (1, 2), ComOffsetOptions(detrend=request.param))


def test_basis_factors_equal_the_basis(model):
    # tolerance: 1e-13 of each column's largest entry (one product and one sum per entry differ in rounding)
    epochs = _epochs(500, 1)
    dense = model.basis_factors(*epochs).dense()
    reference = model.basis(*epochs)
    scale = np.max(np.abs(reference), axis=(0, 1), keepdims=True)
    assert np.all(np.abs(dense - reference) <= 1e-13 * np.where(scale > 0, scale, 1.0))


def _normalised(info: np.ndarray) -> np.ndarray:
    diag = np.diag(info)
    scale = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))
    return info * scale[:, None] * scale[None, :]


def test_factored_run_equals_dense_run(model):
    """Same information, normal vector, chi-square and carried state as the dense path.

    Two consecutive runs (the second continues from the carried posterior), the first one after a
    partial-measurement step, so that it starts with a transient (densified) and reaches the steady
    state inside the run. Tolerance: 1e-9 of the normalised information (correlations) and of the
    largest entry of the other sums, far below the 1e-6 sigma the estimates are held to, and far
    above rounding (~1e-13 over 10^5 samples).
    """
    filters = [TwoStageFilter(model.state_space, model.n_columns) for _ in range(2)]
    rng = np.random.default_rng(7)
    first = rng.normal(size=model.m) * 1e-9
    for filt in filters:
        filt.step(first, model.basis(*_epochs(1, 9))[0], rows=np.arange(model.m) < 3)
    for seed, length in ((2, 60000), (3, 9000)):
        epochs = _epochs(length, seed)
        y = 1e-9 * rng.normal(size=(length, model.m))
        filters[0].run_regular(y, model.basis(*epochs))
        filters[1].run_regular(y, model.basis_factors(*epochs))
    dense, factored = filters
    assert dense.steady and factored.steady
    assert np.max(np.abs(_normalised(factored.info) - _normalised(dense.info))) <= 1e-9
    for name in ("vector", "x", "sens"):
        a, b = getattr(dense, name), getattr(factored, name)
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(a)), name
    assert factored.chi2 == pytest.approx(dense.chi2, rel=1e-9)
    assert (factored.n_updates, factored.dof_total) == (dense.n_updates, dense.dof_total)
