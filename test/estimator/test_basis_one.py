"""ComOffsetModel.basis_one (the running estimator's per-epoch basis, issue 26 row 9) equals the dense basis."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.core.com_offset.model import ComOffsetModel, ComOffsetOptions
from taiji2_estimator_pkg.core.instrument import InstrumentModel


@pytest.mark.parametrize("detrend", ["linear", "constant", "none"])
def test_basis_one_equals_the_dense_basis(detrend):
    model = ComOffsetModel(InstrumentModel.from_layout("type1"), (1, 2), ComOffsetOptions(detrend=detrend))
    rng = np.random.default_rng(26)
    for _ in range(20):
        sums, diffs = rng.normal(size=(2, 3)), rng.normal(size=(2, 3))
        omega, tau = rng.normal(size=3) * 1e-4, float(rng.normal())
        dense = model.basis(sums[None], diffs[None], omega[None], np.array([tau]), np.ones((1, 2), dtype=bool))[0]
        # rounding only: products of the same factors summed in another order
        np.testing.assert_allclose(model.basis_one(sums, diffs, omega, tau), dense, rtol=0,
                                   atol=1e-15 * np.max(np.abs(dense)))
