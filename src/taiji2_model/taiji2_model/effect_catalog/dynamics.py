"""Spacecraft and test-mass dynamics effects: thruster torque gain, inertia error, gravity gradient, c.m.
drift, thruster force leakage.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.config_schema import SimConfig
from taiji2_model.effect_catalog.base import (
    _AXES,
    EffectParameterError,
    _CatalogEffect,
    _choice,
    _grs,
    _scalar,
    _vector,
)
from taiji2_model.frames import cross


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


