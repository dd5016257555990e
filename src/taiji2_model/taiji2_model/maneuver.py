"""Square-wave torque maneuver and the thrust it demands from the micro-thrusters.

Axis k of the maneuver is a square wave of period P shifted by ``phase_k``: ``+A_k`` during the
first half period after ``start + phase_k``, ``-A_k`` during the second, repeated (and extended
periodically back to ``start``), and zero outside ``[start, start + duration)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.config_schema import ConfigError, ManeuverConfig

__all__ = ["AXIS_NAMES", "ManeuverError", "SquareWaveManeuver", "thrust_per_thruster_n"]

AXIS_NAMES = ("X", "Y", "Z")
"""CRF axis names used in messages."""

# Times within this of an edge count as at (after) the edge, so that an edge on a sample time
# is not lost to rounding of t = t0 + k dt (numerical, not physical).
_EDGE_TOLERANCE_S = 1e-9


class ManeuverError(ConfigError):
    """Invalid maneuver parameter or a thrust the thrusters cannot deliver.

    Parameters
    ----------
    parameter : str
        Offending parameter, e.g. ``"period_s"`` or ``"amplitude_n_m[Z]"``.
    problem : str
        What is wrong with it.
    """


def thrust_per_thruster_n(torque_n_m: ArrayLike, lever_arm_m: float) -> np.ndarray:
    """Thrust one thruster per axis must deliver for a torque.

    Parameters
    ----------
    torque_n_m : array_like
        (..., 3) torque about the CRF axes [N m].
    lever_arm_m : float
        Lever arm L of each axis' thruster [m].

    Returns
    -------
    numpy.ndarray
        (..., 3) thrust ``|tau| / L`` [N].
    """
    if not lever_arm_m > 0.0:
        raise ManeuverError("lever_arm_m", f"must be > 0, got {lever_arm_m!r}")
    return np.abs(np.asarray(torque_n_m, dtype=np.float64)) / lever_arm_m


class SquareWaveManeuver:
    """Square-wave torque about the CRF axes.

    Parameters
    ----------
    period_s : float
        Period P [s], > 0.
    amplitude_n_m : array_like
        (3,) amplitude per CRF axis [N m] (a scalar is broadcast).
    phase_s : array_like
        (3,) time shift per axis [s] (a scalar is broadcast).
    start_s : float
        Start time [s].
    duration_s : float
        Duration [s], >= 0.

    Raises
    ------
    ManeuverError
        Non-finite values, non-positive period, negative duration, wrong shapes.
    """

    def __init__(self, period_s: float, amplitude_n_m: ArrayLike, phase_s: ArrayLike,
                 start_s: float, duration_s: float) -> None:
        self.period_s = self._scalar("period_s", period_s)
        if not self.period_s > 0.0:
            raise ManeuverError("period_s", f"must be > 0, got {period_s!r}")
        self.amplitude_n_m = self._vector("amplitude_n_m", amplitude_n_m)
        self.phase_s = self._vector("phase_s", phase_s)
        self.start_s = self._scalar("start_s", start_s)
        self.duration_s = self._scalar("duration_s", duration_s)
        if self.duration_s < 0.0:
            raise ManeuverError("duration_s", f"must be >= 0, got {duration_s!r}")

    @classmethod
    def from_config(cls, config: ManeuverConfig) -> SquareWaveManeuver:
        """Build from the ``maneuver`` section of a :class:`~.config.SimConfig`."""
        return cls(config.period_s, config.amplitude_n_m, config.phase_s, config.start_s,
                   config.duration_s)

    @property
    def end_s(self) -> float:
        """End of the maneuver window ``start + duration`` [s] (exclusive)."""
        return self.start_s + self.duration_s

    @staticmethod
    def _scalar(name: str, value: float) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ManeuverError(name, f"must be a number, got {value!r}") from None
        if not np.isfinite(number):
            raise ManeuverError(name, f"must be finite, got {value!r}")
        return number

    @staticmethod
    def _vector(name: str, value: ArrayLike) -> np.ndarray:
        try:
            array = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ManeuverError(name, f"must be numeric, got {value!r}") from None
        if array.ndim == 0:
            array = np.full(3, float(array))
        if array.shape != (3,):
            raise ManeuverError(name, f"wrong shape {array.shape}, expected (3,)")
        if not np.all(np.isfinite(array)):
            raise ManeuverError(name, "must be finite")
        array.setflags(write=False)
        return array

    # ---------------------------------------------------------------------------------------
    def torque_series(self, t_s: ArrayLike) -> np.ndarray:
        """Commanded torque at many times.

        Parameters
        ----------
        t_s : array_like
            (n,) times [s].

        Returns
        -------
        numpy.ndarray
            (n, 3) torque about CRF X, Y, Z [N m].
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        half_period_s = 0.5 * self.period_s
        # index of the half period each time falls in, per axis; even -> +A, odd -> -A
        elapsed = t[:, None] - self.start_s - self.phase_s[None, :]
        half_index = np.floor((elapsed + _EDGE_TOLERANCE_S) / half_period_s)
        sign = 1.0 - 2.0 * np.mod(half_index, 2.0)
        active = (t >= self.start_s - _EDGE_TOLERANCE_S) & (t < self.end_s - _EDGE_TOLERANCE_S)
        return np.where(active[:, None], sign * self.amplitude_n_m[None, :], 0.0)

    def torque_at(self, t_s: float) -> np.ndarray:
        """Commanded torque at one time t [s], (3,) [N m]."""
        return self.torque_series(np.array([t_s], dtype=np.float64))[0]

    def switch_times(self, t0_s: float, t1_s: float) -> np.ndarray:
        """Times in ``[t0, t1)`` at which the commanded torque changes.

        Parameters
        ----------
        t0_s, t1_s : float
            Window [s].

        Returns
        -------
        numpy.ndarray
            Sorted edge times [s]: the start, each half-period edge of a non-zero axis inside the
            maneuver window, and the end (if any axis is non-zero).
        """
        if not np.any(self.amplitude_n_m != 0.0) or self.duration_s == 0.0:
            return np.empty(0)
        half_period_s = 0.5 * self.period_s
        edges = [self.start_s, self.end_s]
        for axis in np.flatnonzero(self.amplitude_n_m != 0.0):
            reference_s = self.start_s + self.phase_s[axis]
            first = np.ceil((self.start_s - reference_s) / half_period_s)
            last = np.floor((self.end_s - reference_s) / half_period_s)
            edges.extend(reference_s + half_period_s * np.arange(first, last + 1.0))
        times = np.unique(np.asarray(edges, dtype=np.float64))
        inside_window = (times >= self.start_s) & (times <= self.end_s)
        in_request = (times >= t0_s - _EDGE_TOLERANCE_S) & (times < t1_s - _EDGE_TOLERANCE_S)
        times = times[inside_window & in_request]
        # merge edges that coincide to rounding (e.g. two axes switching together)
        if times.size > 1:
            keep = np.concatenate(([True], np.diff(times) > _EDGE_TOLERANCE_S))
            times = times[keep]
        return times

    def check_thrust(self, min_thrust_n: float, max_thrust_n: float, lever_arm_m: float) -> None:
        """Refuse amplitudes the micro-thrusters cannot deliver.

        Parameters
        ----------
        min_thrust_n, max_thrust_n : float
            Usable thrust range of one thruster [N].
        lever_arm_m : float
            Lever arm L [m].

        Raises
        ------
        ManeuverError
            Naming the axis (``amplitude_n_m[X]`` etc.) whose non-zero amplitude needs a thrust
            ``|A| / L`` outside ``[min_thrust_n, max_thrust_n]``.
        """
        thrust_n = thrust_per_thruster_n(self.amplitude_n_m, lever_arm_m)
        for axis, (amplitude, thrust) in enumerate(zip(self.amplitude_n_m, thrust_n, strict=True)):
            if amplitude != 0.0 and not min_thrust_n <= thrust <= max_thrust_n:
                raise ManeuverError(
                    f"amplitude_n_m[{AXIS_NAMES[axis]}]",
                    f"|{amplitude:.4g}| N m / {lever_arm_m:.4g} m needs {thrust:.4g} N per thruster, "
                    f"outside the thruster range [{min_thrust_n:.4g}, {max_thrust_n:.4g}] N",
                )
