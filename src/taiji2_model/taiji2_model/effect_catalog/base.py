"""Shared parts of the catalog effects: readout names, parameter checks and the common base class.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.effects import Effect

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


