"""Summary of a bag (the ``taiji2 bag info`` engine): files, time span, topics, rates, gaps, provenance.

Rates and gaps come from the bag (receive) stamps of every message, read from the MCAP message
indexes or the sqlite3 timestamp column, without decoding any message.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from .bulk_read import read_raw_messages
from .reading import custom_data, open_reader, storage_identifier, storages_of

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
        (count - 1) / (last - first stamp) [Hz]; None with fewer than two messages.
    largest_gap_s : float or None
        Largest interval between consecutive bag stamps [s].
    largest_gap_at_s : float or None
        Where that gap starts, relative to the bag start [s].
    """

    topic: str
    msgtype: str
    count: int
    rate_hz: float | None
    largest_gap_s: float | None
    largest_gap_at_s: float | None


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
        topics.append(TopicSummary(topic, msgtype, messages.count, rate, gap, gap_at))
    return BagSummary(str(path), storage, files, sum(size for _, size in files), start, end,
                      sum(t.count for t in topics), topics, custom, distro)


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
        "Topics:",
    ]
    width = max([len(t.topic) for t in summary.topics] + [5])
    type_width = max([len(t.msgtype) for t in summary.topics] + [4])
    for t in summary.topics:
        rate = f"{t.rate_hz:10.3f} Hz" if t.rate_hz is not None else f"{'-':>10s} Hz"
        gap = (f"largest gap {t.largest_gap_s:.3f} s at +{t.largest_gap_at_s:.3f} s"
               if t.largest_gap_s is not None else "largest gap -")
        lines.append(f"  {t.topic:<{width}s}  {t.msgtype:<{type_width}s}  {t.count:8d} msgs  {rate}  {gap}")
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
