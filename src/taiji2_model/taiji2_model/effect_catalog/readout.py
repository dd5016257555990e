"""Readout effects of a GRS: scale-factor drift, cross-coupling, readout nonlinearity.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.effect_catalog.base import (
    ANGULAR_READOUTS,
    ELECTRODE_PAIRS,
    LINEAR_READOUTS,
    _CatalogEffect,
    _choice,
    _grs,
    _scalar,
    _vector,
)
from taiji2_model.frames import cross


class ScaleFactorDrift(_CatalogEffect):
    """Linear drift of the scale factors of one electrode pair of one GRS.

    The preload voltage and the electrode gaps set both the angular and the linear scale factor of
    a pair (paper, scale-factor table), so both drift together:
    ``G(t) = G (1 + rate_per_s (t - t_ref_s))``.

    Parameters
    ----------
    rate_per_s : float
        Relative drift rate [1/s] (e.g. 1e-7 /s = 0.1 % per 3 h).
    grs : int
        1 or 2.
    axis : str
        Electrode pair ``"x"`` (psi and x), ``"y"`` (phi and y) or ``"z"`` (theta and z).
    t_ref_s : float
        Time at which G equals its configured value [s].
    enabled : bool
        Switch.
    """

    name = "scale_factor_drift"
    _params = ("rate_per_s", "grs", "axis", "t_ref_s")
    ONSET_KIND = "ramp"

    def __init__(self, rate_per_s: float = 0.0, grs: int = 1, axis: str = "x", t_ref_s: float = 0.0,
                 enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.rate_per_s = _scalar(self.name, "rate_per_s", rate_per_s)
        self.grs = _grs(self.name, grs)
        self.axis = _choice(self.name, "axis", axis, ELECTRODE_PAIRS)
        self.t_ref_s = _scalar(self.name, "t_ref_s", t_ref_s)

    @property
    def active(self) -> bool:
        return self.enabled and self.rate_per_s != 0.0

    def grs_scale_factors(self, t_s: np.ndarray, grs_id: int, angular_scale_factors: np.ndarray,
                          linear_scale_factors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.active or grs_id != self.grs:
            return angular_scale_factors, linear_scale_factors
        factor = 1.0 + self.rate_per_s * (self._clock(t_s) - self.t_ref_s)
        angular_index, linear_index = ELECTRODE_PAIRS[self.axis]
        count = factor.shape[0]
        angular = np.array(np.broadcast_to(angular_scale_factors, (count, 3)))
        linear = np.array(np.broadcast_to(linear_scale_factors, (count, 3)))
        angular[:, angular_index] = angular[:, angular_index] * factor
        linear[:, linear_index] = linear[:, linear_index] * factor
        return angular, linear


class CrossCoupling(_CatalogEffect):
    """GRS axis misalignment and electrode gain imbalance (angular <-> linear cross-talk).

    - Misalignment: the GRS axes are rotated by the small rotation vector ``eps`` (TMRF) from
      their nominal C_i, so it reads ``a - eps x a`` for every angular and linear acceleration a.
    - Imbalance: the two electrodes of pair e have gains ``1 + eta_e`` and ``1 - eta_e``; the sum
      then picks up the difference and vice versa: linear ``+= eta r alpha`` and angular
      ``+= eta a / r`` (r = G_lin / G_ang), i.e. angular-to-linear cross-talk.

    Parameters
    ----------
    grs : int
        1 or 2.
    misalignment_rad : array_like
        (3,) rotation vector eps about TMRF x, y, z [rad].
    imbalance : array_like
        (3,) eta for the electrode pairs x, y, z [1].
    enabled : bool
        Switch.
    """

    name = "cross_coupling"
    _params = ("grs", "misalignment_rad", "imbalance")

    def __init__(self, grs: int = 1, misalignment_rad: ArrayLike = 0.0, imbalance: ArrayLike = 0.0,
                 enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.grs = _grs(self.name, grs)
        self.misalignment_rad = _vector(self.name, "misalignment_rad", misalignment_rad)
        self.imbalance = _vector(self.name, "imbalance", imbalance)

    @property
    def active(self) -> bool:
        return self.enabled and bool(np.any(self.misalignment_rad) or np.any(self.imbalance))

    def grs_accelerations(self, t_s: np.ndarray, grs_id: int, angular_rad_s2: np.ndarray,
                          linear_m_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.active or grs_id != self.grs or not np.any(self.misalignment_rad):
            return angular_rad_s2, linear_m_s2
        eps = self.misalignment_rad
        on = self._on(t_s)
        if on is None:
            return angular_rad_s2 - cross(eps, angular_rad_s2), linear_m_s2 - cross(eps, linear_m_s2)
        step = on[:, None].astype(np.float64)
        return angular_rad_s2 - step * cross(eps, angular_rad_s2), linear_m_s2 - step * cross(eps, linear_m_s2)

    def grs_voltages_v(self, t_s: np.ndarray, grs_id: int, voltages_v: np.ndarray) -> np.ndarray:
        if not self.active or grs_id != self.grs or not np.any(self.imbalance):
            return voltages_v
        gains = np.empty(6)
        gains[0::2] = 1.0 + self.imbalance
        gains[1::2] = 1.0 - self.imbalance
        on = self._on(t_s)
        if on is None:
            return voltages_v * gains
        return voltages_v * np.where(on[:, None], gains, 1.0)


class ReadoutNonlinearity(_CatalogEffect):
    """Quadratic term in one GRS readout: ``a_meas = a + k a^2`` (before the voltage conversion).

    Parameters
    ----------
    k : float
        Quadratic coefficient [1/(rad s^-2)] for an angular readout, [1/(m s^-2)] for a linear one.
    grs : int
        1 or 2.
    readout : str
        ``"phi"``, ``"theta"``, ``"psi"`` (angular) or ``"x"``, ``"y"``, ``"z"`` (linear), TMRF.
    enabled : bool
        Switch.
    """

    name = "readout_nonlinearity"
    _params = ("k", "grs", "readout")

    def __init__(self, k: float = 0.0, grs: int = 1, readout: str = "x", enabled: bool = True,
                 onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.k = _scalar(self.name, "k", k)
        self.grs = _grs(self.name, grs)
        self.readout = _choice(self.name, "readout", readout, ANGULAR_READOUTS + LINEAR_READOUTS)

    @property
    def active(self) -> bool:
        return self.enabled and self.k != 0.0

    def grs_accelerations(self, t_s: np.ndarray, grs_id: int, angular_rad_s2: np.ndarray,
                          linear_m_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.active or grs_id != self.grs:
            return angular_rad_s2, linear_m_s2
        if self.readout in ANGULAR_READOUTS:
            index = ANGULAR_READOUTS.index(self.readout)
            angular = np.array(angular_rad_s2, dtype=np.float64)
            angular[:, index] = angular[:, index] + self._stepped(t_s, self.k * angular[:, index] ** 2)
            return angular, linear_m_s2
        index = LINEAR_READOUTS.index(self.readout)
        linear = np.array(linear_m_s2, dtype=np.float64)
        linear[:, index] = linear[:, index] + self._stepped(t_s, self.k * linear[:, index] ** 2)
        return angular_rad_s2, linear


