"""The one rule that turns raw streams (star tracker, GRS1, GRS2) into epochs, in bulk and streaming.

Every path that reads raw data - ``taiji2 calibrate``, ``taiji2 diagnose`` and the estimator nodes -
assigns samples to epochs here: :func:`grid_streams` on whole arrays (a bag), :class:`EpochAssembler`
message by message (the nodes). Both apply the same rule, so the same samples in stamp order give the
same epochs (same instants, same stamps and samples per epoch).

The rule
--------
Epoch grid
    ``T_j = origin + j P`` (``P`` the sample period, ``j >= 0``). The GRS are the reference clock:
    ``origin`` is the first stamp of a reference stream (``reference``, by default both GRS; with no
    reference sample at all, the first stamp of any stream).
Slot of a stream
    Each stream keeps its own sampling phase: its *slot* ``s`` is the circular median, modulo
    ``P``, of the offsets ``t - origin`` of its first :data:`SLOT_SAMPLES` distinct stamps, in
    ``[-P/2, P/2)`` (circular: the offsets are unwrapped around the first one, so a phase near
    ``P/2`` with jitter does not split). A sample stamped ``t`` goes to the epoch
    ``j = round((t - origin - s) / P)``: the epoch whose instant is nearest to ``t - s``, i.e. within
    half a period of its stream's own sampling instant. Its stamp is kept in the epoch
    (:attr:`Epoch.stamps`): nothing is resampled or re-stamped.
Reasons (one set, per stream, counted)
    ``duplicate_stamp``: the stamp of the stream's previous sample again.
    ``out_of_order_stamp``: streaming only: older than the stream's previous sample, or for an epoch
    already released (a bulk read sorts each stream by stamp first, so it has none).
    ``off_grid_stamp``: further than :data:`GRID_TOLERANCE` ``P`` from its stream's slot (a stamp
    jitter of a few ms rms at 10 Hz is far inside: 25 ms).
    ``before_start``: its epoch precedes the origin (``j < 0``: a stream that started before the GRS).
    ``duplicate_epoch``: a second, distinct stamp of the stream in an epoch that already holds one
    (the first is kept).
Phase
    The slot is what the estimators use as the stream's constant time offset against the GRS
    (:meth:`GriddedStreams.offset_s`, :meth:`EpochAssembler.offset_s`); the median of the residual
    ``t - T_j`` over *all* accepted samples is reported as ``phase_ns`` (bulk).

Streaming release
-----------------
Messages of each stream arrive in stamp order, but the streams interleave arbitrarily: how far one
stream runs ahead of another in stamps depends on transport, executor batching and the backlog. So an
epoch is released, in stamp order, once every stream has either delivered its sample for that epoch
or moved past it. A stream that stops (a star-tracker dropout, a dead sensor, a stream never heard)
stops holding epochs back once, since its last message, another stream has delivered ``max_lag_s``
worth of samples (``max_lag_s`` times the sample rate, counted in messages). Until its slot is known
(its first :data:`SLOT_SAMPLES` samples, or it stopped) a stream's samples wait, and so do the epochs.

Which epochs a stream holds back is a function of the messages received and their order, never of
how far apart stamps are: a stream whose messages are merely late (its publisher starved of CPU, a
slow transport, a reader drained in batches) keeps delivering between the others' messages and holds
the epochs back however long it takes, so the epochs released - hence the estimate - are the same on
an idle and on a busy machine. The order of messages *across* readers is that of the executor's round
robin (at most one take batch, 64 messages, of one reader in a row) only while every reader has
messages waiting: when one topic's datagrams are lost and repaired (a busy receiver's socket buffer
overflowing in a burst), the other readers deliver batch after batch meanwhile, and two batches (128
messages) had GRS2 taken for stopped and its next 64 samples refused as out of order (a link run in
the CI beside two CPU-bound processes). So a node also gives ``min_silence_s``: a stream counts as
stopped only once it has, besides, been silent that long on the wall clock. Wall time can thus only
delay the decision that a stream stopped, never make it: a stream that did stop has no samples left
to deliver, so the epochs are the same whenever they go. Only ``max_pending`` (memory) and
:meth:`EpochAssembler.flush` (end of data) release an epoch otherwise.

Where streaming and bulk differ
-------------------------------
Only where messages do not arrive in stamp order: a sample older than its stream's previous one, or
whose epoch was already released (it arrived after the others had moved on by more than ``max_lag_s``
of messages, or its stream had been declared stopped), is refused as ``out_of_order_stamp`` by the
assembler, while the bulk read sorts and uses it. Stamps at which a stream's sample did not enter an
epoch are counted as missing, per stream, from the origin (the assembler cannot know of samples sent
before it listened). When every stream has stepped back in time (a restarted source, e.g. a simulator
running its seed again) the next epoch released is marked ``after_restart``: the estimators start a
new segment there. Plain Python and numpy: no middleware.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["GRID_TOLERANCE", "REASONS", "SLOT_SAMPLES", "Epoch", "EpochAssembler", "GriddedStreams",
           "UndeterminedError", "circular_offset", "grid_streams"]

#: a stamp this far behind its stream's latest [ns] is a step back in time, not a late sample
RESTART_STEP_BACK_NS = 1_000_000_000
#: a stamp further than this fraction of a period from its stream's slot is off the grid
GRID_TOLERANCE = 0.25
#: distinct stamps of a stream whose circular median fixes its slot
SLOT_SAMPLES = 9
#: every reason a sample is refused, in the order the rule tests them
REASONS = ("duplicate_stamp", "out_of_order_stamp", "off_grid_stamp", "before_start", "duplicate_epoch")
DEFAULT_REFERENCE = ("grs1", "grs2")


class UndeterminedError(ValueError):
    """A result that the data cannot determine; ``str()`` is one line naming the stream and the reason."""

    def __init__(self, stream: str, reason: str) -> None:
        super().__init__(f"{stream}: {reason}")
        self.stream = stream
        self.reason = reason


def circular_offset(offsets_ns: Sequence[int] | np.ndarray, period_ns: int) -> int:
    """Circular median of stamp offsets modulo the period, in [-P/2, P/2) [ns].

    The offsets are unwrapped around the first one (each moved by a whole number of periods to
    within half a period of it) before the median, so that a phase near P/2 with jitter does not
    split into two halves a period apart.
    """
    x = np.asarray(offsets_ns, dtype=np.int64)
    first = int(x[0])
    unwrapped = first + ((x - first + period_ns // 2) % period_ns) - period_ns // 2
    median = round(float(np.median(unwrapped)))
    return (median + period_ns // 2) % period_ns - period_ns // 2


def _place(t_ns: np.ndarray, origin_ns: int, slot_ns: int, period_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """(epoch index, residual from the stream's own instant [ns]) of stamps: the rule."""
    shifted = np.asarray(t_ns, dtype=np.int64) - origin_ns - slot_ns
    index = np.floor_divide(shifted + period_ns // 2, period_ns)
    return index, shifted - index * period_ns


@dataclass
class GriddedStreams:
    """Streams assigned to epochs by the rule (:func:`grid_streams`).

    Attributes
    ----------
    t_ns : numpy.ndarray
        (n,) epoch instants ``origin + j P``, from the origin to the last epoch holding a sample [ns].
    period_ns : int
        P [ns].
    index : dict of str to numpy.ndarray
        Per stream: (m,) epoch index of each accepted sample, increasing.
    stamps_ns : dict of str to numpy.ndarray
        Per stream: (m,) stamps of the accepted samples [ns].
    values : dict of str to numpy.ndarray
        Per stream: (m, ...) payload rows of the accepted samples.
    slot_ns : dict of str to int
        Per stream: the slot of the rule (its constant offset from the epoch instants) [ns].
    phase_ns : dict of str to float
        Per stream: median of ``stamp - T_j`` over its accepted samples (the robust phase) [ns].
    refused : dict of str to dict of str to int
        Per stream and reason (:data:`REASONS`): samples not assigned.
    """

    t_ns: np.ndarray
    period_ns: int
    index: dict[str, np.ndarray] = field(default_factory=dict)
    stamps_ns: dict[str, np.ndarray] = field(default_factory=dict)
    values: dict[str, np.ndarray] = field(default_factory=dict)
    slot_ns: dict[str, int] = field(default_factory=dict)
    phase_ns: dict[str, float] = field(default_factory=dict)
    refused: dict[str, dict[str, int]] = field(default_factory=dict)
    reference: tuple[str, ...] = DEFAULT_REFERENCE

    @property
    def n(self) -> int:
        """Number of epochs."""
        return int(self.t_ns.size)

    def on_grid(self, stream: str, fill: float = np.nan) -> np.ndarray:
        """(n, ...) the stream's payload rows at their epochs, ``fill`` where it has none."""
        rows = self.values[stream]
        out = np.full((self.n, *rows.shape[1:]), fill, dtype=np.float64)
        out[self.index[stream]] = rows
        return out

    def present(self, stream: str) -> np.ndarray:
        """(n,) bool: epochs holding a sample of the stream."""
        out = np.zeros(self.n, dtype=bool)
        out[self.index[stream]] = True
        return out

    def missing(self) -> dict[str, int]:
        """Per stream: epochs without a sample of it (from the origin to the last epoch)."""
        return {s: self.n - int(self.index[s].size) for s in self.index}

    def offset_s(self, stream: str) -> float:
        """The stream's constant time offset after the reference's sampling instants [s].

        Its slot minus the mean slot of the reference streams that have samples (0 when it is
        itself the only reference); what the estimators model (docs/estimators.md, epochs).
        """
        return _offset_s(self.slot_ns, stream, self.reference)


def _offset_s(slots: Mapping[str, int | None], stream: str, reference: Sequence[str]) -> float:
    slot = slots.get(stream)
    if slot is None:
        return 0.0
    refs = [slots[r] for r in reference if slots.get(r) is not None]
    return (slot - (float(np.mean(refs)) if refs else 0.0)) / 1e9


def _count(refused: dict[str, dict[str, int]], stream: str, reason: str, n: int) -> None:
    if n:
        inner = refused.setdefault(stream, {})
        inner[reason] = inner.get(reason, 0) + int(n)


def grid_streams(streams: Mapping[str, tuple[Any, Any]], period_s: float,
                 reference: Sequence[str] = DEFAULT_REFERENCE) -> GriddedStreams:
    """Assign whole streams to epochs by the rule (the bulk path: a bag, arrays).

    Parameters
    ----------
    streams : mapping
        Stream name -> ((m,) stamps [ns], integers; (m, ...) payload rows), in any order (each
        stream is sorted by stamp, stably, first).
    period_s : float
        Sample period P [s] (0.1 at 10 Hz).
    reference : sequence of str
        The streams whose first stamp is the grid's origin (default both GRS).

    Returns
    -------
    GriddedStreams
        Empty (``n == 0``) when no stream has a sample.
    """
    if not period_s > 0:
        raise ValueError(f"period_s: must be > 0 s, got {period_s!r}")
    period_ns = round(float(period_s) * 1e9)
    reference = tuple(reference)
    clean: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    refused: dict[str, dict[str, int]] = {}
    for name, (t_raw, x_raw) in streams.items():
        t = np.asarray(t_raw, dtype=np.int64).reshape(-1)
        x = np.asarray(x_raw)
        if x.shape[0] != t.size:
            raise ValueError(f"{name}: {x.shape[0]} samples but {t.size} stamps")
        order = np.argsort(t, kind="stable")
        t, x = t[order], x[order]
        repeat = np.zeros(t.size, dtype=bool)
        repeat[1:] = t[1:] == t[:-1]
        _count(refused, name, "duplicate_stamp", int(np.count_nonzero(repeat)))
        clean[name] = (t[~repeat], x[~repeat])
    firsts = [int(t[0]) for name, (t, _) in clean.items() if name in reference and t.size]
    if not firsts:
        firsts = [int(t[0]) for t, _ in clean.values() if t.size]
    out = GriddedStreams(t_ns=np.zeros(0, dtype=np.int64), period_ns=period_ns, refused=refused,
                         reference=reference)
    if not firsts:
        for name, (t, x) in clean.items():
            out.index[name], out.stamps_ns[name], out.values[name] = np.zeros(0, np.int64), t, x
        return out
    origin = min(firsts)
    last = -1
    for name, (t, x) in clean.items():
        if not t.size:
            out.index[name], out.stamps_ns[name], out.values[name] = np.zeros(0, np.int64), t, x
            continue
        slot = circular_offset(t[:SLOT_SAMPLES] - origin, period_ns)
        out.slot_ns[name] = slot
        index, residual = _place(t, origin, slot, period_ns)
        keep = np.abs(residual) <= GRID_TOLERANCE * period_ns
        _count(refused, name, "off_grid_stamp", int(np.count_nonzero(~keep)))
        early = keep & (index < 0)
        _count(refused, name, "before_start", int(np.count_nonzero(early)))
        keep &= ~early
        kept = np.flatnonzero(keep)
        second = np.zeros(kept.size, dtype=bool)
        second[1:] = index[kept[1:]] == index[kept[:-1]]
        _count(refused, name, "duplicate_epoch", int(np.count_nonzero(second)))
        kept = kept[~second]
        out.index[name], out.stamps_ns[name], out.values[name] = index[kept], t[kept], x[kept]
        if kept.size:
            last = max(last, int(index[kept[-1]]))
            out.phase_ns[name] = float(np.median(residual[kept] + slot))
    out.t_ns = origin + np.arange(last + 1, dtype=np.int64) * period_ns
    return out


@dataclass
class Epoch:
    """The samples of one epoch: stream name -> payload (absent streams missing).

    Attributes
    ----------
    t_ns : int
        The epoch's instant ``origin + j P`` on the reference (GRS) clock [ns].
    samples : dict of str to Any
        Stream -> payload.
    stamps : dict of str to int
        Stream -> the sample's own stamp [ns] (its time offset from ``t_ns`` is kept, not removed).
    after_restart : bool
        Every stream went back in time before this epoch (a restarted source, e.g. a simulator
        rerun): its data need not continue the dynamics of the epochs before.
    index : int
        j.
    """

    t_ns: int
    samples: dict[str, Any] = field(default_factory=dict)
    stamps: dict[str, int] = field(default_factory=dict)
    after_restart: bool = False
    index: int = 0

    def state_dict(self) -> dict[str, Any]:
        """The epoch as plain values (for a checkpoint)."""
        return {"t_ns": self.t_ns, "index": self.index, "samples": dict(self.samples), "stamps": dict(self.stamps),
                "after_restart": self.after_restart}

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> Epoch:
        """The epoch of :meth:`state_dict`."""
        return cls(int(state["t_ns"]), dict(state["samples"]), {k: int(v) for k, v in state["stamps"].items()},
                   bool(state["after_restart"]), int(state["index"]))


class EpochAssembler:
    """Collects per-stream samples and releases epochs in order, by the rule of this module.

    Parameters
    ----------
    streams : sequence of str
        Stream names, e.g. ``("star_tracker", "grs1", "grs2")``.
    max_lag_s : float
        A stream from which no message arrived while another stream delivered this much data
        (``max_lag_s / sample_period_s`` messages) no longer holds epochs back: they go without it [s].
    sample_period_s : float
        Sample period P of the streams [s] (0.1 at 10 Hz).
    max_pending : int
        At most this many epochs wait; the oldest is released beyond it.
    reference : sequence of str
        Streams whose first stamp is the grid's origin (default both GRS, those of them in ``streams``).
    min_silence_s : float
        A stream counts as stopped only once it has also been silent this long on ``clock`` [s] (0: the
        message count alone decides). Poll :meth:`release_stopped` for the epochs that frees.
    clock : callable
        Seconds on a monotonic clock (default :func:`time.monotonic`).
    """

    def __init__(self, streams: Sequence[str], max_lag_s: float, sample_period_s: float = 0.1,
                 max_pending: int = 200_000, reference: Sequence[str] = DEFAULT_REFERENCE, *,
                 min_silence_s: float = 0.0, clock: Callable[[], float] = time.monotonic) -> None:
        if not max_lag_s > 0:
            raise ValueError(f"max_lag_s: must be > 0 s, got {max_lag_s!r}")
        if not sample_period_s > 0:
            raise ValueError(f"sample_period_s: must be > 0 s, got {sample_period_s!r}")
        if not min_silence_s >= 0:
            raise ValueError(f"min_silence_s: must be >= 0 s, got {min_silence_s!r}")
        self.streams = tuple(streams)
        self.min_silence_s = float(min_silence_s)
        self._clock = clock
        #: clock time of each stream's last message (of the assembler's start before its first)
        self._heard_s: dict[str, float] = {s: clock() for s in self.streams}
        self.reference = tuple(s for s in reference if s in self.streams) or self.streams
        self.period_ns = round(float(sample_period_s) * 1e9)
        self.max_lag_messages = max(round(float(max_lag_s) / float(sample_period_s)), 1)
        self.max_pending = int(max_pending)
        self._pending: dict[int, Epoch] = {}
        self._latest: dict[str, int] = {s: -1 for s in self.streams}
        #: epoch index of each stream's latest in-order stamp (None: its slot is not known yet)
        self._reached: dict[str, int | None] = {s: None for s in self.streams}
        self._last_index: dict[str, int | None] = {s: None for s in self.streams}
        #: samples waiting for the origin and their stream's slot: (stamp, payload)
        self._unplaced: dict[str, list[tuple[int, Any]]] = {s: [] for s in self.streams}
        self.origin_ns: int | None = None
        self.slot_ns: dict[str, int | None] = {s: None for s in self.streams}
        self._released = -1  # index of the last released epoch
        self._received: dict[str, int] = {s: 0 for s in self.streams}
        self._received_at_last: dict[str, dict[str, int]] = {s: dict(self._received) for s in self.streams}
        self.refused: dict[str, dict[str, int]] = {}
        #: samples of each stream that entered a released epoch
        self.delivered: dict[str, int] = {s: 0 for s in self.streams}
        #: stamp of the first sample received from any stream [ns] (-1: none yet)
        self.first_ns = -1
        #: streams whose stamps went back by more than RESTART_STEP_BACK_NS since the last released epoch
        self._went_back: set[str] = set()

    # -- the rule, sample by sample ------------------------------------------------------------
    def _refuse(self, stream: str, reason: str) -> None:
        _count(self.refused, stream, reason, 1)

    def add(self, stream: str, t_ns: int, payload: Any) -> list[Epoch]:
        """Add a sample stamped ``t_ns`` [ns]; returns the epochs now ready, oldest first."""
        if stream not in self._latest:
            raise KeyError(f"unknown stream {stream!r}")
        t_ns = int(t_ns)
        if self.first_ns < 0:
            self.first_ns = t_ns
        self._received[stream] += 1
        self._received_at_last[stream] = dict(self._received)
        if self.min_silence_s > 0:
            self._heard_s[stream] = self._clock()
        if t_ns == self._latest[stream]:
            self._refuse(stream, "duplicate_stamp")
            return []
        if t_ns < self._latest[stream]:
            self._refuse(stream, "out_of_order_stamp")
            if t_ns < self._latest[stream] - RESTART_STEP_BACK_NS:
                self._went_back.add(stream)
            return []
        self._latest[stream] = t_ns
        if self.slot_ns[stream] is None:
            self._unplaced[stream].append((t_ns, payload))
            self._anchor(final=False)
        else:
            self._put(stream, t_ns, payload)
        return self._ready()

    def _anchor(self, final: bool) -> None:
        """Fix the origin and the slots that the samples received allow (all of them when ``final``)."""
        if self.origin_ns is None:
            firsts = [self._unplaced[s][0][0] for s in self.reference if self._unplaced[s]]
            if not firsts and (final or all(map(self._is_dead, self.reference))):
                firsts = [u[0][0] for u in self._unplaced.values() if u]
            if not firsts:
                return
            self.origin_ns = min(firsts)
        for s in self.streams:
            waiting = self._unplaced[s]
            if waiting and (len(waiting) >= SLOT_SAMPLES or final or self._is_dead(s)):
                self.slot_ns[s] = circular_offset([t - self.origin_ns for t, _ in waiting[:SLOT_SAMPLES]],
                                                  self.period_ns)
                self._unplaced[s] = []
                for t, payload in waiting:
                    self._put(s, t, payload)

    def _put(self, stream: str, t_ns: int, payload: Any) -> None:
        assert self.origin_ns is not None and self.slot_ns[stream] is not None
        # the rule of _place, in plain integers (per message)
        shifted = t_ns - self.origin_ns - self.slot_ns[stream]
        j = (shifted + self.period_ns // 2) // self.period_ns
        self._reached[stream] = j
        if abs(shifted - j * self.period_ns) > GRID_TOLERANCE * self.period_ns:
            self._refuse(stream, "off_grid_stamp")
        elif j < 0:
            self._refuse(stream, "before_start")
        elif j <= self._released:
            self._refuse(stream, "out_of_order_stamp")
        elif j == self._last_index[stream]:
            self._refuse(stream, "duplicate_epoch")
        else:
            epoch = self._pending.get(j)
            if epoch is None:
                epoch = self._pending[j] = Epoch(self.origin_ns + j * self.period_ns, index=j)
            epoch.samples[stream] = payload
            epoch.stamps[stream] = t_ns
            self._last_index[stream] = j

    # -- release --------------------------------------------------------------------------------
    def _is_dead(self, stream: str) -> bool:
        """Nothing arrived from ``stream`` while another stream delivered ``max_lag_s`` worth of messages, nor for
        ``min_silence_s`` of the clock."""
        at_last = self._received_at_last[stream]
        if not any(self._received[o] - at_last[o] >= self.max_lag_messages for o in self.streams):
            return False
        return self.min_silence_s <= 0 or self._clock() - self._heard_s[stream] >= self.min_silence_s

    def release_stopped(self) -> list[Epoch]:
        """The epochs that wait only for streams which have since been silent for ``min_silence_s`` (poll it:
        no message need come to make a stream's silence long enough), oldest first."""
        return self._ready()

    def _holds(self, stream: str, j: int) -> bool:
        """Whether ``stream`` may still deliver a sample for epoch ``j``."""
        reached = self._reached[stream]
        return (reached is None or reached < j) and not self._is_dead(stream)

    def _ready(self) -> list[Epoch]:
        """The epochs every stream has delivered or passed, or that wait only for dead streams (or overflow)."""
        if any(self._unplaced.values()):
            self._anchor(final=False)  # a stream may have stopped holding its slot back
        released: list[Epoch] = []
        for j in sorted(self._pending):
            epoch = self._pending[j]
            overflow = len(self._pending) > self.max_pending
            if not overflow and any(self._holds(s, j) for s in self.streams if s not in epoch.samples):
                break
            released.append(self._release(j))
        return released

    def _release(self, j: int) -> Epoch:
        epoch = self._pending.pop(j)
        # a restart sends every stream back; one stale or flooding peer sends back only its own topic
        epoch.after_restart = self._went_back >= set(self.streams)
        self._went_back.clear()
        for stream in epoch.samples:
            self.delivered[stream] += 1
        self._released = j
        return epoch

    def flush(self) -> list[Epoch]:
        """Release everything still pending (end of data), oldest first."""
        self._anchor(final=True)
        return [self._release(j) for j in sorted(self._pending)]

    # -- counts ---------------------------------------------------------------------------------
    @property
    def released_ns(self) -> int:
        """Instant of the last released epoch [ns] (-1: none yet)."""
        return -1 if self.origin_ns is None or self._released < 0 else self.origin_ns + self._released * self.period_ns

    def grid_stamps(self) -> int:
        """Epochs from the origin to the last released epoch."""
        return self._released + 1

    def missing(self) -> dict[str, int]:
        """Per stream: epochs from the origin to the last released epoch without its sample (lost in
        transport, dropped, refused, or never sent)."""
        grid = self.grid_stamps()
        return {s: max(grid - self.delivered[s], 0) for s in self.streams}

    def offset_s(self, stream: str) -> float:
        """The stream's constant time offset after the reference's sampling instants [s] (0 until known)."""
        return _offset_s(self.slot_ns, stream, self.reference)

    def state_dict(self) -> dict[str, Any]:
        """Everything the assembler holds, the epochs still pending and the samples waiting for their slot
        included: a node restarted from it refuses a sample it had accepted (as out of order, its stamp not
        newer than its stream's latest), so a sample accepted but left out of the state would be lost for good
        (a restarted c.m.-offset estimator that had taken the whole run before its kill then stalled on the
        simulator's rerun)."""
        return {"latest": dict(self._latest), "released": self._released, "refused": self.refused,
                "delivered": dict(self.delivered), "first_ns": self.first_ns, "origin_ns": self.origin_ns,
                "slot_ns": dict(self.slot_ns), "reached": dict(self._reached),
                "last_index": dict(self._last_index),
                "pending": [self._pending[j].state_dict() for j in sorted(self._pending)],
                "unplaced": {k: list(v) for k, v in self._unplaced.items()}, "went_back": sorted(self._went_back)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._latest.update({k: int(v) for k, v in state["latest"].items()})
        self.refused = {k: dict(v) for k, v in state["refused"].items()}
        self.delivered.update({k: int(v) for k, v in state.get("delivered", {}).items()})
        self.first_ns = int(state.get("first_ns", -1))
        if "origin_ns" in state:
            self.origin_ns = None if state["origin_ns"] is None else int(state["origin_ns"])
            self._released = int(state["released"])
            for name, table in (("slot_ns", self.slot_ns), ("reached", self._reached),
                                ("last_index", self._last_index)):
                table.update({k: None if v is None else int(v) for k, v in state[name].items()})
        elif int(state.get("released_ns", -1)) >= 0:
            # a checkpoint of the stamp-keyed assembler: its last epoch's stamp is this grid's index 0
            self.origin_ns, self._released = int(state["released_ns"]), 0
        # (checkpoints before 2026-12-01 hold none of these: what they had pending is lost, as it was)
        for epoch in map(Epoch.from_state_dict, state.get("pending", [])):
            self._pending[epoch.index] = epoch
        for name, waiting in state.get("unplaced", {}).items():
            self._unplaced[name] = [(int(t), payload) for t, payload in waiting]
        self._went_back = set(state.get("went_back", []))
