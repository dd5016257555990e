"""Alignment of the raw streams (star tracker, GRS1, GRS2) into epochs by header stamp.

Messages of each stream arrive in stamp order, but the streams interleave arbitrarily: how far one
stream runs ahead of another depends on transport and executor batching (a bag replayed as fast as
possible can put one topic many seconds of stamps ahead). So an epoch is released, in stamp order,
once every stream has either delivered its sample for that stamp or moved past it; a stream that
goes silent (no message for ``max_silence_s`` of wall time, e.g. a star-tracker dropout or a dead
sensor) stops holding epochs back. ``max_pending`` bounds memory. Duplicate and out-of-order stamps
of a stream are refused and counted. When every stream has stepped back in time (a restarted source,
e.g. a simulator running its seed again) the next epoch released is marked ``after_restart``: the
estimators start a new segment there instead of joining two runs' dynamics. Plain Python: no
middleware.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

#: a stamp this far behind its stream's latest [ns] is a step back in time, not a late sample
RESTART_STEP_BACK_NS = 1_000_000_000


@dataclass
class Epoch:
    """The samples of one stamp: stream name -> payload (absent streams missing)."""

    t_ns: int
    samples: dict[str, Any] = field(default_factory=dict)
    #: every stream went back in time before this epoch (a restarted source, e.g. a simulator rerun):
    #: its data need not continue the dynamics of the epochs before
    after_restart: bool = False


class EpochAssembler:
    """Collects per-stream samples and releases epochs in stamp order.

    Parameters
    ----------
    streams : sequence of str
        Stream names, e.g. ``("star_tracker", "grs1", "grs2")``.
    max_silence_s : float
        A stream without a message for this long (wall clock) no longer holds epochs back [s].
    max_pending : int
        At most this many epochs wait; the oldest is released beyond it.
    """

    def __init__(self, streams: Sequence[str], max_silence_s: float, max_pending: int = 200_000) -> None:
        self.streams = tuple(streams)
        self.max_silence_s = float(max_silence_s)
        self.max_pending = int(max_pending)
        self._pending: dict[int, Epoch] = {}
        self._latest: dict[str, int] = {s: -1 for s in self.streams}
        self._heard: dict[str, float] = {}
        self._first_heard_s: float | None = None
        self._released_ns = -1
        self.refused: dict[str, dict[str, int]] = {}
        #: streams whose stamps went back by more than RESTART_STEP_BACK_NS since the last released epoch
        self._went_back: set[str] = set()

    def _refuse(self, stream: str, reason: str) -> None:
        counts = self.refused.setdefault(stream, {})
        counts[reason] = counts.get(reason, 0) + 1

    def add(self, stream: str, t_ns: int, payload: Any, now_s: float) -> list[Epoch]:
        """Add a sample received at wall time ``now_s`` [s]; returns the epochs now ready, oldest first."""
        if stream not in self._latest:
            raise KeyError(f"unknown stream {stream!r}")
        self._heard[stream] = now_s
        if self._first_heard_s is None:
            self._first_heard_s = now_s
        if t_ns == self._latest[stream]:
            self._refuse(stream, "duplicate_stamp")
            return []
        if t_ns < self._latest[stream] or t_ns <= self._released_ns:
            self._refuse(stream, "out_of_order_stamp")
            if t_ns < self._latest[stream] - RESTART_STEP_BACK_NS:
                self._went_back.add(stream)
            return []
        self._latest[stream] = t_ns
        self._pending.setdefault(t_ns, Epoch(t_ns)).samples[stream] = payload
        return self.expire(now_s)

    def expire(self, now_s: float) -> list[Epoch]:
        """The epochs ready at wall time ``now_s``: complete, passed by every stream, or waiting only
        for silent streams (call periodically so that a dropout does not stall the output)."""
        # a stream never heard counts from the first message of any stream
        start = self._first_heard_s if self._first_heard_s is not None else now_s
        silent = {s for s in self.streams if now_s - self._heard.get(s, start) >= self.max_silence_s}
        released: list[Epoch] = []
        for t_ns in sorted(self._pending):
            epoch = self._pending[t_ns]
            waiting = [s for s in self.streams if s not in epoch.samples and self._latest[s] < t_ns]
            overflow = len(self._pending) > self.max_pending
            if waiting and not overflow and not all(s in silent for s in waiting):
                break
            released.append(self._release(t_ns))
        return released

    def _release(self, t_ns: int) -> Epoch:
        epoch = self._pending.pop(t_ns)
        # a restart sends every stream back; one stale or flooding peer sends back only its own topic
        epoch.after_restart = self._went_back >= set(self.streams)
        self._went_back.clear()
        self._released_ns = t_ns
        return epoch

    def flush(self) -> list[Epoch]:
        """Release everything still pending (end of data), oldest first."""
        return [self._release(t) for t in sorted(self._pending)]

    def state_dict(self) -> dict[str, Any]:
        return {"latest": dict(self._latest), "released_ns": self._released_ns, "refused": self.refused}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._latest.update({k: int(v) for k, v in state["latest"].items()})
        self._released_ns = int(state["released_ns"])
        self.refused = {k: dict(v) for k, v in state["refused"].items()}
