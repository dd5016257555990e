"""Catalog of unmodelled effects: named switches with physical magnitudes in SI units.

Each entry is an :class:`~.effects.Effect` subclass, usable both to make "real" data (pass it to
:class:`~.simulator.Simulator` or :func:`~.simulator.simulate_batch`) and, in the sim-to-real gap
diagnosis, as a candidate extension of the nominal model (the diagnosis derives the signature of
each entry from the same definitions; ``docs/diagnosis.md``).

Every effect has an ``enabled`` switch; disabled, or with all magnitudes zero, it returns its
inputs unchanged, so the data are bit-identical to a run without it. Frames and signs follow
``docs/physics_model.md``: CRF vectors, TMRF readouts ``C_i v``; angular readouts
``(phi, theta, psi)``, linear ``(x, y, z)``; the electrode pair ``x`` carries ``psi`` (difference)
and ``x`` (sum), ``y`` carries ``phi`` and ``y``, ``z`` carries ``theta`` and ``z``.

=============================  ==================================================================
name                           model (magnitude parameters, SI)
=============================  ==================================================================
scale_factor_drift             G(t) = G (1 + rate (t - t_ref)) of one electrode pair of one GRS,
                               angular and linear together (``rate_per_s`` [1/s])
cross_coupling                 TMRF misalignment ``a -> a - eps x a`` (``misalignment_rad``) and
                               electrode gain imbalance ``v1 (1 + eta), v2 (1 - eta)``, which
                               couples angular and linear (``imbalance`` [1])
time_offset                    star tracker stamped ``offset_s`` late: it reads q(t - offset) [s]
actuation_delay                the applied torque lags the command by ``delay_s`` [s] (any sign)
thruster_response              first-order lag of the applied torque, ``time_constant_s`` [s]
grs_time_offset                GRS stamped ``offset_s`` late against the model's convention [s]
star_tracker_lowfreq_noise     extra star-tracker error, PSD ``S_w f_knee^2 / (f^2 + f_c^2)``
                               (``knee_hz``: where it equals the white level S_w) [Hz]
thruster_torque_gain           applied torque = (1 + g_k) x (command + noise) per axis (``gain``)
com_drift                      d_i(t) = d_i + v (t - t_ref) for GRS 1, 2 or both (``rate_m_s``)
readout_nonlinearity           a_meas = a + k a^2 on one readout of one GRS (``k`` [1/(unit)])
inertia_error                  J_true = J + diag(eps J_kk) + products of inertia
                               (``relative``, ``products_kg_m2``)
gravity_gradient               3 n^2 r x J r for a circular orbit of period ``orbit_period_s``
                               (orbit normal, phase; ``scale`` multiplies the torque)
tm_stiffness                   TM-to-spacecraft stiffness k acting on the suspension's tracking
                               error x_rel = -H(s) a_req: the GRS reads a_req - k H(s) a_req
                               (``stiffness_s2`` [s^-2], suspension frequency, damping)
thruster_force_leakage         net force F = Lambda tau from the torque maneuver: a_SC += F / M
                               (``leakage_per_m`` (3, 3) [N / (N m)])
=============================  ==================================================================

Registry: :data:`EFFECTS` (name -> class), :func:`make_effect` and :func:`effects_from_config`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import bilinear, lfilter

from taiji2_model.config_schema import SimConfig, TimingConfig
from taiji2_model.effects import Effect
from taiji2_model.frames import cross, quat_from_rotvec, quat_multiply
from taiji2_model.noise import noise_rng

__all__ = [
    "ANGULAR_READOUTS",
    "EFFECTS",
    "ELECTRODE_PAIRS",
    "LINEAR_READOUTS",
    "ActuationDelay",
    "ComDrift",
    "CrossCoupling",
    "EffectParameterError",
    "GravityGradient",
    "GrsTimeOffset",
    "InertiaError",
    "ReadoutNonlinearity",
    "ScaleFactorDrift",
    "StarTrackerLowFreqNoise",
    "ThrusterForceLeakage",
    "ThrusterResponse",
    "ThrusterTorqueGain",
    "TimeOffset",
    "TmStiffness",
    "effects_from_config",
    "make_effect",
    "suspension_filter",
]

ELECTRODE_PAIRS: dict[str, tuple[int, int]] = {"x": (2, 0), "y": (0, 1), "z": (1, 2)}
"""Electrode pair -> (index of its angular readout in (phi, theta, psi), index of its linear readout)."""
ANGULAR_READOUTS = ("phi", "theta", "psi")
LINEAR_READOUTS = ("x", "y", "z")
_AXES = {"x": 0, "y": 1, "z": 2}


class EffectParameterError(ValueError):
    """Invalid effect parameter; the message starts with ``<effect>.<parameter>``."""

    def __init__(self, effect: str, parameter: str, problem: str) -> None:
        super().__init__(f"{effect}.{parameter}: {problem}")


def _vector(effect: str, name: str, value: ArrayLike, size: int = 3) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim == 0:
        array = np.full(size, float(array))
    if array.shape != (size,):
        raise EffectParameterError(effect, name, f"expected a number or {size} numbers, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise EffectParameterError(effect, name, "must be finite")
    return array


def _scalar(effect: str, name: str, value: float, positive: bool = False) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise EffectParameterError(effect, name, f"expected a number, got {value!r}") from None
    if not math.isfinite(number) or (positive and number <= 0.0):
        raise EffectParameterError(effect, name, f"must be finite{' and > 0' if positive else ''}, got {value!r}")
    return number


def _grs(effect: str, value: int, allow_both: bool = False) -> int:
    allowed = (0, 1, 2) if allow_both else (1, 2)
    if isinstance(value, bool) or value not in allowed:
        raise EffectParameterError(effect, "grs", f"must be one of {allowed} (0 = both), got {value!r}")
    return int(value)


def _choice(effect: str, name: str, value: str, options: Iterable[str]) -> str:
    options = tuple(options)
    if value not in options:
        raise EffectParameterError(effect, name, f"must be one of {options}, got {value!r}")
    return value


class _CatalogEffect(Effect):
    """Common parts: the ``enabled`` switch, the onset and provenance of the parameters.

    ``onset_s``: the effect starts at this time [s] (simulation clock), as a step (``ONSET_KIND =
    "step"``: absent before, whole from the onset on) or, for the drifts (``"ramp"``), as a drift
    that starts there. 0 (the default) or less: present from the start, bit-identical to the effect
    without an onset.
    """

    _params: ClassVar[tuple[str, ...]] = ()
    ONSET_KIND: ClassVar[str] = "step"

    def __init__(self, enabled: bool = True, onset_s: float = 0.0) -> None:
        self.enabled = bool(enabled)
        self.onset_s = _scalar(getattr(self, "name", "effect"), "onset_s", onset_s)

    def _on(self, t_s: np.ndarray) -> np.ndarray | None:
        """(n,) True from the onset on; None when the effect is present from the start."""
        if self.onset_s <= 0.0:
            return None
        return np.asarray(t_s, dtype=np.float64) >= self.onset_s

    def _stepped(self, t_s: np.ndarray, change: np.ndarray) -> np.ndarray:
        """``change`` (leading axis n) from the onset on, zero before."""
        on = self._on(t_s)
        if on is None:
            return change
        return change * on.reshape(on.shape + (1,) * (np.ndim(change) - 1))

    def _clock(self, t_s: np.ndarray) -> np.ndarray:
        """Time of a drift that starts at the onset: ``max(t, onset)`` (t itself without an onset)."""
        t = np.asarray(t_s, dtype=np.float64)
        return t if self.onset_s <= 0.0 else np.maximum(t, self.onset_s)

    @property
    def active(self) -> bool:
        """Whether the effect changes anything (enabled and a non-zero magnitude)."""
        return self.enabled

    def to_dict(self) -> dict[str, object]:
        """Name, type and every parameter (lists for arrays)."""
        out: dict[str, object] = {"name": self.name, "type": type(self).__name__, "enabled": self.enabled}
        for key in (*self._params, *(("onset_s",) if self.onset_s else ())):
            value = getattr(self, key)
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        return out


# ------------------------------------------------------------------------------------------------
# GRS effects
# ------------------------------------------------------------------------------------------------


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


class ThrusterTorqueGain(_CatalogEffect):
    """Applied torque differs from the command by a gain per CRF axis.

    ``tau_applied = (1 + g) (tau_cmd + tau_noise)`` componentwise (the gain acts on everything the
    thrusters deliver; for the noise this is a 1e-3 change of a noise level, immaterial).

    Parameters
    ----------
    gain : array_like
        (3,) g per CRF axis [1], or a number with ``axis``.
    axis : str, optional
        ``"x"``, ``"y"`` or ``"z"`` when ``gain`` is one number (default: all axes).
    enabled : bool
        Switch.
    """

    name = "thruster_torque_gain"
    _params = ("gain",)

    def __init__(self, gain: ArrayLike = 0.0, axis: str | None = None, enabled: bool = True,
                 onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        if axis is not None:
            _choice(self.name, "axis", axis, _AXES)
            vector = np.zeros(3)
            vector[_AXES[axis]] = _scalar(self.name, "gain", gain)  # type: ignore[arg-type]
            self.gain = vector
        else:
            self.gain = _vector(self.name, "gain", gain)

    @property
    def active(self) -> bool:
        return self.enabled and bool(np.any(self.gain))

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        if not self.active:
            return torque_n_m
        on = self._on(t_s)
        if on is None:
            return torque_n_m * (1.0 + self.gain)
        return torque_n_m * (1.0 + np.outer(on, self.gain))


class InertiaError(_CatalogEffect):
    """True inertia differs from the nominal one.

    ``J_true = J + diag(relative * diag(J)) + P`` with P the symmetric matrix of the products of
    inertia ``(J_xy, J_xz, J_yz)``.

    Parameters
    ----------
    relative : array_like
        (3,) relative error of the principal moments [1].
    products_kg_m2 : array_like
        (3,) additional products of inertia J_xy, J_xz, J_yz [kg m^2].
    enabled : bool
        Switch.
    """

    name = "inertia_error"
    _params = ("relative", "products_kg_m2")

    def __init__(self, relative: ArrayLike = 0.0, products_kg_m2: ArrayLike = 0.0, enabled: bool = True,
                 onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.relative = _vector(self.name, "relative", relative)
        self.products_kg_m2 = _vector(self.name, "products_kg_m2", products_kg_m2)
        self._true: np.ndarray | None = None

    @property
    def active(self) -> bool:
        return self.enabled and bool(np.any(self.relative) or np.any(self.products_kg_m2))

    def true_inertia(self, nominal_kg_m2: ArrayLike) -> np.ndarray:
        """J_true for a nominal (3, 3) J [kg m^2]."""
        nominal = np.asarray(nominal_kg_m2, dtype=np.float64)
        xy, xz, yz = self.products_kg_m2
        delta = np.diag(self.relative * np.diag(nominal)) + np.array([[0.0, xy, xz], [xy, 0.0, yz], [xz, yz, 0.0]])
        true = nominal + delta
        if np.any(np.linalg.eigvalsh(true) <= 0.0):
            raise EffectParameterError(self.name, "relative", "the true inertia is not positive definite")
        return true

    def bind(self, config: SimConfig, seed: int) -> None:
        self._true = self.true_inertia(config.spacecraft.inertia_kg_m2) if self.active else None

    def inertia_kg_m2(self, t_s: np.ndarray, inertia_kg_m2: np.ndarray) -> np.ndarray:
        if not self.active:
            return inertia_kg_m2
        on = self._on(t_s)
        if on is not None:
            if inertia_kg_m2.ndim == 2:
                return np.where(on[:, None, None], self.true_inertia(inertia_kg_m2), inertia_kg_m2[None])
            return np.stack([self.true_inertia(j) if o else np.array(j)
                             for j, o in zip(inertia_kg_m2, on, strict=True)])
        if inertia_kg_m2.ndim == 2:
            return self.true_inertia(inertia_kg_m2)
        return np.stack([self.true_inertia(j) for j in inertia_kg_m2])


class GravityGradient(_CatalogEffect):
    """Gravity-gradient torque of a circular orbit.

    ``tau = scale * 3 n^2 r x (J r)`` with n = 2 pi / orbit_period, r the unit vector towards the
    central body, rotating in the orbit plane: ``r(t) = cos(n t + phase) e1 + sin(n t + phase) e2``
    with (e1, e2, orbit_normal) right-handed, e1 the projection of the inertial X axis (Y if
    normal to X). r is taken in the inertial frame = CRF: the attitude stays within 2e-3 rad of
    the initial one during the maneuver (docs/physics_model.md), a relative error of that size. J
    is the configured (nominal) inertia. Over a 3 h run the torque is a constant plus a harmonic
    of 2n: ``tau_0 + tau_c cos(2 theta) + tau_s sin(2 theta)``, theta = n t + phase.

    Parameters
    ----------
    orbit_period_s : float
        Orbit period [s] (default: one sidereal day, a high Earth orbit).
    orbit_normal : array_like
        (3,) orbit normal in the inertial frame (normalised).
    phase_rad : float
        Orbit phase at t = 0 [rad].
    scale : float
        Multiplier of the torque (1 = the full point-mass gravity gradient; less, e.g., for a
        partly compensated one).
    enabled : bool
        Switch.
    """

    name = "gravity_gradient"
    _params = ("orbit_period_s", "orbit_normal", "phase_rad", "scale")

    def __init__(self, orbit_period_s: float = 86164.1, orbit_normal: ArrayLike = (0.3, 0.2, 0.93),
                 phase_rad: float = 0.0, scale: float = 1.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.orbit_period_s = _scalar(self.name, "orbit_period_s", orbit_period_s, positive=True)
        normal = _vector(self.name, "orbit_normal", orbit_normal)
        norm = float(np.linalg.norm(normal))
        if norm == 0.0:
            raise EffectParameterError(self.name, "orbit_normal", "must not be zero")
        self.orbit_normal = normal / norm
        self.phase_rad = _scalar(self.name, "phase_rad", phase_rad)
        self.scale = _scalar(self.name, "scale", scale)
        self._inertia: np.ndarray | None = None

    @property
    def active(self) -> bool:
        return self.enabled and self.scale != 0.0

    @property
    def orbit_rate_rad_s(self) -> float:
        """n [rad/s]."""
        return 2.0 * math.pi / self.orbit_period_s

    def plane_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(e1, e2): orthonormal axes of the orbit plane."""
        normal = self.orbit_normal
        seed = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = seed - normal * float(seed @ normal)
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(normal, e1)

    def bind(self, config: SimConfig, seed: int) -> None:
        self._inertia = np.array(config.spacecraft.inertia_kg_m2, dtype=np.float64)

    def torque_n_m(self, t_s: ArrayLike, inertia_kg_m2: ArrayLike | None = None) -> np.ndarray:
        """Torque at times t (n,) -> (n, 3) CRF [N m]."""
        inertia = self._inertia if inertia_kg_m2 is None else np.asarray(inertia_kg_m2, dtype=np.float64)
        if inertia is None:
            raise RuntimeError("gravity_gradient: bind() was not called and no inertia given")
        theta = self.orbit_rate_rad_s * np.asarray(t_s, dtype=np.float64) + self.phase_rad
        e1, e2 = self.plane_axes()
        r = np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2
        n2 = self.orbit_rate_rad_s ** 2
        return self.scale * 3.0 * n2 * cross(r, r @ inertia.T)

    def harmonic_coefficients_n_m(self, inertia_kg_m2: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tau_0, tau_c, tau_s), each (3,) [N m]: torque = tau_0 + tau_c cos 2theta + tau_s sin 2theta."""
        quarter = self.orbit_period_s / 4.0
        base = -self.phase_rad / self.orbit_rate_rad_s  # theta = 0
        samples = self.torque_n_m(base + np.array([0.0, quarter / 2.0, quarter]), inertia_kg_m2)
        # theta = 0, pi/4, pi/2 -> 2 theta = 0, pi/2, pi
        tau_0 = 0.5 * (samples[0] + samples[2])
        tau_c = 0.5 * (samples[0] - samples[2])
        tau_s = samples[1] - tau_0
        return tau_0, tau_c, tau_s

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        if not self.active:
            return torque_n_m
        return torque_n_m + self._stepped(t_s, self.torque_n_m(t_s))


class ComDrift(_CatalogEffect):
    """c.m. offsets changing linearly: ``d_i(t) = d_i + rate (t - t_ref)``.

    ``grs = 0`` moves both offsets together (the spacecraft c.m. moving with propellant use moves
    both d_i by the same amount, of opposite sign to its own motion); 1 or 2 one of them.

    Parameters
    ----------
    rate_m_s : array_like
        (3,) velocity in CRF [m/s].
    grs : int
        0 (both), 1 or 2.
    t_ref_s : float
        Time at which d equals its configured value [s].
    enabled : bool
        Switch.
    """

    name = "com_drift"
    _params = ("rate_m_s", "grs", "t_ref_s")
    ONSET_KIND = "ramp"

    def __init__(self, rate_m_s: ArrayLike = 0.0, grs: int = 0, t_ref_s: float = 0.0, enabled: bool = True,
                 onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.rate_m_s = _vector(self.name, "rate_m_s", rate_m_s)
        self.grs = _grs(self.name, grs, allow_both=True)
        self.t_ref_s = _scalar(self.name, "t_ref_s", t_ref_s)

    @property
    def active(self) -> bool:
        return self.enabled and bool(np.any(self.rate_m_s))

    def com_offset_m(self, t_s: np.ndarray, grs_id: int, com_offset_m: np.ndarray) -> np.ndarray:
        if not self.active or (self.grs and grs_id != self.grs):
            return com_offset_m
        elapsed = self._clock(t_s) - self.t_ref_s
        return com_offset_m + elapsed[:, None] * self.rate_m_s


class ThrusterForceLeakage(_CatalogEffect):
    """Net force produced by the torque maneuver (unbalanced thruster couples).

    ``a_SC += Lambda tau / M`` with tau the applied torque (command and noise) and Lambda a (3, 3)
    matrix [N per N m = 1/m]: Lambda[c, k] is the force along CRF axis c per torque about axis k.

    Parameters
    ----------
    leakage_per_m : array_like
        (3, 3) Lambda [1/m].
    enabled : bool
        Switch.
    """

    name = "thruster_force_leakage"
    _params = ("leakage_per_m",)

    def __init__(self, leakage_per_m: ArrayLike = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        matrix = np.asarray(leakage_per_m, dtype=np.float64)
        if matrix.ndim == 0:
            matrix = np.full((3, 3), float(matrix))
        if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
            raise EffectParameterError(self.name, "leakage_per_m", f"expected finite (3, 3), got shape {matrix.shape}")
        self.leakage_per_m = matrix
        self._mass_kg = 1.0
        self._torque: np.ndarray | None = None

    @property
    def active(self) -> bool:
        return self.enabled and bool(np.any(self.leakage_per_m))

    def bind(self, config: SimConfig, seed: int) -> None:
        self._mass_kg = float(config.spacecraft.mass_kg)

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        self._torque = torque_n_m if self.active else None
        return torque_n_m

    def spacecraft_acceleration_m_s2(self, t_s: np.ndarray, a_sc_m_s2: np.ndarray) -> np.ndarray:
        if not self.active or self._torque is None:
            return a_sc_m_s2
        return a_sc_m_s2 + self._stepped(t_s, self._torque @ self.leakage_per_m.T / self._mass_kg)


# ------------------------------------------------------------------------------------------------
# Star-tracker effects
# ------------------------------------------------------------------------------------------------


class TimeOffset(_CatalogEffect):
    """Star-tracker time stamps offset from the GRS (and command) clock.

    The star tracker stamped t read the attitude at ``t - offset_s`` (offset > 0: it is late).
    The effect follows the true body rate itself from the applied torque it sees (rigid body,
    without the 1e-9-relative gyroscopic term) and rotates each readout by the body-frame angle
    ``-int_{t - offset}^{t} omega dt`` (exact for the piecewise-linear rate of the simulator; for
    a negative offset the rate is extrapolated over |offset| with the last angular acceleration).
    Put it after every effect that changes the torque or the inertia
    (:func:`effects_from_config` does).

    Parameters
    ----------
    offset_s : float
        Offset [s].
    enabled : bool
        Switch.
    """

    name = "time_offset"
    _params = ("offset_s",)

    def __init__(self, offset_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.offset_s = _scalar(self.name, "offset_s", offset_s)
        self._dt_s = 0.1
        self._inertia_inv: np.ndarray | None = None
        self._omega = np.zeros(3)
        self._history_omega = np.zeros((0, 3))
        self._history_acc = np.zeros((0, 3))
        self._pending_acc: np.ndarray | None = None
        self._torque_block = np.zeros((0, 3))

    @property
    def active(self) -> bool:
        return self.enabled and self.offset_s != 0.0

    def bind(self, config: SimConfig, seed: int) -> None:
        self._dt_s = config.dt_s
        self._inertia_inv = np.linalg.inv(config.spacecraft.inertia_kg_m2)
        self._omega = np.array(config.spacecraft.initial_rate_rad_s, dtype=np.float64)
        steps = math.ceil(abs(self.offset_s) / self._dt_s) + 1
        self._history_omega = np.tile(self._omega, (steps, 1))
        self._history_acc = np.zeros((steps, 3))

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        if self.active:
            self._torque_block = torque_n_m
        return torque_n_m

    def inertia_kg_m2(self, t_s: np.ndarray, inertia_kg_m2: np.ndarray) -> np.ndarray:
        if self.active:
            inverse = np.linalg.inv(inertia_kg_m2)
            self._pending_acc = (np.einsum("nij,nj->ni", inverse, self._torque_block) if inverse.ndim == 3
                                 else self._torque_block @ inverse.T)
        return inertia_kg_m2

    def star_tracker_quat_xyzw(self, t_s: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
        if not self.active:
            return quat_xyzw
        if self._pending_acc is None:
            raise RuntimeError("time_offset: no torque seen for this block")
        acc = self._pending_acc
        self._pending_acc = None
        omega = self._omega + self._dt_s * np.cumsum(acc, axis=0)
        self._omega = omega[-1].copy()
        keep = self._history_omega.shape[0]
        all_omega = np.concatenate((self._history_omega, omega))  # rate at the sample times
        all_acc = np.concatenate((self._history_acc, acc))  # acceleration over the step ending there
        self._history_omega = all_omega[-keep:]
        self._history_acc = all_acc[-keep:]
        dt = self._dt_s
        count = omega.shape[0]
        index = keep + np.arange(count)  # position of each new sample in the combined arrays
        if self.offset_s > 0.0:
            whole, fraction = divmod(self.offset_s / dt, 1.0)
            whole = int(whole)
            angle = np.zeros((count, 3))
            for back in range(whole):  # full steps (t_{j-b-1}, t_{j-b}]
                angle += 0.5 * dt * (all_omega[index - back - 1] + all_omega[index - back])
            tail = fraction * dt  # last part of the step ending at t_{j-whole}
            angle += tail * all_omega[index - whole] - 0.5 * tail * tail * all_acc[index - whole]
            rotation = -angle
        else:
            lead = -self.offset_s
            rotation = lead * omega + 0.5 * lead * lead * acc
        return quat_multiply(quat_xyzw, quat_from_rotvec(self._stepped(t_s, rotation)))


class _ActuationFromOnset(_CatalogEffect):
    """A timing effect with an onset: the applied torque changes from the onset on.

    Present from the start, a latency or lag is a timing convention the simulator applies itself
    (:meth:`timing`). From an onset on, it acts through :meth:`applied_torque_n_m`: the torque the
    hook receives (command through the configured timing, plus thruster noise) is passed through the
    extra delay and lag (:func:`~.timing.actuated_commands`, on the hook's own time step), and
    replaces the torque from the onset on (a thruster whose latency or response changes mid-run).
    Exact in batch; in streaming blocks a history of the taps is kept (a negative delay needs
    later torques, i.e. batch simulation).
    """

    def _extra(self) -> tuple[float, float]:
        raise NotImplementedError

    def bind(self, config: SimConfig, seed: int) -> None:
        self._dt_s = config.dt_s
        self._history = np.zeros((0, 3))
        self._calls = 0

    def _from_onset(self) -> bool:
        return self.active and self.onset_s > 0.0

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        if not self._from_onset() or torque_n_m.shape[0] == 0:
            return torque_n_m
        from taiji2_model.timing import actuated_commands, actuation_weights

        t = np.asarray(t_s, dtype=np.float64)
        dt = float(t[1] - t[0]) if t.shape[0] > 1 else getattr(self, "_dt_s", 0.1)
        delay_s, lag_s = self._extra()
        self._calls = getattr(self, "_calls", 0) + 1
        if delay_s < 0.0 and self._calls > 1:
            raise RuntimeError(f"{self.name}: a negative delay from an onset needs the whole torque series "
                               "(batch simulation)")
        history = getattr(self, "_history", np.zeros((0, 3)))
        series = np.concatenate((history, torque_n_m))
        moved = actuated_commands(series, delay_s, lag_s, dt, before=series[0])[history.shape[0]:]
        m_first, weights = actuation_weights(delay_s, lag_s, dt)
        keep = max(m_first + weights.size, 1)
        self._history = series[-keep:]
        return np.where((t >= self.onset_s)[:, None], moved, torque_n_m)


class ActuationDelay(_ActuationFromOnset):
    """The applied torque lags the command by ``delay_s`` (thruster latency, command transport).

    A timing effect: it adds to ``timing.actuation_latency_s`` and the simulator applies the
    exact fractional delay (:mod:`.timing`); a negative delay (torque before its command stamp:
    a command stamped late) needs the whole command series, i.e. batch simulation.
    """

    name = "actuation_delay"
    _params = ("delay_s",)

    def __init__(self, delay_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.delay_s = _scalar(self.name, "delay_s", delay_s)

    @property
    def active(self) -> bool:
        return self.enabled and self.delay_s != 0.0

    def _extra(self) -> tuple[float, float]:
        return self.delay_s, 0.0

    def timing(self, timing: TimingConfig) -> TimingConfig:
        if not self.active or self.onset_s > 0.0:
            return timing
        return replace(timing, actuation_latency_s=timing.actuation_latency_s + self.delay_s)


class ThrusterResponse(_ActuationFromOnset):
    """First-order response of the thrust, time constant ``time_constant_s`` (rise time 2.2 T).

    A timing effect: it adds to ``timing.thruster_time_constant_s``.
    """

    name = "thruster_response"
    _params = ("time_constant_s",)

    def __init__(self, time_constant_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.time_constant_s = _scalar(self.name, "time_constant_s", time_constant_s)
        if self.time_constant_s < 0.0:
            raise EffectParameterError(self.name, "time_constant_s", f"must be >= 0, got {time_constant_s!r}")

    @property
    def active(self) -> bool:
        return self.enabled and self.time_constant_s != 0.0

    def _extra(self) -> tuple[float, float]:
        return 0.0, self.time_constant_s

    def timing(self, timing: TimingConfig) -> TimingConfig:
        if not self.active or self.onset_s > 0.0:
            return timing
        return replace(timing, thruster_time_constant_s=timing.thruster_time_constant_s + self.time_constant_s)


class GrsTimeOffset(_CatalogEffect):
    """GRS samples stamped ``offset_s`` late against the model's convention (both GRS).

    A timing effect: it adds to ``timing.grs_stamp`` (the sample stamped t covers the interval
    ending at t - grs_stamp).
    """

    name = "grs_time_offset"
    _params = ("offset_s",)

    def __init__(self, offset_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.offset_s = _scalar(self.name, "offset_s", offset_s)
        if self.onset_s > 0.0:
            raise EffectParameterError(self.name, "onset_s", "a GRS stamp convention that changes during the run is "
                                       "not simulated; give its reduction, actuation_delay and time_offset "
                                       "(-offset_s) with the same onset (docs/interfaces.md)")

    @property
    def active(self) -> bool:
        return self.enabled and self.offset_s != 0.0

    def timing(self, timing: TimingConfig) -> TimingConfig:
        return replace(timing, grs_stamp=timing.grs_stamp + self.offset_s) if self.active else timing


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

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (ScaleFactorDrift, CrossCoupling, TimeOffset, StarTrackerLowFreqNoise, ThrusterTorqueGain,
                ComDrift, ReadoutNonlinearity, InertiaError, GravityGradient, TmStiffness, ThrusterForceLeakage,
                ActuationDelay, ThrusterResponse, GrsTimeOffset)
}
"""Effect name -> class (the names of the issue's catalog, plus ``thruster_force_leakage``)."""

# effects that read the torque/inertia other effects produce go last
_LAST = ("time_offset",)


def make_effect(name: str, **params: Any) -> Effect:
    """Build a catalog effect by name.

    Parameters
    ----------
    name : str
        A key of :data:`EFFECTS`.
    **params
        Constructor parameters of that effect (SI units).

    Returns
    -------
    Effect

    Raises
    ------
    ValueError
        Unknown name (the message lists the known ones) or bad parameter
        (:class:`EffectParameterError`).
    """
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    try:
        return EFFECTS[name](**params)
    except TypeError as exc:
        raise ValueError(f"{name}: {exc}") from None


def effects_from_config(entries: Sequence[Mapping[str, Any]] | None) -> list[Effect]:
    """Effects from a list of ``{"name": ..., <params>}`` mappings (e.g. a YAML list).

    The order is kept, except that effects which follow the torque (``time_offset``) go last.

    Parameters
    ----------
    entries : sequence of mapping
        Each with the key ``name`` and the effect's parameters.

    Returns
    -------
    list of Effect
    """
    effects: list[Effect] = []
    for position, entry in enumerate(entries or ()):
        if not isinstance(entry, Mapping) or "name" not in entry:
            raise ValueError(f"effects[{position}]: expected a mapping with a 'name' key, got {entry!r}")
        params = {key: value for key, value in entry.items() if key != "name"}
        effects.append(make_effect(str(entry["name"]), **params))
    return sorted(effects, key=lambda effect: effect.name in _LAST)
