"""Star-tracker effects: low-frequency (AR(1)) attitude noise.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter

from taiji2_model.config_schema import SimConfig
from taiji2_model.effect_catalog.base import EffectParameterError, _CatalogEffect, _scalar, _vector
from taiji2_model.frames import quat_from_rotvec, quat_multiply
from taiji2_model.noise import noise_rng


class StarTrackerLowFreqNoise(_CatalogEffect):
    """Star-tracker error rising at low frequency (random-walk-like, flattened below a corner).

    An extra small-angle error per CRF axis with one-sided PSD ``S_w f_knee^2 / (f^2 + f_c^2)``,
    S_w = 2 sigma^2 / fs the white level of the configured star tracker: above the corner it rises
    as 1/f^2 and equals the white noise at f_knee. Generated as an exact AR(1) (Ornstein-Uhlenbeck)
    sequence from its own random stream ``"effect.star_tracker_lowfreq_noise"``, started
    stationary; applied as ``q exp(e / 2)``.

    Parameters
    ----------
    knee_hz : float
        f_knee [Hz].
    corner_hz : float
        f_c [Hz].
    axes : array_like
        (3,) 0/1 mask of the CRF axes affected (default all).
    enabled : bool
        Switch.
    """

    name = "star_tracker_lowfreq_noise"
    _params = ("knee_hz", "corner_hz", "axes")

    def __init__(self, knee_hz: float = 0.0, corner_hz: float = 1e-5, axes: ArrayLike = (1.0, 1.0, 1.0),
                 enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.knee_hz = _scalar(self.name, "knee_hz", knee_hz)
        if self.knee_hz < 0.0:
            raise EffectParameterError(self.name, "knee_hz", f"must be >= 0, got {knee_hz!r}")
        self.corner_hz = _scalar(self.name, "corner_hz", corner_hz, positive=True)
        self.axes = _vector(self.name, "axes", axes)
        self._rng: np.random.Generator | None = None
        self._state = np.zeros(3)
        self._decay = 1.0
        self._innovation_std = np.zeros(3)

    @property
    def active(self) -> bool:
        return self.enabled and self.knee_hz > 0.0 and bool(np.any(self.axes))

    @staticmethod
    def ar1_parameters(sigma_rad: ArrayLike, knee_hz: float, corner_hz: float,
                       sample_rate_hz: float) -> tuple[float, np.ndarray, np.ndarray]:
        """(decay, innovation std (3,), stationary std (3,)) of the AR(1) sequence [rad].

        The OU process ``s^2 exp(-2 pi f_c |tau|)`` has the one-sided PSD
        ``s^2 (2 f_c / pi) / (f^2 + f_c^2)``; equal to ``S_w f_knee^2 / (f^2 + f_c^2)`` for
        ``s^2 = S_w f_knee^2 pi / (2 f_c)``.
        """
        sigma = np.asarray(sigma_rad, dtype=np.float64) * np.ones(3)
        white_psd = 2.0 * sigma ** 2 / sample_rate_hz
        stationary = np.sqrt(white_psd * knee_hz ** 2 * math.pi / (2.0 * corner_hz))
        rate = 2.0 * math.pi * corner_hz / sample_rate_hz
        return math.exp(-rate), stationary * math.sqrt(-math.expm1(-2.0 * rate)), stationary

    def bind(self, config: SimConfig, seed: int) -> None:
        self._rng = noise_rng(seed, "effect." + self.name)
        decay, innovation, stationary = self.ar1_parameters(
            config.noise.star_tracker.sigma_rad, self.knee_hz, self.corner_hz, config.sample_rate_hz)
        self._decay = decay
        self._innovation_std = innovation * self.axes
        self._state = stationary * self.axes * self._rng.standard_normal(3)
        if self.onset_s > 0.0:  # the extra error starts at the onset, from zero (no attitude jump)
            self._state = np.zeros(3)

    def star_tracker_quat_xyzw(self, t_s: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
        if not self.active:
            return quat_xyzw
        if self._rng is None:
            raise RuntimeError("star_tracker_lowfreq_noise: bind() was not called")
        count = quat_xyzw.shape[0]
        innovations = self._stepped(t_s, self._innovation_std * self._rng.standard_normal((count, 3)))
        following, _ = lfilter([1.0], [1.0, -self._decay], innovations, axis=0,
                               zi=(self._decay * self._state)[None, :])
        values = np.concatenate((self._state[None, :], following[:-1]), axis=0)
        self._state = following[-1].copy()
        return quat_multiply(quat_xyzw, quat_from_rotvec(values))


# ------------------------------------------------------------------------------------------------
# Registry
# ------------------------------------------------------------------------------------------------

