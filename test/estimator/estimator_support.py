"""Cached simulator runs for the estimator tests (seeded; simulator imported lazily).

A plain module, not a conftest: `conftest` module names collide across test folders.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

ALL_NOISE = ("thruster_torque", "thruster_force", "srp", "lfs_translational", "lfs_rotational",
             "tm_environment", "grs_voltage", "star_tracker")


@functools.lru_cache(maxsize=64)
def _simulate(layout: str, duration_s: float, seed: int, overrides: tuple) -> object:
    config_mod = pytest.importorskip("taiji2_model.config")
    sim_mod = pytest.importorskip("taiji2_sim_pkg.core.simulator")
    settings = {"maneuver.duration_s": float(duration_s), **dict(overrides)}
    config = config_mod.load_config(layout, overrides=settings)
    out = sim_mod.simulate_batch(config, seed, sim_mod.maneuver_torque_commands(config))
    return config, out


def simulate(layout: str = "type1", duration_s: float = 3600.0, seed: int = 0, **overrides: object) -> tuple:
    """(SimConfig, SimOutput) of a seeded run; keyword overrides use ``__`` for dots."""
    items = tuple(sorted((k.replace("__", "."), v) for k, v in overrides.items()))
    return _simulate(layout, float(duration_s), int(seed), items)


def noise_free(**extra: object) -> dict:
    """Overrides switching every noise source off."""
    return {f"noise__{name}__enabled": False for name in ALL_NOISE} | extra


def truth(config: object) -> tuple[np.ndarray, np.ndarray]:
    """(G stacked (6,), d stacked (6,)) of a SimConfig."""
    sensors = config.grs.sensors
    return (np.concatenate([s.angular_scale_factors for s in sensors]),
            np.concatenate([s.com_offset_m for s in sensors]))
