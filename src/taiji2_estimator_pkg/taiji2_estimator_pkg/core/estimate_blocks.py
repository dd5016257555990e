"""Per-GRS blocks of a joint estimate: the parameter vector holds 3 values per GRS, in ``grs_ids`` order."""

from __future__ import annotations

import numpy as np


class PerGrsBlocks:
    """Accessors shared by the joint estimates; needs ``grs_ids``, ``values`` and ``covariance``."""

    grs_ids: tuple[int, ...]
    values: np.ndarray
    covariance: np.ndarray

    def of(self, grs_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(values (3,), covariance (3, 3)) of one GRS."""
        i = self.grs_ids.index(grs_id)
        block = slice(3 * i, 3 * i + 3)
        return self.values[block], self.covariance[block, block]

    @property
    def sigma(self) -> np.ndarray:
        """(3 n_grs,) 1-sigma, in the units of ``values``."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
