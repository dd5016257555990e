"""GRS epochs held until the scale factors of their publish period have come.

The c.m.-offset estimate of the data up to t needs G; offline (``first_met``, ``taiji2 calibrate``) that is G of
the data up to t. Live, the scale-factor estimator can lag the GRS data by ~1,000 s of data through a playback
burst, and d published with the G received by then met its requirements up to 800 s of data later than the
offline estimate did, by an amount that depends on how the processes were scheduled. Holding each epoch until
the scale-factor estimate of its publish period has come makes the published d, and the time it first meets a
requirement, the same however fast either process runs. The wait has two bounds, so a dead or absent
scale-factor estimator never stalls the c.m.-offset one: no wait before the first scale-factor estimate has
come, and at most ``max_lag_ns`` of data held (older epochs go on with the last G); the node adds a wall-clock
bound for a scale-factor estimator that stops (:meth:`release_all`). No middleware: epochs in, epochs out.
"""

from __future__ import annotations

from collections import deque
from typing import Any


class ScaleFactorWait:
    """Epochs (anything with ``t_ns``, in time order) held until scale factors of their period's start come."""

    def __init__(self) -> None:
        self.pending: deque[Any] = deque()
        #: newest stamp through which scale factors have come (determined or not) [ns]; -1: none yet (no wait)
        self.through_ns = -1
        #: epochs released before the scale factors of their period (the bounds): d of them used an older G
        self.released_early = 0

    def add(self, epoch: Any, period_ns: int, max_lag_ns: int) -> list[Any]:
        """Hold ``epoch``; returns the epochs now free to go on, oldest first."""
        self.pending.append(epoch)
        return self._ready(period_ns, max_lag_ns)

    def scale_factors_through(self, t_ns: int, period_ns: int, max_lag_ns: int) -> list[Any]:
        """Scale factors of the data up to ``t_ns`` have come; returns the epochs now free to go on."""
        self.through_ns = max(self.through_ns, int(t_ns))
        return self._ready(period_ns, max_lag_ns)

    def release_all(self) -> list[Any]:
        """Every held epoch (the scale-factor estimator stopped, or the node shuts down)."""
        out = list(self.pending)
        self.pending.clear()
        self.released_early += len(out)
        return out

    def _ready(self, period_ns: int, max_lag_ns: int) -> list[Any]:
        out = []
        while self.pending:
            t_ns = self.pending[0].t_ns
            if self.through_ns < 0 or t_ns // period_ns * period_ns <= self.through_ns:
                out.append(self.pending.popleft())  # G of its period is here (or no scale factors to wait for)
            elif self.pending[-1].t_ns - t_ns > max_lag_ns:
                out.append(self.pending.popleft())  # memory bound: on with the last G
                self.released_early += 1
            else:
                break
        return out
