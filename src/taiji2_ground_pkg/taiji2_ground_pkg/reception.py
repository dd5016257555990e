"""Ground reception of a live packet stream: per APID in sequence order, each count once, gaps declared.

Packets reach the ground out of time order (real-time data first in a pass, stored data played back
after them), duplicated and with gaps. :class:`GroundReception` takes them as they arrive and
releases the samples of each APID in sequence-count order (= onboard time order), each once:

* a count received twice is a ``duplicate``;
* the next count after the last one released is released at once (nothing can come between them);
* a sample after a gap is held until the gap can no longer be filled: the spacecraft's
  *transmitted-through* time (every packet generated before it has been transmitted, see
  :mod:`taiji2_sim_pkg.core.link`) has passed it; the counts of the gap are then ``missing``
  (lost on the link or overwritten onboard), never released;
* :meth:`GroundReception.finish` (end of data) releases everything held.

Sequence counts are unwrapped per APID with the onboard times (the stream's sample period, learnt
from consecutive counts), so that a loss longer than the 14-bit counter is still placed right.
"""

from __future__ import annotations

import heapq
from collections import Counter
from dataclasses import dataclass

import numpy as np

from taiji2_runtime.packets.definition import STREAM_BY_APID
from taiji2_runtime.packets.packetize import SEQ_MODULO, PacketError, TelemetrySample, decode_packet

__all__ = ["GroundReception", "ReleasedSample"]

_HALF = SEQ_MODULO // 2


@dataclass(frozen=True)
class ReleasedSample:
    """A sample released in order: the decoded packet and its (first) ground reception time [ns]."""

    sample: TelemetrySample
    receive_ns: int


class _Apid:
    def __init__(self) -> None:
        self.top: int | None = None  # highest unwrapped index received
        self.top_seq = 0
        self.top_ns = 0
        self.period_ns: int | None = None
        self.released: int | None = None  # unwrapped index of the last sample released
        self.last_released_ns = -1
        self.held: dict[int, tuple[TelemetrySample, int]] = {}
        self.heap: list[int] = []  # the indices of ``held``
        self.counts: Counter = Counter()

    def index(self, seq: int, onboard_ns: int) -> int:
        if self.top is None:
            return 0
        step = (seq - self.top_seq + _HALF) % SEQ_MODULO - _HALF
        if self.period_ns:
            expected = round((onboard_ns - self.top_ns) / self.period_ns)
            if abs(expected - step) > _HALF:  # more than half the counter away: the times say how many wraps
                step += round((expected - step) / SEQ_MODULO) * SEQ_MODULO
        return self.top + step


class GroundReception:
    """Orders, deduplicates and gap-checks the telemetry packets the ground receives (module docstring)."""

    def __init__(self) -> None:
        self._apids: dict[int, _Apid] = {}
        self.rejected: Counter = Counter()  # packets that could not be decoded, by defect

    def offer(self, packet: bytes, receive_ns: int) -> None:
        """One packet as received at ground time ``receive_ns``."""
        try:
            sample = decode_packet(packet)
        except PacketError as exc:
            self.rejected[exc.kind] += 1
            return
        a = self._apids.setdefault(sample.stream.apid, _Apid())
        a.counts["received"] += 1
        i = a.index(sample.seq_count, sample.onboard_ns)
        if (a.released is not None and i <= a.released) or i in a.held:
            a.counts["duplicate"] += 1
            return
        if a.top is not None and i < a.top:
            a.counts["out_of_order"] += 1
        if a.top is None or i > a.top:
            if a.top is not None and i == a.top + 1 and a.period_ns is None and sample.onboard_ns > a.top_ns:
                a.period_ns = sample.onboard_ns - a.top_ns
            a.top, a.top_seq, a.top_ns = i, sample.seq_count, sample.onboard_ns
        a.held[i] = (sample, receive_ns)
        heapq.heappush(a.heap, i)

    def release(self, transmitted_through_ns: int | None = None) -> list[ReleasedSample]:
        """The samples that can go out now, per APID in order (APIDs interleaved by onboard time).

        ``transmitted_through_ns``: every packet generated onboard before it has been transmitted
        (None: unknown, only samples that continue the released sequence go out)."""
        out: list[ReleasedSample] = []
        for a in self._apids.values():
            while a.heap:
                i = a.heap[0]
                sample, receive_ns = a.held[i]
                contiguous = a.released is not None and i == a.released + 1
                if not contiguous and (transmitted_through_ns is None or sample.onboard_ns >= transmitted_through_ns):
                    break
                if a.released is not None and i > a.released + 1:
                    a.counts["missing"] += i - a.released - 1
                heapq.heappop(a.heap)
                del a.held[i]
                a.released = i
                a.last_released_ns = sample.onboard_ns
                a.counts["released"] += 1
                out.append(ReleasedSample(sample, receive_ns))
        out.sort(key=lambda r: r.sample.onboard_ns)
        return out

    def finish(self) -> list[ReleasedSample]:
        """End of data: release everything held (gaps before it are missing)."""
        return self.release(np.iinfo(np.int64).max)

    def counts(self) -> dict[str, dict[str, int]]:
        """Per stream: received, released, duplicate, out_of_order (arrived after a later count), missing
        (declared lost), held (waiting)."""
        result = {}
        for apid, a in sorted(self._apids.items()):
            name = STREAM_BY_APID[apid].name
            result[name] = {k: int(a.counts.get(k, 0)) for k in ("received", "released", "duplicate", "out_of_order",
                                                                 "missing")}
            result[name]["held"] = len(a.held)
        return result

    def released_through_ns(self) -> dict[str, int]:
        """Per stream: onboard time of the last sample released (-1: none yet)."""
        return {STREAM_BY_APID[apid].name: a.last_released_ns for apid, a in self._apids.items()}
