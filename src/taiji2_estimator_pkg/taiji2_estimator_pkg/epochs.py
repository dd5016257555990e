"""Alignment of the raw streams (star tracker, GRS1, GRS2) into epochs by header stamp.

Messages of each stream arrive in stamp order, but the streams interleave arbitrarily: how far one
stream runs ahead of another in stamps depends on transport, executor batching and the backlog (with
a backlog, a stream that had a gap covers more stamps per message taken than the others). So an
epoch is released, in stamp order, once every stream has either delivered its sample for that stamp
or moved past it. A stream that stops (a star-tracker dropout, a dead sensor, a stream never heard)
stops holding epochs back once, since its last message, another stream has delivered ``max_lag_s``
worth of samples (``max_lag_s`` times the sample rate, counted in messages).

Every decision here is a function of the messages received and their order, never of wall time or
of how far apart stamps are: a stream whose messages are merely late (its publisher starved of CPU,
a slow transport, a reader drained in batches) keeps delivering between the others' messages and
holds the epochs back however long it takes, so the epochs released - hence the estimate - are the
same on an idle and on a busy machine. (Deciding on wall-clock silence, as this module once did,
released epochs without the samples of a publisher descheduled for 0.5 s; those samples were then
refused as out of order. Deciding on the stamp span the others ran ahead fails too: with a backlog,
a stream that had a gap runs ahead in stamps.) The order of messages *across* readers is that of the
executor's round robin (at most one take batch, 64 messages, of one reader in a row), so
``max_lag_s`` must exceed that; streams from separate publishers in separate processes can drift
apart by more under load, at high acceleration: raise ``max_lag_s`` there. Only ``max_pending``
(memory) and :meth:`flush` (end of data) release an epoch otherwise.

Duplicate and out-of-order stamps of a stream are refused and counted. Stamps at which a stream's
sample did not enter an epoch are counted as missing, per stream, on the sample grid, from the first
stamp this assembler received (it cannot know of samples sent before it listened). When every
stream has stepped back in time (a restarted source, e.g. a simulator running its seed again) the
next epoch released is marked ``after_restart``: the estimators start a new segment there instead of
joining two runs' dynamics. Plain Python: no middleware.
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
    max_lag_s : float
        A stream from which no message arrived while another stream delivered this much data
        (``max_lag_s / sample_period_s`` messages) no longer holds epochs back: they go without it [s].
    sample_period_s : float
        Sample period of the streams [s] (0.1 at 10 Hz): the grid on which missing samples are
        counted, and the unit of ``max_lag_s`` in messages.
    max_pending : int
        At most this many epochs wait; the oldest is released beyond it.
    """

    def __init__(self, streams: Sequence[str], max_lag_s: float, sample_period_s: float = 0.1,
                 max_pending: int = 200_000) -> None:
        if not max_lag_s > 0:
            raise ValueError(f"max_lag_s: must be > 0 s, got {max_lag_s!r}")
        if not sample_period_s > 0:
            raise ValueError(f"sample_period_s: must be > 0 s, got {sample_period_s!r}")
        self.streams = tuple(streams)
        self.period_ns = round(float(sample_period_s) * 1e9)
        self.max_lag_messages = max(round(float(max_lag_s) / float(sample_period_s)), 1)
        self.max_pending = int(max_pending)
        self._pending: dict[int, Epoch] = {}
        self._latest: dict[str, int] = {s: -1 for s in self.streams}
        self._released_ns = -1
        #: messages received per stream, and their values at each stream's last message
        self._received: dict[str, int] = {s: 0 for s in self.streams}
        self._received_at_last: dict[str, dict[str, int]] = {s: dict(self._received) for s in self.streams}
        self.refused: dict[str, dict[str, int]] = {}
        #: samples of each stream that entered a released epoch
        self.delivered: dict[str, int] = {s: 0 for s in self.streams}
        #: stamp of the first sample received from any stream [ns] (-1: none yet)
        self.first_ns = -1
        #: grid stamps from ``first_ns`` to the last released epoch, over segments (restarts)
        self._grid_before = 0  # grid stamps of the segments before the current one
        self._segment_first_ns = -1
        #: streams whose stamps went back by more than RESTART_STEP_BACK_NS since the last released epoch
        self._went_back: set[str] = set()

    def _refuse(self, stream: str, reason: str) -> None:
        counts = self.refused.setdefault(stream, {})
        counts[reason] = counts.get(reason, 0) + 1

    def add(self, stream: str, t_ns: int, payload: Any) -> list[Epoch]:
        """Add a sample stamped ``t_ns`` [ns]; returns the epochs now ready, oldest first."""
        if stream not in self._latest:
            raise KeyError(f"unknown stream {stream!r}")
        if self.first_ns < 0:
            self.first_ns = self._segment_first_ns = int(t_ns)
        self._received[stream] += 1
        self._received_at_last[stream] = dict(self._received)
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
        return self._ready()

    def _is_dead(self, stream: str) -> bool:
        """Nothing arrived from ``stream`` while another stream delivered ``max_lag_s`` worth of messages."""
        at_last = self._received_at_last[stream]
        return any(self._received[o] - at_last[o] >= self.max_lag_messages for o in self.streams)

    def _ready(self) -> list[Epoch]:
        """The epochs every stream has delivered or passed, or that wait only for dead streams (or overflow)."""
        released: list[Epoch] = []
        for t_ns in sorted(self._pending):
            epoch = self._pending[t_ns]
            waiting = [s for s in self.streams if s not in epoch.samples and self._latest[s] < t_ns]
            # an epoch usually waits for a live stream (the first of its samples has just arrived): the first
            # live one found ends the test (releasing changes no count, so the answer holds for later epochs)
            if waiting and not len(self._pending) > self.max_pending and not all(map(self._is_dead, waiting)):
                break
            released.append(self._release(t_ns))
        return released

    def _release(self, t_ns: int) -> Epoch:
        epoch = self._pending.pop(t_ns)
        # a restart sends every stream back; one stale or flooding peer sends back only its own topic
        epoch.after_restart = self._went_back >= set(self.streams)
        self._went_back.clear()
        if epoch.after_restart:
            self._grid_before += self._grid_count(self._segment_first_ns, self._released_ns)
            self._segment_first_ns = t_ns
        for stream in epoch.samples:
            self.delivered[stream] += 1
        self._released_ns = t_ns
        return epoch

    def _grid_count(self, first_ns: int, last_ns: int) -> int:
        return 0 if first_ns < 0 or last_ns < first_ns else round((last_ns - first_ns) / self.period_ns) + 1

    def grid_stamps(self) -> int:
        """Stamps of the sample grid from the first sample received to the last released epoch."""
        return self._grid_before + self._grid_count(self._segment_first_ns, self._released_ns)

    def missing(self) -> dict[str, int]:
        """Per stream: grid stamps from the first sample received to the last released epoch at which
        its sample did not enter an epoch (lost in transport, dropped, refused, or never sent)."""
        grid = self.grid_stamps()
        return {s: max(grid - self.delivered[s], 0) for s in self.streams}

    def flush(self) -> list[Epoch]:
        """Release everything still pending (end of data), oldest first."""
        return [self._release(t) for t in sorted(self._pending)]

    def state_dict(self) -> dict[str, Any]:
        return {"latest": dict(self._latest), "released_ns": self._released_ns, "refused": self.refused,
                "delivered": dict(self.delivered), "first_ns": self.first_ns,
                "grid_before": self._grid_before, "segment_first_ns": self._segment_first_ns}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._latest.update({k: int(v) for k, v in state["latest"].items()})
        self._released_ns = int(state["released_ns"])
        self.refused = {k: dict(v) for k, v in state["refused"].items()}
        # checkpoints written before missing samples were counted: count from the restart on
        self.delivered.update({k: int(v) for k, v in state.get("delivered", {}).items()})
        self.first_ns = int(state.get("first_ns", -1))
        self._grid_before = int(state.get("grid_before", 0))
        self._segment_first_ns = int(state.get("segment_first_ns", self.first_ns))
