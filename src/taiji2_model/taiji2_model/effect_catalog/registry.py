"""The registry of catalog effects: name -> class, and effects built from names and parameters.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from taiji2_model.effect_catalog.dynamics import (
    ComDrift,
    GravityGradient,
    InertiaError,
    ThrusterForceLeakage,
    ThrusterTorqueGain,
)
from taiji2_model.effect_catalog.impulse import Impulse
from taiji2_model.effect_catalog.readout import CrossCoupling, ReadoutNonlinearity, ScaleFactorDrift
from taiji2_model.effect_catalog.star_tracker import StarTrackerLowFreqNoise
from taiji2_model.effect_catalog.test_mass import TmStiffness
from taiji2_model.effect_catalog.timing import ActuationDelay, GrsTimeOffset, ThrusterResponse, TimeOffset
from taiji2_model.effects import Effect

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (ScaleFactorDrift, CrossCoupling, TimeOffset, StarTrackerLowFreqNoise, ThrusterTorqueGain,
                ComDrift, ReadoutNonlinearity, InertiaError, GravityGradient, TmStiffness, ThrusterForceLeakage,
                ActuationDelay, ThrusterResponse, GrsTimeOffset, Impulse)
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
