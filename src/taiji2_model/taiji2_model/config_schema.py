"""Configuration schema: the frozen dataclass tree of the simulator and its error type.

Loading, overrides and validation are in :mod:`.config`, which re-exports everything here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

__all__ = [
    "NOISE_SOURCE_NAMES",
    "ConfigError",
    "GrsAssemblyConfig",
    "GrsConfig",
    "GrsVoltageNoiseConfig",
    "ManeuverConfig",
    "NoiseConfig",
    "SimConfig",
    "SpacecraftConfig",
    "SrpNoiseConfig",
    "StarTrackerNoiseConfig",
    "ThrusterConfig",
    "TimingConfig",
    "VectorNoiseConfig",
]

NOISE_SOURCE_NAMES: tuple[str, ...] = (
    "thruster_torque",
    "thruster_force",
    "srp",
    "lfs_translational",
    "lfs_rotational",
    "tm_environment",
    "grs_voltage",
    "star_tracker",
)
"""Stable names of the noise sources; each also names its own random stream."""

# YAML key of the ASD of each vector white-noise source, by unit
_VECTOR_NOISE_KEYS = {
    "N m Hz^-1/2": "asd_n_m_rthz",
    "N Hz^-1/2": "asd_n_rthz",
    "m s^-2 Hz^-1/2": "asd_m_s2_rthz",
    "rad s^-2 Hz^-1/2": "asd_rad_s2_rthz",
}
_VECTOR_NOISE_UNITS = {
    "thruster_torque": "N m Hz^-1/2",
    "thruster_force": "N Hz^-1/2",
    "lfs_translational": "m s^-2 Hz^-1/2",
    "lfs_rotational": "rad s^-2 Hz^-1/2",
    "tm_environment": "m s^-2 Hz^-1/2",
}


class ConfigError(ValueError):
    """Invalid or missing configuration value.

    Parameters
    ----------
    parameter : str
        Dotted path of the offending parameter, e.g. ``"spacecraft.mass_kg"``.
    problem : str
        What is wrong with it.
    """

    def __init__(self, parameter: str, problem: str) -> None:
        super().__init__(f"{parameter}: {problem}")
        self.parameter = parameter
        self.problem = problem


# --------------------------------------------------------------------------------------------
# Dataclass tree
# --------------------------------------------------------------------------------------------


def _freeze(array: np.ndarray) -> np.ndarray:
    """Return a read-only float64 copy so that a frozen config is really immutable."""
    frozen = np.array(array, dtype=np.float64, copy=True)
    frozen.setflags(write=False)
    return frozen


@dataclass(frozen=True, eq=False)
class SpacecraftConfig:
    """Spacecraft rigid body.

    Attributes
    ----------
    mass_kg : float
        Spacecraft mass M [kg].
    inertia_kg_m2 : numpy.ndarray
        (3, 3) inertia tensor J about the spacecraft c.m., in CRF [kg m^2].
    initial_attitude_xyzw : numpy.ndarray
        (4,) orientation of the CRF in the inertial frame at t0, Hamilton, x y z w (unit norm).
    initial_rate_rad_s : numpy.ndarray
        (3,) body rate omega in CRF at t0 [rad/s].
    """

    mass_kg: float
    inertia_kg_m2: np.ndarray
    initial_attitude_xyzw: np.ndarray
    initial_rate_rad_s: np.ndarray


@dataclass(frozen=True, eq=False)
class GrsConfig:
    """One gravitational reference sensor.

    Attributes
    ----------
    grs_id : int
        1 or 2; selects C_1 or C_2 = C_1^T.
    com_offset_m : numpy.ndarray
        (3,) position d_i of the test-mass c.m. relative to the spacecraft c.m., in CRF [m].
    angular_scale_factors : numpy.ndarray
        (3,) true (G_Pphi, G_Ptheta, G_Ppsi) [rad s^-2 V^-1].
    linear_scale_factors : numpy.ndarray
        (3,) true (G_Px, G_Py, G_Pz) [m s^-2 V^-1]; derived as r (G_Ppsi, G_Pphi, G_Ptheta)
        unless given explicitly.
    """

    grs_id: int
    com_offset_m: np.ndarray
    angular_scale_factors: np.ndarray
    linear_scale_factors: np.ndarray


@dataclass(frozen=True, eq=False)
class GrsAssemblyConfig:
    """The two GRS and their shared geometry.

    Attributes
    ----------
    alpha_deg : float
        Angle between the two telescope lines of sight [deg]; sets C_1 and C_2.
    range_m_s2 : float
        Linear-acceleration range of the GRS in the experiment, +-range [m s^-2].
    tm_mass_kg : float
        Test-mass mass [kg].
    tm_side_m : float
        Test-mass cube side a [m].
    electrode_lever_arm_m : float
        Lever arm l of the electrostatic torque [m]; r = a^2 / (6 l).
    sensors : tuple of GrsConfig
        GRS1 and GRS2, in this order.
    readout_saturation : bool
        Switch: the linear readout ``G_P,lin (v1 + v2)`` of every axis saturates (is clipped) at
        +-``range_m_s2`` (default true; false: unclipped, for studies).
    """

    alpha_deg: float
    range_m_s2: float
    tm_mass_kg: float
    tm_side_m: float
    electrode_lever_arm_m: float
    sensors: tuple[GrsConfig, GrsConfig]
    readout_saturation: bool = True

    @property
    def alpha_rad(self) -> float:
        """Telescope angle alpha [rad]."""
        return math.radians(self.alpha_deg)

    @property
    def linear_to_angular_ratio_m(self) -> float:
        """r = J_TM / (m_TM l) = a^2 / (6 l) [m]: linear scale factor per angular one."""
        return self.tm_side_m**2 / (6.0 * self.electrode_lever_arm_m)


@dataclass(frozen=True, eq=False)
class ManeuverConfig:
    """Square-wave torque maneuver about the CRF axes.

    Attributes
    ----------
    period_s : float
        Square-wave period P [s].
    amplitude_n_m : numpy.ndarray
        (3,) torque amplitude per CRF axis [N m].
    phase_s : numpy.ndarray
        (3,) time shift of each axis' square wave [s].
    start_s : float
        Maneuver start time [s].
    duration_s : float
        Maneuver duration [s]; zero torque outside [start, start + duration).
    """

    period_s: float
    amplitude_n_m: np.ndarray
    phase_s: np.ndarray
    start_s: float
    duration_s: float


@dataclass(frozen=True, eq=False)
class ThrusterConfig:
    """Micro-thruster geometry and capability.

    Attributes
    ----------
    lever_arm_m : float
        Lever arm L of the thruster producing each axis' torque [m].
    min_thrust_n, max_thrust_n : float
        Usable thrust range of one micro-thruster [N].
    """

    lever_arm_m: float
    min_thrust_n: float
    max_thrust_n: float


@dataclass(frozen=True, eq=False)
class VectorNoiseConfig:
    """White noise with a one-sided amplitude spectral density per axis.

    Attributes
    ----------
    enabled : bool
        Switch.
    asd : numpy.ndarray
        (3,) one-sided ASD per axis, in the unit of the source per sqrt(Hz) (see ``unit``).
    unit : str
        Unit of ``asd`` (documentation and provenance only).
    """

    enabled: bool
    asd: np.ndarray
    unit: str


@dataclass(frozen=True, eq=False)
class SrpNoiseConfig:
    """Solar-radiation-pressure fluctuation on the spacecraft.

    One-sided ASD per CRF axis ``A f_ref / sqrt(f^2 + f_c^2)`` [m s^-2 Hz^-1/2]: the paper's
    ``A (f_ref / f)`` above ``f_c``, flattened below.

    Attributes
    ----------
    enabled : bool
        Switch.
    asd_at_f_ref_m_s2_rthz : float
        A [m s^-2 Hz^-1/2].
    f_ref_hz : float
        f_ref [Hz].
    f_corner_hz : float
        f_c [Hz].
    """

    enabled: bool
    asd_at_f_ref_m_s2_rthz: float
    f_ref_hz: float
    f_corner_hz: float


@dataclass(frozen=True, eq=False)
class GrsVoltageNoiseConfig:
    """Electrode voltage readout noise.

    Attributes
    ----------
    enabled : bool
        Switch.
    linear_equivalent_asd_m_s2_rthz : float
        Linear-acceleration-equivalent ASD of a sum pair (v1 + v2) [m s^-2 Hz^-1/2]; each channel
        gets ``S / (sqrt(2) G_P,lin)`` [V Hz^-1/2].
    """

    enabled: bool
    linear_equivalent_asd_m_s2_rthz: float


@dataclass(frozen=True, eq=False)
class StarTrackerNoiseConfig:
    """Star-tracker attitude noise.

    Attributes
    ----------
    enabled : bool
        Switch (the reported covariance is always ``diag(sigma_rad^2)``).
    sigma_rad : numpy.ndarray
        (3,) 1-sigma white small-angle error about CRF X, Y, Z per sample [rad].
    """

    enabled: bool
    sigma_rad: np.ndarray


@dataclass(frozen=True, eq=False)
class NoiseConfig:
    """All noise sources; the attribute names are :data:`NOISE_SOURCE_NAMES`."""

    thruster_torque: VectorNoiseConfig
    thruster_force: VectorNoiseConfig
    srp: SrpNoiseConfig
    lfs_translational: VectorNoiseConfig
    lfs_rotational: VectorNoiseConfig
    tm_environment: VectorNoiseConfig
    grs_voltage: GrsVoltageNoiseConfig
    star_tracker: StarTrackerNoiseConfig


@dataclass(frozen=True)
class TimingConfig:
    """Timing conventions of the raw data and the actuation (section ``timing``; :mod:`.timing`).

    Defaults are the simulator's own conventions (and the contract's): a GRS sample stamped t is
    the mean over (t - dt, t], the star tracker reads the attitude at its stamp, the command stamped
    t_k acts over (t_k, t_k + dt] at once.

    Attributes
    ----------
    grs_stamp : float
        delta_g: GRS stamp minus the end of its integration interval [s] (``end`` 0, ``midpoint``
        -dt/2, ``start`` -dt; the YAML also takes these names).
    star_tracker_stamp_offset_s : float
        epsilon: the star tracker stamped t read the attitude at t - epsilon [s].
    actuation_latency_s : float
        L: the command stamped t_k acts from t_k + L on [s].
    thruster_time_constant_s : float
        T: first-order response of the thrust [s] (>= 0).
    """

    grs_stamp: float = 0.0
    star_tracker_stamp_offset_s: float = 0.0
    actuation_latency_s: float = 0.0
    thruster_time_constant_s: float = 0.0

    @property
    def reduced(self) -> tuple[float, float, float]:
        """(command-to-GRS delay D, star-tracker offset against the GRS e, lag T) [s] (:mod:`.timing`)."""
        return (self.actuation_latency_s + self.grs_stamp, self.star_tracker_stamp_offset_s - self.grs_stamp,
                self.thruster_time_constant_s)

    @property
    def is_default(self) -> bool:
        """True for the simulator's own conventions (all zero)."""
        return not any((self.grs_stamp, self.star_tracker_stamp_offset_s, self.actuation_latency_s,
                        self.thruster_time_constant_s))


