"""Noise budget of the calibration experiment, as the estimators model it.

Built from a plain configuration mapping in the layout-file format of ``taiji2_sim_pkg``
(``config/type1.yaml``: the ``noise`` section, ``spacecraft.mass_kg``, ``sample_rate_hz``); the
simulator package is not needed. Every source follows physics.md:

- star tracker: white small-angle error about CRF X, Y, Z, ``sigma_rad`` per sample;
- LFS rotational: white, TMRF (phi, theta, psi), on the GRS angular readout;
- LFS translational, TM environment, GRS voltage: white, TMRF (x, y, z), on the linear readout;
  the voltage noise also reaches the angular readout, as ``S_V / r`` [rad s^-2 Hz^-1/2];
- thruster force: white force on the spacecraft, ``a_SC += F / M``, common to both GRS;
- SRP: Ornstein-Uhlenbeck on ``a_SC``, one-sided ASD ``A f_ref / sqrt(f^2 + f_c^2)``, common;
- thruster torque: real motion, seen by star tracker and GRS alike, hence no noise of the fit.

White noise of one-sided ASD S sampled at fs has the per-sample standard deviation
``S sqrt(fs / 2)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["NoiseBudget", "SrpProcess"]

ARCSEC_RAD = math.pi / (180.0 * 3600.0)
"""One arc second [rad]."""

# A source switched off keeps this fraction of its nominal variance, so that no covariance the
# estimators invert becomes singular (numerical floor, not physics).
_DISABLED_VARIANCE_FRACTION = 1e-12


def _vector3(value: Any, name: str) -> np.ndarray:
    array = np.array(value, dtype=np.float64)
    if array.ndim == 0:
        array = np.full(3, float(array))
    if array.shape != (3,) or not np.all(np.isfinite(array)) or np.any(array < 0.0):
        raise ValueError(f"{name}: expected a non-negative number or a list of three, got {value!r}")
    return array


def _get(mapping: Mapping[str, Any], path: str, default: Any) -> Any:
    node: Any = mapping
    for part in path.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return default
        node = node[part]
    return node


@dataclass(frozen=True)
class SrpProcess:
    """Exact AR(1) sampling of the SRP Ornstein-Uhlenbeck process, per CRF axis.

    Attributes
    ----------
    decay : float
        ``phi = exp(-2 pi f_c dt)``.
    innovation_variance : float
        ``sigma^2 (1 - phi^2)`` [m^2 s^-4].
    stationary_variance : float
        ``sigma^2 = A^2 f_ref^2 pi / (2 f_c)`` [m^2 s^-4].
    """

    decay: float
    innovation_variance: float
    stationary_variance: float


@dataclass(frozen=True)
class NoiseBudget:
    """Nominal noise amplitudes (one-sided ASDs unless stated) and switches.

    Attributes
    ----------
    sample_rate_hz : float
        Readout rate fs [Hz].
    star_tracker_sigma_rad : numpy.ndarray
        (3,) 1-sigma white small-angle error per sample about CRF X, Y, Z [rad].
    lfs_rotational_asd : numpy.ndarray
        (3,) TMRF (phi, theta, psi) [rad s^-2 Hz^-1/2].
    lfs_translational_asd : numpy.ndarray
        (3,) TMRF (x, y, z) [m s^-2 Hz^-1/2].
    tm_environment_asd : numpy.ndarray
        (3,) TMRF (x, y, z) [m s^-2 Hz^-1/2].
    voltage_linear_asd : float
        Linear-acceleration equivalent of the voltage noise of a sum pair [m s^-2 Hz^-1/2].
    thruster_force_asd_n : numpy.ndarray
        (3,) CRF [N Hz^-1/2].
    spacecraft_mass_kg : float
        M [kg].
    srp_asd_at_f_ref : float
        A [m s^-2 Hz^-1/2].
    srp_f_ref_hz : float
        f_ref [Hz].
    srp_f_corner_hz : float
        f_c [Hz].
    linear_ratio_m : float
        r = a^2 / (6 l) [m], converts the voltage noise to the angular readout.
    enabled : dict of str to bool
        Source switches, keys as in the layout file (``star_tracker``, ``lfs_rotational``,
        ``lfs_translational``, ``tm_environment``, ``grs_voltage``, ``thruster_force``, ``srp``).
    """

    sample_rate_hz: float
    star_tracker_sigma_rad: np.ndarray
    lfs_rotational_asd: np.ndarray
    lfs_translational_asd: np.ndarray
    tm_environment_asd: np.ndarray
    voltage_linear_asd: float
    thruster_force_asd_n: np.ndarray
    spacecraft_mass_kg: float
    srp_asd_at_f_ref: float
    srp_f_ref_hz: float
    srp_f_corner_hz: float
    linear_ratio_m: float
    enabled: dict[str, bool]

    # ------------------------------------------------------------------------------------------
    @classmethod
    def from_layout(cls, layout: Mapping[str, Any]) -> NoiseBudget:
        """Build from a layout mapping (``taiji2_sim_pkg`` YAML format, or ``SimConfig.to_dict()``).

        Missing keys take the physics.md nominal values.

        Parameters
        ----------
        layout : mapping
            Nested configuration with ``sample_rate_hz``, ``spacecraft.mass_kg``,
            ``grs.tm_side_m``, ``grs.electrode_lever_arm_m`` and a ``noise`` section.

        Returns
        -------
        NoiseBudget
        """
        noise = _get(layout, "noise", {}) or {}

        def switch(name: str) -> bool:
            return bool(_get(noise, f"{name}.enabled", True))

        side = float(_get(layout, "grs.tm_side_m", 0.046))
        lever = float(_get(layout, "grs.electrode_lever_arm_m", 0.0115))
        names = ("star_tracker", "lfs_rotational", "lfs_translational", "tm_environment", "grs_voltage",
                 "thruster_force", "srp")
        return cls(
            sample_rate_hz=float(_get(layout, "sample_rate_hz", 10.0)),
            star_tracker_sigma_rad=_vector3(_get(noise, "star_tracker.sigma_rad", 0.2 * ARCSEC_RAD),
                                            "noise.star_tracker.sigma_rad"),
            lfs_rotational_asd=_vector3(_get(noise, "lfs_rotational.asd_rad_s2_rthz", [2e-11, 3.5e-11, 3.5e-11]),
                                        "noise.lfs_rotational.asd_rad_s2_rthz"),
            lfs_translational_asd=_vector3(
                _get(noise, "lfs_translational.asd_m_s2_rthz", [2.4e-12, 3.6e-12, 3.6e-12]),
                "noise.lfs_translational.asd_m_s2_rthz"),
            tm_environment_asd=_vector3(_get(noise, "tm_environment.asd_m_s2_rthz", 3e-14),
                                        "noise.tm_environment.asd_m_s2_rthz"),
            voltage_linear_asd=float(_get(noise, "grs_voltage.linear_equivalent_asd_m_s2_rthz", 2.2e-14)),
            thruster_force_asd_n=_vector3(_get(noise, "thruster_force.asd_n_rthz", 1e-7),
                                          "noise.thruster_force.asd_n_rthz"),
            spacecraft_mass_kg=float(_get(layout, "spacecraft.mass_kg", 1500.0)),
            srp_asd_at_f_ref=float(_get(noise, "srp.asd_at_f_ref_m_s2_rthz", 1.1e-11)),
            srp_f_ref_hz=float(_get(noise, "srp.f_ref_hz", 3e-3)),
            srp_f_corner_hz=float(_get(noise, "srp.f_corner_hz", 1e-5)),
            linear_ratio_m=side * side / (6.0 * lever),
            enabled={name: switch(name) for name in names},
        )

    # ------------------------------------------------------------------------------------------
    def _white_variance(self, asd: np.ndarray | float, source: str) -> np.ndarray:
        variance = np.asarray(asd, dtype=np.float64) ** 2 * (0.5 * self.sample_rate_hz)
        return variance if self.enabled[source] else _DISABLED_VARIANCE_FRACTION * variance

    @property
    def dt_s(self) -> float:
        """Sample interval [s]."""
        return 1.0 / self.sample_rate_hz

    def star_tracker_variance(self) -> np.ndarray:
        """(3,) per-sample variance of the star-tracker small-angle error, CRF [rad^2]."""
        variance = np.asarray(self.star_tracker_sigma_rad, dtype=np.float64) ** 2
        return variance if self.enabled["star_tracker"] else _DISABLED_VARIANCE_FRACTION * variance

    def angular_readout_variance(self) -> np.ndarray:
        """(3,) per-sample variance of a GRS angular readout, TMRF (phi, theta, psi) [rad^2 s^-4].

        LFS rotational noise plus the voltage noise of the difference pair, ``S_V / r``.
        """
        lfs = self._white_variance(self.lfs_rotational_asd, "lfs_rotational")
        volt = self._white_variance(np.full(3, self.voltage_linear_asd / self.linear_ratio_m), "grs_voltage")
        return lfs + volt

    def linear_readout_variance(self) -> np.ndarray:
        """(3,) per-sample variance of a GRS linear readout, TMRF (x, y, z) [m^2 s^-4]."""
        return (self._white_variance(self.lfs_translational_asd, "lfs_translational")
                + self._white_variance(self.tm_environment_asd, "tm_environment")
                + self._white_variance(np.full(3, self.voltage_linear_asd), "grs_voltage"))

    def thruster_acceleration_variance(self) -> np.ndarray:
        """(3,) per-sample variance of the white spacecraft acceleration ``F / M``, CRF [m^2 s^-4]."""
        return self._white_variance(self.thruster_force_asd_n / self.spacecraft_mass_kg, "thruster_force")

    def srp_process(self) -> SrpProcess:
        """AR(1) sampling of the SRP process at fs (exact for the OU process)."""
        rate = 2.0 * math.pi * self.srp_f_corner_hz
        stationary = self.srp_asd_at_f_ref**2 * self.srp_f_ref_hz**2 * math.pi / (2.0 * self.srp_f_corner_hz)
        if not self.enabled["srp"]:
            stationary *= _DISABLED_VARIANCE_FRACTION
        decay = math.exp(-rate * self.dt_s)
        return SrpProcess(decay, stationary * -math.expm1(-2.0 * rate * self.dt_s), stationary)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (provenance, checkpoints)."""
        return {
            "sample_rate_hz": self.sample_rate_hz,
            "star_tracker_sigma_rad": self.star_tracker_sigma_rad.tolist(),
            "lfs_rotational_asd": self.lfs_rotational_asd.tolist(),
            "lfs_translational_asd": self.lfs_translational_asd.tolist(),
            "tm_environment_asd": self.tm_environment_asd.tolist(),
            "voltage_linear_asd": self.voltage_linear_asd,
            "thruster_force_asd_n": self.thruster_force_asd_n.tolist(),
            "spacecraft_mass_kg": self.spacecraft_mass_kg,
            "srp_asd_at_f_ref": self.srp_asd_at_f_ref,
            "srp_f_ref_hz": self.srp_f_ref_hz,
            "srp_f_corner_hz": self.srp_f_corner_hz,
            "linear_ratio_m": self.linear_ratio_m,
            "enabled": dict(self.enabled),
        }
