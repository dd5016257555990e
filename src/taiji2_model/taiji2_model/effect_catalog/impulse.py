"""An impulsive event: an angular momentum and a linear impulse delivered to the spacecraft at one instant.

What LISA Pathfinder saw from micrometeoroid impacts (54 in 4,348 h, the smallest ~0.2 uN s; Thorpe et
al. 2019): a momentum transfer far shorter than a sample. Part of the effect catalog
(:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.config_schema import SimConfig
from taiji2_model.effect_catalog.base import _CatalogEffect, _scalar, _vector


class Impulse(_CatalogEffect):
    """A delta impulse at ``time_s``: the rate jumps by ``J^-1 L``, the velocity by ``p / M``.

    Delivered as a torque ``L / h`` and a force ``p / h`` held over the one integration step of
    length h that contains ``time_s`` (step start <= time_s < step end); h is the spacing of the step
    start times the hook receives (the simulator's sample step, the reference simulator's internal
    step), or the configured step for a block of one step. The integrating GRS then read the whole
    impulse in the one sample whose step contains it, whatever the discretisation.

    Parameters
    ----------
    time_s : float
        Instant of the impulse [s] (simulation clock).
    angular_momentum_n_m_s : array_like
        (3,) angular momentum transferred, CRF [N m s].
    linear_impulse_n_s : array_like
        (3,) linear momentum transferred, CRF [N s] (default 0).
    enabled : bool
        Switch.
    """

    name = "impulse"
    _params = ("time_s", "angular_momentum_n_m_s", "linear_impulse_n_s")

    def __init__(self, time_s: float = 0.0, angular_momentum_n_m_s: ArrayLike = 0.0,
                 linear_impulse_n_s: ArrayLike = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.time_s = _scalar(self.name, "time_s", time_s)
        self.angular_momentum_n_m_s = _vector(self.name, "angular_momentum_n_m_s", angular_momentum_n_m_s)
        self.linear_impulse_n_s = _vector(self.name, "linear_impulse_n_s", linear_impulse_n_s)
        self._dt_s = 0.1
        self._mass_kg = 1.0

    @property
    def active(self) -> bool:
        return self.enabled and self.time_s >= self.onset_s and bool(
            np.any(self.angular_momentum_n_m_s) or np.any(self.linear_impulse_n_s))

    def bind(self, config: SimConfig, seed: int) -> None:
        self._dt_s = float(config.dt_s)
        self._mass_kg = float(config.spacecraft.mass_kg)

    def _step(self, t_s: np.ndarray) -> tuple[int, float] | None:
        """Index of the step of ``t_s`` (step start times) that contains the impulse, and its length [s]."""
        t = np.asarray(t_s, dtype=np.float64)
        if t.size == 0:
            return None
        h = float(t[1] - t[0]) if t.size > 1 else self._dt_s
        index = int(np.searchsorted(t, self.time_s, side="right")) - 1
        if index < 0 or self.time_s >= t[index] + h:
            return None
        return index, h

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        step = self._step(t_s) if self.active and np.any(self.angular_momentum_n_m_s) else None
        if step is None:
            return torque_n_m
        out = np.array(torque_n_m, dtype=np.float64, copy=True)
        out[step[0]] += self.angular_momentum_n_m_s / step[1]
        return out

    def spacecraft_acceleration_m_s2(self, t_s: np.ndarray, a_sc_m_s2: np.ndarray) -> np.ndarray:
        step = self._step(t_s) if self.active and np.any(self.linear_impulse_n_s) else None
        if step is None:
            return a_sc_m_s2
        out = np.array(a_sc_m_s2, dtype=np.float64, copy=True)
        out[step[0]] += self.linear_impulse_n_s / (self._mass_kg * step[1])
        return out
