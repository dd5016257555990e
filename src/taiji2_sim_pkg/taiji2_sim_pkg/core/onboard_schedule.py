"""The onboard time-based schedule of time-tagged commanding (ECSS PUS service 11), without middleware.

:class:`OnboardSchedule` inserts activities on their arrival onboard, refusing (and counting) one released
before arrival + time margin (late: never executed late) or beyond the capacity; the torque at a time is
that of the last activity released at or before it (zero before the first). The ground's side, which makes
the tables, is :mod:`taiji2_ground_pkg.uplink_plan` (docs/link.md).
"""

from __future__ import annotations

import bisect

import numpy as np

__all__ = ["RELEASE_TOLERANCE_S", "OnboardSchedule"]

#: a release this close after a time counts as at it [s] (one CUC count, 2**-24 s)
RELEASE_TOLERANCE_S = 2.0**-24


class OnboardSchedule:
    """The onboard time-based schedule (module docstring)."""

    def __init__(self, capacity: int, time_margin_s: float) -> None:
        self.capacity = int(capacity)
        self.time_margin_s = float(time_margin_s)
        self._release: list[float] = []
        self._torque: list[tuple[float, float, float]] = []
        self.inserted = 0
        self.refused_late = 0
        self.refused_full = 0

    def pending(self, t_s: float) -> int:
        """Activities not yet released at ``t_s``."""
        return len(self._release) - bisect.bisect_right(self._release, t_s)

    def insert(self, arrival_s: float, activities: list[tuple[float, tuple[float, float, float]]]) -> tuple[int, int]:
        """Insert activities arriving onboard at ``arrival_s``; returns (refused late, refused for capacity)."""
        late = full = 0
        for release_s, torque in sorted(activities, key=lambda a: a[0]):
            if release_s < arrival_s + self.time_margin_s:
                late += 1
                continue
            if self.pending(arrival_s) >= self.capacity:
                full += 1
                continue
            j = bisect.bisect_right(self._release, release_s)
            self._release.insert(j, release_s)
            self._torque.insert(j, tuple(float(v) for v in torque))
            self.inserted += 1
        self.refused_late += late
        self.refused_full += full
        return late, full

    def torque_at(self, t_s: float) -> np.ndarray:
        """Torque in effect at ``t_s`` [N m] (the last activity released at or before it; zero before any).

        A release within :data:`RELEASE_TOLERANCE_S` after ``t_s`` counts as at it: release times travel as
        CUC times (2**-24 s counts), so a release on the command grid comes back up to 30 ns off it."""
        j = bisect.bisect_right(self._release, t_s + RELEASE_TOLERANCE_S)
        return np.array(self._torque[j - 1]) if j else np.zeros(3)
