"""The Cramer-Rao bound of a layout's maneuver: the simulator's noise-free signals into the estimator's bound.

:func:`taiji2_estimator_pkg.core.crlb.crlb` bounds any record's information; this module supplies the
noise-free angular acceleration and rate of a layout's maneuver by simulating it, which is why it lives at
the applications layer (the estimator never needs the simulator).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.crlb import CrlbResult, crlb
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

__all__ = ["crlb_for_layout", "noise_free_signals"]


def noise_free_signals(layout: Any, duration_s: float | None = None, overrides: Mapping[str, Any] | None = None,
                       maneuver: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
    """True angular acceleration and rate of a layout's maneuver (simulated).

    Every noise source is switched off; the thruster torque noise (real motion) too.

    Parameters
    ----------
    layout : str, path, mapping or SimConfig
        Simulator layout.
    duration_s : float, optional
        Maneuver duration [s] (default: the layout's).
    overrides : mapping, optional
        Further dotted-key overrides of the layout.
    maneuver : object, optional
        Any maneuver family (:mod:`taiji2_model.maneuver_families`) instead of the layout's square wave; flown
        over ``duration_s`` (default: to its end).

    Returns
    -------
    t_s, omega_dot, omega : numpy.ndarray
        (n,), (n, 3), (n, 3).
    config : SimConfig
        The configuration used (noise switched off).
    """
    source = layout.to_dict() if hasattr(layout, "to_dict") else layout
    settings = dict(overrides or {})
    if duration_s is not None:
        settings["maneuver.duration_s"] = float(duration_s)
    for name in NOISE_SOURCE_NAMES:
        settings[f"noise.{name}.enabled"] = False
    config = load_config(source, overrides=settings)
    steps = None if maneuver is None or duration_s is None else round(float(duration_s) * config.sample_rate_hz)
    out = simulate_batch(config, 0, maneuver_torque_commands(config, steps, maneuver=maneuver))
    return out.t_s, out.truth.omega_dot_rad_s2, out.truth.omega_rad_s, config


def crlb_for_layout(layout: Any, duration_s: float | None = None, grs_ids: Sequence[int] = (1, 2),
                    overrides: Mapping[str, Any] | None = None, detrend: str = "linear",
                    maneuver: Any = None) -> CrlbResult:
    """Bounds for a simulator layout (maneuver, geometry, noise budget, true G and d of the layout).

    Parameters
    ----------
    layout : str, path, mapping or SimConfig
        Layout, e.g. ``"type1"``.
    duration_s : float, optional
        Experiment length [s].
    grs_ids : sequence of int
        GRS.
    overrides : mapping, optional
        Dotted-key overrides (e.g. ``{"noise.thruster_force.enabled": False}``); they apply to the
        noise budget of the bound, while the signals are always noise-free.
    detrend : str
        Nuisance model of d.
    maneuver : object, optional
        The maneuver flown (any family), instead of the layout's square wave.
    """
    source = layout.to_dict() if hasattr(layout, "to_dict") else layout
    config = load_config(source, overrides=dict(overrides or {}))
    instrument = InstrumentModel.from_layout(config)
    t, wd, w, _ = noise_free_signals(config, duration_s, maneuver=maneuver)
    sensors = {s.grs_id: s for s in config.grs.sensors}
    return crlb(instrument, t, wd, w, grs_ids, {g: sensors[g].angular_scale_factors for g in grs_ids},
                {g: sensors[g].com_offset_m for g in grs_ids}, detrend)