@dataclass(frozen=True, eq=False)
class SimConfig:
    """Complete simulator configuration (immutable).

    Attributes
    ----------
    layout : str
        Layout name (``"type1"``, ``"type2"`` or a user name).
    sample_rate_hz : float
        Simulation and readout rate fs [Hz].
    spacecraft, grs, maneuver, thrusters, noise, timing
        See the respective classes (``timing`` optional in a YAML: defaults to the simulator's
        conventions).
    effects : tuple of dict
        Known catalog effects of an *extended* nominal model (section ``effects``, optional: a list
        of ``{"name": ..., <parameters>, "onset_s": ...}`` as :func:`~.effect_catalog.make_effect`
        takes them), e.g. as ``taiji2 diagnose --write-config`` writes them. The diagnosis and
        ``taiji2 calibrate`` model them; the simulator does not inject them (give ``--effect``).
    """

    layout: str
    sample_rate_hz: float
    spacecraft: SpacecraftConfig
    grs: GrsAssemblyConfig
    maneuver: ManeuverConfig
    thrusters: ThrusterConfig
    noise: NoiseConfig
    timing: TimingConfig = field(default_factory=TimingConfig)
    effects: tuple[dict[str, Any], ...] = ()

    def __eq__(self, other: object) -> bool:
        """Value equality (the arrays inside make the generated ``__eq__`` unusable)."""
        if not isinstance(other, SimConfig):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays inside: not hashable

    @property
    def dt_s(self) -> float:
        """Sample interval 1 / fs [s]."""
        return 1.0 / self.sample_rate_hz

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (lists, floats, ints, bools, str), YAML/JSON-serialisable.

        ``load_config(cfg.to_dict())`` rebuilds an equal configuration; derived linear scale
        factors are written out explicitly.
        """
        return _to_plain(self)


def _to_plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, VectorNoiseConfig):
        # the YAML key carries the unit, e.g. asd_m_s2_rthz
        return {"enabled": bool(value.enabled), _VECTOR_NOISE_KEYS[value.unit]: value.asd.tolist()}
    if hasattr(value, "__dataclass_fields__"):
        return {f.name: _to_plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, tuple | list):
        return [_to_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _to_plain(v) for k, v in value.items()}
    if isinstance(value, bool | int | str):
        return value
    if isinstance(value, float | np.floating):
        return float(value)
    raise TypeError(f"cannot serialise {type(value).__name__}")
