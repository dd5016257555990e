"""Alignment of the raw streams (star tracker, GRS1, GRS2) into epochs by header stamp.

Messages of each stream arrive in stamp order, but the streams interleave arbitrarily and any of
them may drop samples. An epoch is released, in stamp order, once every stream has either
delivered its sample for that stamp or moved past it, or once it lags the newest stamp seen by more
than ``max_lag_ns`` (a stream that went silent). Duplicate and out-of-order stamps of a stream are
refused and counted. Plain Python: no middleware.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Epoch:
    """The samples of one stamp: stream name -> payload (absent streams missing)."""

    t_ns: int
    samples: dict[str, Any] = field(default_factory=dict)


class EpochAssembler:
    """Collects per-stream samples and releases complete or expired epochs in stamp order.

    Parameters
    ----------
    streams : sequence of str
        Stream names, e.g. ``("star_tracker", "grs1", "grs2")``.
    max_lag_ns : int
        An incomplete epoch older than the newest stamp by more than this is released anyway [ns].
    """

    def __init__(self, streams: Sequence[str], max_lag_ns: int) -> None:
        self.streams = tuple(streams)
        self.max_lag_ns = int(max_lag_ns)
        self._pending: dict[int, Epoch] = {}
        self._latest: dict[str, int] = {s: -1 for s in self.streams}
        self._released_ns = -1
        self.refused: dict[str, dict[str, int]] = {}

    def _refuse(self, stream: str, reason: str) -> None:
        counts = self.refused.setdefault(stream, {})
        counts[reason] = counts.get(reason, 0) + 1

    def add(self, stream: str, t_ns: int, payload: Any) -> list[Epoch]:
        """Add a sample; returns the epochs that became ready, oldest first."""
        if stream not in self._latest:
            raise KeyError(f"unknown stream {stream!r}")
        if t_ns == self._latest[stream]:
            self._refuse(stream, "duplicate_stamp")
            return []
        if t_ns < self._latest[stream] or t_ns <= self._released_ns:
            self._refuse(stream, "out_of_order_stamp")
            return []
        self._latest[stream] = t_ns
        self._pending.setdefault(t_ns, Epoch(t_ns)).samples[stream] = payload
        return self._ready()

    def _ready(self) -> list[Epoch]:
        released: list[Epoch] = []
        newest = max(self._latest.values())
        slowest = min(self._latest.values())
        for t_ns in sorted(self._pending):
            epoch = self._pending[t_ns]
            complete = len(epoch.samples) == len(self.streams)
            passed = t_ns <= slowest  # every stream delivered or moved past this stamp
            expired = newest - t_ns > self.max_lag_ns
            if not (complete or passed or expired):
                break
            released.append(self._pending.pop(t_ns))
            self._released_ns = t_ns
        return released

    def flush(self) -> list[Epoch]:
        """Release everything still pending (end of data), oldest first."""
        released = [self._pending.pop(t) for t in sorted(self._pending)]
        if released:
            self._released_ns = released[-1].t_ns
        return released

    def state_dict(self) -> dict[str, Any]:
        return {"latest": dict(self._latest), "released_ns": self._released_ns, "refused": self.refused}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._latest.update({k: int(v) for k, v in state["latest"].items()})
        self._released_ns = int(state["released_ns"])
        self.refused = {k: dict(v) for k, v in state["refused"].items()}
