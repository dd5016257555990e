"""Test-mass effects: the suspension's stiffness (electrostatic spring) and its filter.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import bilinear, lfilter

from taiji2_model.config_schema import SimConfig
from taiji2_model.effect_catalog.base import _AXES, LINEAR_READOUTS, _CatalogEffect, _choice, _grs, _scalar


def suspension_filter(frequency_hz: float, damping: float, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete ``H(s) = 1 / (s^2 + 2 zeta w s + w^2)`` (bilinear transform), w = 2 pi f.

    H maps the acceleration a suspension must impose on a TM to minus its displacement from the
    cage centre (a second-order servo, DC gain ``1 / w^2`` [s^2]).

    Parameters
    ----------
    frequency_hz : float
        Suspension natural frequency f [Hz].
    damping : float
        Damping ratio zeta.
    sample_rate_hz : float
        fs [Hz].

    Returns
    -------
    b, a : numpy.ndarray
        ``scipy.signal.lfilter`` coefficients [s^2].
    """
    omega = 2.0 * math.pi * frequency_hz
    b, a = bilinear([1.0], [1.0, 2.0 * damping * omega, omega * omega], fs=sample_rate_hz)
    return np.asarray(b, dtype=np.float64), np.asarray(a, dtype=np.float64)


class TmStiffness(_CatalogEffect):
    """TM-to-spacecraft stiffness acting on the suspension's tracking error.

    In accelerometer mode a servo holds the TM near the cage centre; with natural frequency f_s
    and damping zeta it lags by ``x_rel = -H(s) a_req`` (:func:`suspension_filter`), a_req being
    the acceleration it must impose (TMRF, linear). A stiffness k (force per unit TM mass and
    displacement, s^-2; positive = restoring towards the cage centre, LISA-type negative
    stiffness allowed) adds ``-k x_rel`` on the TM, which the suspension no longer has to supply:
    the GRS reads ``a_req - k H(s) a_req``. At DC this is a gain ``1 - k / w_s^2`` of the linear
    readout only (breaking the angular/linear conversion), above f_s it falls off as f^-2.

    Parameters
    ----------
    stiffness_s2 : float
        k [s^-2].
    grs : int
        1 or 2.
    axis : str
        Linear TMRF axis ``"x"``, ``"y"`` or ``"z"``.
    suspension_hz : float
        f_s [Hz].
    damping : float
        zeta.
    enabled : bool
        Switch.
    """

    name = "tm_stiffness"
    _params = ("stiffness_s2", "grs", "axis", "suspension_hz", "damping")

    def __init__(self, stiffness_s2: float = 0.0, grs: int = 1, axis: str = "x", suspension_hz: float = 0.01,
                 damping: float = 0.7, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.stiffness_s2 = _scalar(self.name, "stiffness_s2", stiffness_s2)
        self.grs = _grs(self.name, grs)
        self.axis = _choice(self.name, "axis", axis, LINEAR_READOUTS)
        self.suspension_hz = _scalar(self.name, "suspension_hz", suspension_hz, positive=True)
        self.damping = _scalar(self.name, "damping", damping, positive=True)
        self._coefficients: tuple[np.ndarray, np.ndarray] | None = None
        self._state: np.ndarray | None = None

    @property
    def active(self) -> bool:
        return self.enabled and self.stiffness_s2 != 0.0

    def bind(self, config: SimConfig, seed: int) -> None:
        self._coefficients = suspension_filter(self.suspension_hz, self.damping, config.sample_rate_hz)
        self._state = np.zeros(len(self._coefficients[1]) - 1)

    def grs_accelerations(self, t_s: np.ndarray, grs_id: int, angular_rad_s2: np.ndarray,
                          linear_m_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.active or grs_id != self.grs:
            return angular_rad_s2, linear_m_s2
        if self._coefficients is None or self._state is None:
            raise RuntimeError("tm_stiffness: bind() was not called")
        index = _AXES[self.axis]
        b, a = self._coefficients
        lag, self._state = lfilter(b, a, linear_m_s2[:, index], zi=self._state)
        linear = np.array(linear_m_s2, dtype=np.float64)
        linear[:, index] = linear[:, index] - self._stepped(t_s, self.stiffness_s2 * lag)
        return angular_rad_s2, linear


# ------------------------------------------------------------------------------------------------
# Dynamics effects
# ------------------------------------------------------------------------------------------------


