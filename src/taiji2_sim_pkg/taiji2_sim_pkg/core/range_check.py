"""GRS range monitoring: the TM linear readout against the +-range of the experiment.

Two parts are tracked separately, per GRS and TMRF axis:

- ``maneuver``: the rotation-induced part ``C_i (omega_dot x d_i + omega x (omega x d_i))``
  (truth field ``grs_linear_maneuver``), what the maneuver design controls;
- ``total``: the measured linear readout with all noise (truth field ``grs_linear_meas``), what
  the sensor actually has to accommodate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["PARTS", "PeakLinearReport", "RangeEvent", "RangeMonitor", "peak_linear_report"]

PARTS = ("maneuver", "total")
"""Names of the monitored parts of the linear readout."""
_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class RangeEvent:
    """A part of one GRS axis left the range for the first time.

    Attributes
    ----------
    t_s : float
        Sample time [s].
    part : str
        ``"maneuver"`` or ``"total"``.
    grs_id : int
        1 or 2.
    axis : str
        TMRF axis ``"x"``, ``"y"`` or ``"z"``.
    value_m_s2 : float
        Linear acceleration at that sample [m s^-2].
    range_m_s2 : float
        The range [m s^-2].
    """

    t_s: float
    part: str
    grs_id: int
    axis: str
    value_m_s2: float
    range_m_s2: float

    def message(self) -> str:
        """One-line human-readable description."""
        return (f"GRS{self.grs_id} {self.axis}: {self.part} linear acceleration {self.value_m_s2:.3e} m/s^2 "
                f"at t = {self.t_s:.3f} s exceeds the range +-{self.range_m_s2:.3e} m/s^2 "
                f"({abs(self.value_m_s2) / self.range_m_s2:.1%})")


class RangeMonitor:
    """Streaming range monitor for the two GRS.

    Parameters
    ----------
    range_m_s2 : float
        GRS linear range, +-range [m s^-2], > 0.
    n_grs : int
        Number of GRS (2).
    """

    def __init__(self, range_m_s2: float, n_grs: int = 2) -> None:
        if not (np.isfinite(range_m_s2) and range_m_s2 > 0.0):
            raise ValueError(f"range_m_s2: must be > 0, got {range_m_s2!r}")
        self.range_m_s2 = float(range_m_s2)
        self._shape = (n_grs, 3)
        self.samples = 0
        self.peak_m_s2 = {part: np.zeros(self._shape) for part in PARTS}
        self.peak_time_s = {part: np.full(self._shape, np.nan) for part in PARTS}
        self.excursions = {part: np.zeros(self._shape, dtype=np.int64) for part in PARTS}
        self.samples_outside = {part: np.zeros(self._shape, dtype=np.int64) for part in PARTS}
        self._was_outside = {part: np.zeros(self._shape, dtype=bool) for part in PARTS}
        self._reported = {part: np.zeros(self._shape, dtype=bool) for part in PARTS}

    def update(self, t_s: float, maneuver_linear_m_s2: ArrayLike,
               total_linear_m_s2: ArrayLike) -> list[RangeEvent]:
        """Feed one sample.

        Parameters
        ----------
        t_s : float
            Sample time [s].
        maneuver_linear_m_s2, total_linear_m_s2 : array_like
            (2, 3) per GRS, TMRF [m s^-2].

        Returns
        -------
        list of RangeEvent
            One event per (part, GRS, axis) that leaves the range for the first time.
        """
        return self.update_block(np.array([t_s], dtype=np.float64),
                                 np.asarray(maneuver_linear_m_s2)[None], np.asarray(total_linear_m_s2)[None])

    def update_block(self, t_s: ArrayLike, maneuver_linear_m_s2: ArrayLike,
                     total_linear_m_s2: ArrayLike) -> list[RangeEvent]:
        """Feed n consecutive samples: (n,) times and (n, 2, 3) accelerations; as n calls of update."""
        times = np.asarray(t_s, dtype=np.float64).reshape(-1)
        events: list[RangeEvent] = []
        if times.size == 0:
            return events
        for part, values in zip(PARTS, (maneuver_linear_m_s2, total_linear_m_s2), strict=True):
            block = np.asarray(values, dtype=np.float64).reshape(times.size, *self._shape)
            magnitude = np.abs(block)
            peak_index = np.argmax(magnitude, axis=0)
            block_peak = np.take_along_axis(magnitude, peak_index[None], axis=0)[0]
            better = block_peak > self.peak_m_s2[part]
            self.peak_m_s2[part] = np.where(better, block_peak, self.peak_m_s2[part])
            self.peak_time_s[part] = np.where(better, times[peak_index], self.peak_time_s[part])
            outside = magnitude > self.range_m_s2
            previous = np.concatenate((self._was_outside[part][None], outside[:-1]), axis=0)
            self.excursions[part] += np.sum(outside & ~previous, axis=0)
            self.samples_outside[part] += np.sum(outside, axis=0)
            self._was_outside[part] = outside[-1]
            first_new = np.any(outside, axis=0) & ~self._reported[part]
            for grs_index, axis in zip(*np.nonzero(first_new), strict=True):
                k = int(np.argmax(outside[:, grs_index, axis]))
                events.append(RangeEvent(float(times[k]), part, int(grs_index) + 1, _AXES[axis],
                                         float(block[k, grs_index, axis]), self.range_m_s2))
            self._reported[part] |= first_new
        self.samples += times.size
        events.sort(key=lambda event: event.t_s)
        return events

    def fraction_of_range(self, part: str) -> np.ndarray:
        """Peak |value| over range, (2, 3)."""
        return self.peak_m_s2[part] / self.range_m_s2

    def summary(self) -> dict[str, Any]:
        """Plain dict: range, samples, and per part peak, fraction, peak time, excursion counts."""
        result: dict[str, Any] = {"range_m_s2": self.range_m_s2, "samples": self.samples}
        for part in PARTS:
            result[part] = {
                "peak_m_s2": self.peak_m_s2[part].tolist(),
                "fraction_of_range": self.fraction_of_range(part).tolist(),
                "peak_time_s": self.peak_time_s[part].tolist(),
                "excursions": self.excursions[part].tolist(),
                "samples_outside": self.samples_outside[part].tolist(),
                "within_range": bool(np.all(self.peak_m_s2[part] <= self.range_m_s2)),
            }
        return result


@dataclass(frozen=True)
class PeakLinearReport:
    """Peak linear accelerations of a batch run against the range.

    Attributes
    ----------
    range_m_s2 : float
        The range [m s^-2].
    maneuver_peak_m_s2, total_peak_m_s2 : numpy.ndarray
        (2, 3) peak |value| per GRS and TMRF axis [m s^-2].
    total_excursions : numpy.ndarray
        (2, 3) number of excursions of the total beyond the range.
    """

    range_m_s2: float
    maneuver_peak_m_s2: np.ndarray
    total_peak_m_s2: np.ndarray
    total_excursions: np.ndarray

    @property
    def maneuver_fraction(self) -> np.ndarray:
        """(2, 3) maneuver peak over range."""
        return self.maneuver_peak_m_s2 / self.range_m_s2

    @property
    def total_fraction(self) -> np.ndarray:
        """(2, 3) total peak over range."""
        return self.total_peak_m_s2 / self.range_m_s2

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for logs and provenance."""
        return {
            "range_m_s2": self.range_m_s2,
            "maneuver_peak_m_s2": self.maneuver_peak_m_s2.tolist(),
            "maneuver_fraction_of_range": self.maneuver_fraction.tolist(),
            "total_peak_m_s2": self.total_peak_m_s2.tolist(),
            "total_fraction_of_range": self.total_fraction.tolist(),
            "total_excursions": self.total_excursions.tolist(),
        }

    def format(self) -> str:
        """Table, one line per GRS and part."""
        lines = [f"range +-{self.range_m_s2:.3e} m/s^2; peak |a| per TMRF axis x, y, z"]
        for grs_index in range(self.maneuver_peak_m_s2.shape[0]):
            for part, peak in (("maneuver", self.maneuver_peak_m_s2), ("total", self.total_peak_m_s2)):
                cells = ", ".join(f"{value:.3e} ({value / self.range_m_s2:6.1%})"
                                  for value in peak[grs_index])
                lines.append(f"  GRS{grs_index + 1} {part:8s}: {cells}")
        return "\n".join(lines)


def peak_linear_report(out: Any, range_m_s2: float) -> PeakLinearReport:
    """Peak maneuver-induced and total linear accelerations of a batch run.

    Parameters
    ----------
    out : SimOutput
        Batch output (uses ``out.t_s``, ``out.truth.grs_linear_maneuver`` and
        ``out.truth.grs_linear_meas``).
    range_m_s2 : float
        The range [m s^-2].

    Returns
    -------
    PeakLinearReport
    """
    monitor = RangeMonitor(range_m_s2, n_grs=out.truth.grs_linear_meas.shape[1])
    monitor.update_block(out.t_s, out.truth.grs_linear_maneuver, out.truth.grs_linear_meas)
    return PeakLinearReport(monitor.range_m_s2, monitor.peak_m_s2["maneuver"], monitor.peak_m_s2["total"],
                            monitor.excursions["total"])
