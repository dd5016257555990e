"""Summary of a bag (the ``taiji2 bag info`` engine): files, time span, topics, rates, gaps, provenance.

Two views of time per topic:

* receive times (the bag stamps: when the recorder got each message), read from the MCAP message
  indexes or the sqlite3 timestamp column, without decoding any message;
* header stamps (when the data were taken), for every type whose first field is a
  ``std_msgs/Header``: read from the first bytes of each serialised message. This is the view a
  user means by the rate and the gaps of a sensor stream: under accelerated simulated time the
  receive times follow the wall clock (bursts, pauses), the header stamps the data's own time.

``format_info`` shows the header-stamp view where there is one and says which view each row is.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from taiji2_runtime.bag.bulk_read import gather, read_raw_messages
from taiji2_runtime.bag.reading import custom_data, open_reader, storage_identifier, storages_of

_NS = 1_000_000_000


@dataclass
class TopicSummary:
    """One topic (and type) of a bag.

    Attributes
    ----------
    topic, msgtype : str
        Name and ``pkg/msg/Name`` type.
    count : int
        Messages.
    rate_hz : float or None
        (count - 1) / (last - first stamp) [Hz] of the receive times; None with fewer than two messages.
    largest_gap_s : float or None
        Largest interval between consecutive bag (receive) stamps [s].
    largest_gap_at_s : float or None
        Where that gap starts, relative to the bag start [s].
    stamp_rate_hz, stamp_largest_gap_s : float or None
        The same from the header stamps (sorted); None when the type has no header.
    stamp_largest_gap_at_s : float or None
        Where that gap starts, relative to the topic's first header stamp [s].
    stamp_start_ns, stamp_end_ns : int or None
        First and last header stamp [ns].
    """

    topic: str
    msgtype: str
    count: int
    rate_hz: float | None
    largest_gap_s: float | None
    largest_gap_at_s: float | None
    stamp_rate_hz: float | None = None
    stamp_largest_gap_s: float | None = None
    stamp_largest_gap_at_s: float | None = None
    stamp_start_ns: int | None = None
    stamp_end_ns: int | None = None


@dataclass
class BagSummary:
    """A bag as ``taiji2 bag info`` shows it (stamps in ns since the epoch of the recorder clock)."""

    path: str
    storage: str
    files: list[tuple[str, int]]
    size_bytes: int
    start_ns: int | None
    end_ns: int | None
    message_count: int
    topics: list[TopicSummary]
    custom_data: dict[str, str] = field(default_factory=dict)
    ros_distro: str | None = None

    @property
    def duration_s(self) -> float:
        """End minus start [s] (0 for an empty bag)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / _NS


def bag_info(path: str | Path) -> BagSummary:
    """Summarise the bag at ``path``.

    Raises
    ------
    BagError
        If the bag cannot be read.
    """
    with open_reader(path) as reader:
        files = [(Path(str(s.path)).name, Path(str(s.path)).stat().st_size) for s in storages_of(reader)]
        raw = read_raw_messages(reader, with_data=False)
        stamped = sorted({c.topic for c in reader.connections if _header_first(c)})
        stamps = {key: _header_stamps(m) for key, m in read_raw_messages(reader, stamped).items()} if stamped else {}
        storage = storage_identifier(reader)
        custom = custom_data(reader)
        distro = reader.ros_distro
    starts = [m.log_time_ns.min() for m in raw.values() if m.count]
    ends = [m.log_time_ns.max() for m in raw.values() if m.count]
    start = int(min(starts)) if starts else None
    end = int(max(ends)) if ends else None
    topics = []
    for (topic, msgtype), messages in sorted(raw.items()):
        times = np.sort(messages.log_time_ns)
        rate = gap = gap_at = None
        if times.shape[0] >= 2:
            span = (times[-1] - times[0]) / _NS
            rate = float((times.shape[0] - 1) / span) if span > 0 else None
            diffs = np.diff(times)
            k = int(np.argmax(diffs))
            gap = float(diffs[k]) / _NS
            gap_at = float(times[k] - (start or 0)) / _NS
        summary = TopicSummary(topic, msgtype, messages.count, rate, gap, gap_at)
        header = stamps.get((topic, msgtype))
        if header is not None and header.shape[0]:
            header = np.sort(header)
            summary.stamp_start_ns, summary.stamp_end_ns = int(header[0]), int(header[-1])
            if header.shape[0] >= 2:
                span = (header[-1] - header[0]) / _NS
                summary.stamp_rate_hz = float((header.shape[0] - 1) / span) if span > 0 else None
                diffs = np.diff(header)
                k = int(np.argmax(diffs))
                summary.stamp_largest_gap_s = float(diffs[k]) / _NS
                summary.stamp_largest_gap_at_s = float(header[k] - header[0]) / _NS
        topics.append(summary)
    return BagSummary(str(path), storage, files, sum(size for _, size in files), start, end,
                      sum(t.count for t in topics), topics, custom, distro)


_HEADER_TYPES = ("Header", "std_msgs/Header", "std_msgs/msg/Header")


