"""Extension points for injected effects (drifts, couplings, time offsets, ...).

An effect is an :class:`Effect` subclass overriding some hooks; the simulator calls every hook of
every effect, in list order, at fixed points of each block of steps. The base class leaves every
quantity unchanged, so an effect overrides only what it changes.

Contract (what keeps streaming and batch identical):

- Hooks receive a block of n consecutive steps (n = 1 in streaming, the whole run in batch) with
  the time stamps ``t_s`` (n,) and arrays with a leading axis n. Blocks arrive in time order and do
  not overlap; a hook's result must not depend on how the run is cut into blocks (an effect with
  memory, e.g. a time offset, keeps its own history).
- Random effects draw from ``noise_rng(seed, "effect." + name)`` (:func:`.noise.noise_rng`),
  obtained in :meth:`Effect.bind`, never from the simulator's noise streams.
- Torque and inertia hooks get the step start times t_k (the value is held over (t_k, t_{k+1}]);
  sensor-side hooks get the sample times t_{k+1}.
- Hooks must not modify their input arrays in place; they return new arrays (or the input).
- Timing effects (a latency, a thruster lag, a GRS stamp offset) change the timing conventions
  through :meth:`Effect.timing`, which the simulator asks once, before the first step; the
  simulator implements the resulting timing itself (:mod:`.timing`).
"""

from __future__ import annotations

import numpy as np

from taiji2_model.config_schema import SimConfig, TimingConfig

__all__ = ["Effect"]


class Effect:
    """Base class of injected effects; every hook is the identity.

    Attributes
    ----------
    name : str
        Stable name (provenance, random stream key).
    """

    name: str = "effect"

    def bind(self, config: SimConfig, seed: int) -> None:
        """Called once by the simulator before the first step with its configuration and seed."""

    def to_dict(self) -> dict[str, object]:
        """Parameters for provenance (override to list them)."""
        return {"name": self.name, "type": type(self).__name__}

    def timing(self, timing: TimingConfig) -> TimingConfig:
        """Timing conventions with this effect (called once, before the first step)."""
        return timing

    # dynamics -------------------------------------------------------------------------------
    def inertia_kg_m2(self, t_s: np.ndarray, inertia_kg_m2: np.ndarray) -> np.ndarray:
        """True inertia over each step: (3, 3) or (n, 3, 3) [kg m^2]."""
        return inertia_kg_m2

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        """Torque actually applied over each step, (n, 3) CRF [N m] (command + thruster noise in)."""
        return torque_n_m

    def spacecraft_acceleration_m_s2(self, t_s: np.ndarray, a_sc_m_s2: np.ndarray) -> np.ndarray:
        """Non-gravitational spacecraft acceleration over each step, (n, 3) CRF [m s^-2]."""
        return a_sc_m_s2

    # GRS ------------------------------------------------------------------------------------
    def com_offset_m(self, t_s: np.ndarray, grs_id: int, com_offset_m: np.ndarray) -> np.ndarray:
        """True c.m. offset d of GRS ``grs_id``: (3,) or (n, 3) CRF [m]."""
        return com_offset_m

    def grs_accelerations(self, t_s: np.ndarray, grs_id: int, angular_rad_s2: np.ndarray,
                          linear_m_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Accelerations the GRS converts to voltages (readout noise included), (n, 3) each, TMRF."""
        return angular_rad_s2, linear_m_s2

    def grs_scale_factors(self, t_s: np.ndarray, grs_id: int, angular_scale_factors: np.ndarray,
                          linear_scale_factors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True scale factors of the conversion: (3,) or (n, 3) each [rad s^-2 V^-1], [m s^-2 V^-1]."""
        return angular_scale_factors, linear_scale_factors

    def grs_voltages_v(self, t_s: np.ndarray, grs_id: int, voltages_v: np.ndarray) -> np.ndarray:
        """Electrode voltages after conversion and voltage noise, (n, 6) [V]."""
        return voltages_v

    # star tracker ---------------------------------------------------------------------------
    def star_tracker_quat_xyzw(self, t_s: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
        """Measured star-tracker attitude (noise included), (n, 4)."""
        return quat_xyzw
