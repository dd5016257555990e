"""Parameterisations of the maneuver families for the search.

Each family maps a vector x in a box to a maneuver *shape* with a common torque scale s [N m]:
the search fixes the shape, :mod:`.optimize` scales it up to the binding constraint. Times are
rounded to the 10 Hz command grid (0.1 s) so that the commander and the simulator agree.

- ``square``: x = (log10 P, a_X, a_Y, a_Z in [0, 1], phase_X/P, phase_Y/P, phase_Z/P in [0, 1));
- ``multisine``: harmonics 1 and 3 of 1/P on each axis: x = (log10 P, 6 amplitudes in [0, 1],
  6 phases / 2 pi in [0, 1));
- ``piecewise``: 8 steps of P/8 per period: x = (log10 P, 24 values in [-1, 1]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FAMILY_NAMES", "Family", "family"]

FAMILY_NAMES = ("square", "multisine", "piecewise")
_PERIOD_BOUNDS_S = (100.0, 2000.0)
_HARMONICS = (1.0, 3.0)
_STEPS = 8


def _grid(value_s: float, step_s: float = 0.1) -> float:
    return float(max(step_s, np.round(value_s / step_s) * step_s))


@dataclass(frozen=True)
class Family:
    """A family: its box, its shape builder, and the paper's preset expressed in it."""

    name: str
    bounds: list[tuple[float, float]]

    def period_s(self, x: np.ndarray) -> float:
        """Repetition period of the shape [s]."""
        p = 10.0 ** float(x[0])
        return _grid(p, 0.2) if self.name == "square" else _grid(p / _STEPS) * _STEPS if self.name == "piecewise" \
            else _grid(p)

    def maneuver(self, x: np.ndarray, scale_n_m: float, duration_s: float, min_torque_n_m: float = 0.0) -> object:
        """Maneuver of shape x, torque scale s [N m]; levels below ``min_torque_n_m`` are set to 0."""
        from taiji2_model.maneuver import SquareWaveManeuver
        from taiji2_model.maneuver_families import MultisineManeuver, PiecewiseManeuver

        x = np.asarray(x, dtype=np.float64)
        period = self.period_s(x)
        if self.name == "square":
            amp = scale_n_m * x[1:4]
            amp = np.where(amp < min_torque_n_m, 0.0, amp)
            phase = np.array([_grid(f * period) for f in x[4:7]])
            return SquareWaveManeuver(period, amp, phase, 0.0, duration_s)
        if self.name == "multisine":
            amp = scale_n_m * x[1:7].reshape(2, 3)
            # an axis whose peak falls below the smallest thrust is switched off
            amp[:, np.sum(amp, axis=0) < min_torque_n_m] = 0.0
            phase = 2.0 * np.pi * x[7:13].reshape(2, 3)
            return MultisineManeuver(np.array(_HARMONICS) / period, amp, phase, 0.0, duration_s)
        values = scale_n_m * x[1:].reshape(_STEPS, 3)
        values = np.where(np.abs(values) < min_torque_n_m, 0.0, values)
        return PiecewiseManeuver(period / _STEPS, values, 0.0, duration_s)

    def paper_start(self, period_s: float, amplitude_n_m: np.ndarray, phase_s: np.ndarray) -> np.ndarray:
        """x of (an approximation of) the paper's square wave in this family (seed of the search)."""
        a = np.asarray(amplitude_n_m, dtype=np.float64) / np.max(np.abs(amplitude_n_m))
        f = np.mod(np.asarray(phase_s, dtype=np.float64) / period_s, 1.0)
        lp = np.log10(period_s)
        if self.name == "square":
            return np.concatenate(([lp], a, f))
        if self.name == "multisine":
            # Fourier series of the square wave: 4/pi sum sin(2 pi k (t - phase) / P) / k, k = 1, 3;
            # amplitudes normalised into [0, 1]
            amps = np.vstack([a / k for k in _HARMONICS]) * (np.pi / 4.0) * (4.0 / np.pi)
            phases = np.vstack([np.mod(-k * f, 1.0) for k in _HARMONICS])
            return np.concatenate(([lp], np.clip(amps.ravel(), 0.0, 1.0), phases.ravel()))
        t = (np.arange(_STEPS) + 0.5) * period_s / _STEPS
        square = np.where(np.mod(np.floor((t[:, None] - phase_s[None, :]) / (0.5 * period_s)), 2.0) == 0.0, 1.0, -1.0)
        return np.concatenate(([lp], (square * a[None, :]).ravel()))


def family(name: str) -> Family:
    """The family called ``name`` (square | multisine | piecewise)."""
    lp = (float(np.log10(_PERIOD_BOUNDS_S[0])), float(np.log10(_PERIOD_BOUNDS_S[1])))
    if name == "square":
        return Family(name, [lp] + [(0.0, 1.0)] * 3 + [(0.0, 0.999)] * 3)
    if name == "multisine":
        return Family(name, [lp] + [(0.0, 1.0)] * 6 + [(0.0, 0.999)] * 6)
    if name == "piecewise":
        return Family(name, [lp] + [(-1.0, 1.0)] * (3 * _STEPS))
    raise ValueError(f"family: must be one of {', '.join(FAMILY_NAMES)}, got {name!r}")