def _header_first(connection: Any) -> bool:
    """Whether the connection's type starts with a std_msgs/Header (from the bag's own definition,
    else from the standard and taiji2 types)."""
    msgdef = getattr(connection, "msgdef", None)
    text = getattr(msgdef, "data", "") or ""
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("="):
            break
        if line:
            parts = line.split()
            return len(parts) >= 2 and parts[0] in _HEADER_TYPES and parts[1] == "header"
    try:
        from taiji2_runtime.typestore import typestore

        fields = typestore().fielddefs[connection.msgtype][1]
    except (KeyError, ImportError):
        return False
    return bool(fields) and fields[0][0] == "header" and fields[0][1][1] == "std_msgs/msg/Header"


def _header_stamps(messages: Any) -> np.ndarray:
    """(n,) header stamps [ns] of messages whose first field is a std_msgs/Header (CDR: 4-byte
    encapsulation, then int32 sec and uint32 nanosec in the encapsulation's byte order)."""
    parts = []
    for piece in messages.pieces:
        short = piece.lengths < 12
        rows = np.ascontiguousarray(gather(piece.blob, np.where(short, 0, piece.offsets), 12))
        little = rows[:, 1] == 1  # CDR_LE / PL_CDR_LE encapsulation
        sec = np.where(little, rows[:, 4:8].copy().view("<i4")[:, 0], rows[:, 4:8].copy().view(">i4")[:, 0])
        nsec = np.where(little, rows[:, 8:12].copy().view("<u4")[:, 0], rows[:, 8:12].copy().view(">u4")[:, 0])
        parts.append((sec.astype(np.int64) * _NS + nsec.astype(np.int64))[~short])
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} GiB"


def _stamp(ns: int | None) -> str:
    if ns is None:
        return "-"
    when = datetime.fromtimestamp(ns / _NS, tz=timezone.utc)
    return f"{when:%Y-%m-%d %H:%M:%S}.{(ns % _NS) // 1_000_000:03d} UTC ({ns // _NS}.{ns % _NS:09d})"


def format_info(summary: BagSummary, *, full_custom_data: bool = False) -> str:
    """Human-readable text of a :class:`BagSummary`, in the spirit of ``ros2 bag info``."""
    lines = [
        f"Files:             {', '.join(f'{name} ({_size(size)})' for name, size in summary.files) or '-'}",
        f"Bag size:          {_size(summary.size_bytes)}",
        f"Storage id:        {summary.storage}",
        f"Duration:          {summary.duration_s:.3f} s",
        f"Start:             {_stamp(summary.start_ns)}",
        f"End:               {_stamp(summary.end_ns)}",
        f"Messages:          {summary.message_count}",
    ]
    stamped = [t for t in summary.topics if t.stamp_start_ns is not None]
    if stamped:
        first, last = min(t.stamp_start_ns for t in stamped), max(t.stamp_end_ns for t in stamped)
        lines.insert(4, f"Header stamps:     {(last - first) / _NS:.3f} s, {first / _NS:.3f} .. {last / _NS:.3f} s "
                        "(the data's own time; Duration, Start and End are receive times)")
    lines.append("Topics:")
    width = max([len(t.topic) for t in summary.topics] + [5])
    type_width = max([len(t.msgtype) for t in summary.topics] + [4])
    for t in summary.topics:
        header = t.stamp_start_ns is not None
        rate_hz = t.stamp_rate_hz if header else t.rate_hz
        gap_s, gap_at_s = (t.stamp_largest_gap_s, t.stamp_largest_gap_at_s) if header else (t.largest_gap_s,
                                                                                              t.largest_gap_at_s)
        rate = f"{rate_hz:10.3f} Hz" if rate_hz is not None else f"{'-':>10s} Hz"
        gap = f"largest gap {gap_s:.3f} s at +{gap_at_s:.3f} s" if gap_s is not None else "largest gap -"
        view = "header stamps" if header else "receive times"
        lines.append(f"  {t.topic:<{width}s}  {t.msgtype:<{type_width}s}  {t.count:8d} msgs  {rate}  {gap}  "
                     f"({view})")
    if any(t.stamp_start_ns is not None for t in summary.topics):
        lines.append("  (rates and gaps from the header stamps, the data's own time, where the type has a header; "
                     "else from the receive times, which follow the wall clock; --json has both)")
    if summary.custom_data:
        lines.append("Custom data (provenance):")
        for key in sorted(summary.custom_data):
            value = " ".join(summary.custom_data[key].split())
            if not full_custom_data and len(value) > 100:
                value = f"{value[:97]}... ({len(value)} chars; --full shows all)"
            lines.append(f"  {key}: {value}")
    return "\n".join(lines)


def info_json(summary: BagSummary) -> dict[str, Any]:
    """JSON-ready dict of a :class:`BagSummary` (custom data values parsed when they are JSON)."""
    data = asdict(summary)
    data["duration_s"] = summary.duration_s
    custom = {}
    for key, value in summary.custom_data.items():
        try:
            custom[key] = json.loads(value) if value[:1] in "{[" else value
        except ValueError:
            custom[key] = value
    data["custom_data"] = custom
    return data
