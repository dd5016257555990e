"""A validated record as arrays per epoch (the bulk paths of both estimators)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.attitude import integrate_attitude
from taiji2_estimator_pkg.core.instrument import angular_differences, linear_sums


@dataclass
class EpochArrays:
    """Per-epoch arrays of a validated record (epochs with at least one usable input)."""

    index: np.ndarray
    t: np.ndarray
    t0: float
    st_ok: np.ndarray
    grs_ok: np.ndarray
    phi: np.ndarray
    diffs: np.ndarray
    sums: np.ndarray
    last_quat: np.ndarray
    last_phi: np.ndarray

    @property
    def count(self) -> int:
        return int(self.index.size)

    @classmethod
    def build(cls, checked: Any, t: np.ndarray, volts: np.ndarray) -> EpochArrays:
        usable = (checked.grid_index >= 0) & (checked.star_tracker_ok | np.any(checked.grs_ok, axis=1))
        rows = np.flatnonzero(usable)
        phi_all = integrate_attitude(checked.quat_xyzw, checked.star_tracker_ok)
        st_rows = np.flatnonzero(checked.star_tracker_ok)
        last_quat = checked.quat_xyzw[st_rows[-1]] if st_rows.size else np.array([0.0, 0.0, 0.0, 1.0])
        last_phi = phi_all[st_rows[-1]] if st_rows.size else np.zeros(3)
        first_stamp = int(np.flatnonzero(checked.grid_index >= 0)[0]) if np.any(checked.grid_index >= 0) else 0
        t0 = float(t[first_stamp]) if t.size else 0.0
        index = checked.grid_index[rows]
        if rows.size:
            index = index - index[0]
            t0 = float(t[rows[0]])
        st_ok = checked.star_tracker_ok[rows]
        phi = np.where(st_ok[:, None], phi_all[rows], 0.0)
        grs_ok = checked.grs_ok[rows]
        # every row usable (the common case): no copy of the voltages
        usable_volts = volts if rows.size == volts.shape[0] else volts[rows]
        finite = np.isfinite(usable_volts)
        if not finite.all():
            usable_volts = np.where(finite, usable_volts, 0.0)
        diffs, sums = angular_differences(usable_volts), linear_sums(usable_volts)
        if not grs_ok.all():  # a GRS sample rejected: no information from it
            diffs[~grs_ok] = 0.0
            sums[~grs_ok] = 0.0
        return cls(index, t[rows], t0, st_ok, grs_ok, phi, diffs, sums, last_quat, last_phi)
