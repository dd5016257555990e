"""d of the GRS data up to t with G of the data up to t, however the two estimators run against each other.

Offline (``first_met``, ``taiji2 calibrate``) the c.m.-offset estimate of the data up to t uses G of the data up
to t. Live, the scale-factor estimator can lag the GRS data by ~1,000 s of data through a playback burst, or run
ahead of the c.m.-offset estimator by as much: d published with whatever G had arrived met its requirements up
to 800 s of data later than the offline estimate did when G lagged, and was stamped up to 1,300 s late when G
led, by amounts that depended on how the processes were scheduled. Two halves make the published d, and the
time it first meets a requirement, the same however fast either process runs:

* :class:`ScaleFactorWait` holds each GRS epoch until the scale-factor estimate of its publish period has come.
  Its bounds keep a dead or absent scale-factor estimator from stalling the c.m.-offset one: no wait before
  the first scale-factor estimate has come, at most ``max_lag_ns`` of data held (older epochs go on with the
  last G), and the node's wall-clock bound for one that stops (:meth:`ScaleFactorWait.release_all`);
* :class:`ScaleFactorHistory` keeps the scale factors received by stamp, so an epoch at t uses the newest of
  the data up to t even where newer ones have already come.

No middleware: epochs and arrays in, epochs and arrays out.
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
        """Scale factors of the data up to ``t_ns`` have come; returns the epochs now free to go on. The pairs come
        in stamp order; an older one is a scale-factor estimator that restarted (from its checkpoint, or on a
        restarted source's rerun): the held epochs wait for it to catch up again."""
        self.through_ns = int(t_ns)
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


class ScaleFactorHistory:
    """Determined scale factors (G and its covariance) by stamp, oldest first; the newest is always kept."""

    def __init__(self) -> None:
        self.entries: deque[tuple[int, Any, Any]] = deque()

    def add(self, t_ns: int, g: Any, cov: Any) -> None:
        """Scale factors of the data up to ``t_ns``. Stamps increase; an older one starts the history again (a
        restarted scale-factor estimator: what it had estimated beyond is not of the data it will use)."""
        if self.entries and t_ns < self.entries[-1][0]:
            self.entries.clear()
        self.entries.append((int(t_ns), g, cov))

    def newest(self) -> tuple[int, Any, Any] | None:
        """(stamp [ns], G, covariance) of the newest, or None."""
        return self.entries[-1] if self.entries else None

    def through(self, t_ns: int) -> tuple[int, Any, Any] | None:
        """The newest with a stamp up to ``t_ns`` (None: none yet); older ones are dropped (``t_ns`` increases)."""
        while len(self.entries) > 1 and self.entries[1][0] <= t_ns:
            self.entries.popleft()
        return self.entries[0] if self.entries and self.entries[0][0] <= t_ns else None
