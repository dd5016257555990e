"""Load the raw streams of a CCSDS packet file or directory into the arrays of :func:`load_raw_bag`.

The packets are decoded by :mod:`taiji2_runtime.packets` (definition in docs/interfaces.md):
per APID, sound packets only, each sequence count once, in sequence (time) order, onboard time
mapped to contract time by the time correlation. What was left out is counted per topic in the
:class:`TopicReport` (``dropped``: ``crc_error``, ``truncated``, ``wrong_length``,
``bad_time_field``, ``duplicate_packet``; ``flagged``: ``out_of_order_packet``, kept and put in
order) and per APID in ``RawExperiment.packets``; sequence counts never received soundly are
noted and become ``missing`` samples where the streams are put on the grid.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from taiji2_estimator_pkg.io.raw_bag import (
    CommandData,
    GrsData,
    RawBagError,
    RawExperiment,
    StarTrackerData,
    TopicReport,
    _stamp_flags,
)
from taiji2_model.contract import COMMAND_TOPIC, GRS_IDS, RAW_FRAME_IDS, RAW_TOPICS, STAR_TRACKER_TOPIC

__all__ = ["load_raw_archive", "load_raw_packets", "raw_from_decoded", "time_correlation_from"]

_NS = 1_000_000_000
_DROPPED = {"crc_error": "crc_error", "truncated": "truncated", "wrong_length": "wrong_length",
            "bad_time_field": "bad_time_field", "duplicate": "duplicate_packet"}


def time_correlation_from(correlation_file: str | Path | None = None) -> Any:
    """The time correlation of a ``--time-correlation`` file, or None (then the packet directory's
    ``time_correlation.yaml``, else the identity)."""
    from taiji2_runtime.packets.time_correlation import load_time_correlation

    return load_time_correlation(correlation_file) if correlation_file else None


def load_raw_packets(path: str | Path, *, required: Iterable[str] = tuple(RAW_TOPICS),
                     correlation: Any = None) -> RawExperiment:
    """Load a packet file or directory as a :class:`RawExperiment` (``storage == "ccsds"``).

    Parameters
    ----------
    path : str or pathlib.Path
        A packet file, or a directory of them (detected by content).
    required : iterable of str
        Raw topics that must have samples (default all four).
    correlation : taiji2_runtime.packets.time_correlation.TimeCorrelation, optional
        Onboard -> contract time; default the directory's ``time_correlation.yaml``, else identity.

    Raises
    ------
    RawBagError
        One line naming the path and the problem.
    """
    from taiji2_runtime.packets.files import PacketFileError, read_packets

    path = Path(path)
    try:
        decoded = read_packets(path, correlation)
    except PacketFileError as exc:
        raise RawBagError(exc.path, exc.problem) from None
    return raw_from_decoded(decoded, path, required=required)


def load_raw_archive(url: str, *, required: Iterable[str] = tuple(RAW_TOPICS),
                     correlation: Any = None) -> RawExperiment:
    """Load the packets a Yamcs instance archived (``yamcs://HOST:PORT/INSTANCE[?start=...&stop=...]``),
    decoded by the project's own decoder exactly as a packet file (Yamcs's own decoding is not used: the
    calibration reads the raw octets). ``correlation`` default: the identity.

    Raises
    ------
    RawBagError
        One line naming the address and the problem (unreachable, no such instance, nothing sound).
    """
    from taiji2_ground_pkg.mcs.errors import GroundError
    from taiji2_ground_pkg.mcs.yamcs_api import archived_packets
    from taiji2_runtime.packets.bulk_decode import decode_packet_buffers
    from taiji2_runtime.packets.time_correlation import TimeCorrelation

    try:
        packets = archived_packets(url)
    except GroundError as exc:
        raise RawBagError(url, str(exc).removeprefix(f"{url}: ")) from None
    if not packets:
        raise RawBagError(url, "the archive holds no packets (in that time range)")
    decoded = decode_packet_buffers([(url, b"".join(packets))], correlation or TimeCorrelation())
    return raw_from_decoded(decoded, url, required=required)


def raw_from_decoded(decoded: Any, path: str | Path, *, required: Iterable[str] = tuple(RAW_TOPICS)) -> RawExperiment:
    """The :class:`RawExperiment` of decoded packets (``storage == "ccsds"``); ``path`` names their source."""
    required = list(required)
    streams = dict(decoded.streams)
    if "executed_torque" not in streams and decoded.telecommands is not None:
        streams["executed_torque"] = decoded.telecommands
    by_topic = {data.stream.topic: data for data in streams.values()}
    reports: dict[str, TopicReport] = {}
    for data in streams.values():
        topic = data.stream.topic
        counts = decoded.report.per_apid.get(data.stream.apid, {})
        report = TopicReport(topic, RAW_TOPICS[topic], found_types=[f"ccsds APID 0x{data.stream.apid:03X}"])
        for key, reason in _DROPPED.items():
            if counts.get(key):
                report.dropped[reason] += int(counts[key])
        if counts.get("out_of_order"):
            report.flagged["out_of_order_packet"] += int(counts["out_of_order"])
        if counts.get("sequence_gap"):
            report.notes.append(f"sequence_gap {int(counts['sequence_gap'])} (samples missing)")
        report.messages = int(counts.get("packets", 0)) + sum(int(counts.get(k, 0)) for k in
                                                              ("crc_error", "truncated"))
        report.loaded = len(data)
        _stamp_flags(data.stamp_ns, report)
        reports[topic] = report
    for topic, msgtype in RAW_TOPICS.items():
        reports.setdefault(topic, TopicReport(topic, msgtype))
    problems = [f"no packets of raw topic {t} (APID of {t} absent or nothing sound)" for t in required
                if t not in by_topic or len(by_topic[t]) == 0]
    if problems:
        raise RawBagError(path, "; ".join(problems) + " [" + "; ".join(decoded.report.lines()[1:]).strip() + "]")

    def star() -> StarTrackerData | None:
        d = by_topic.get(STAR_TRACKER_TOPIC)
        if d is None:
            return None
        return StarTrackerData(d.stamp_ns, d.stamp_ns.copy(), d.stamp_ns / _NS, d.values[:, :4].copy(),
                               d.values[:, 4:].copy())

    def grs(topic: str) -> GrsData | None:
        d = by_topic.get(topic)
        if d is None:
            return None
        return GrsData(d.stamp_ns, d.stamp_ns.copy(), d.stamp_ns / _NS, d.values, GRS_IDS[topic], RAW_FRAME_IDS[topic])

    def commands() -> CommandData | None:
        d = by_topic.get(COMMAND_TOPIC)
        if d is None:
            return None
        return CommandData(d.stamp_ns, d.stamp_ns.copy(), d.stamp_ns / _NS, d.values[:, :3].copy(),
                           d.values[:, 3:].copy())

    grs_topics = list(GRS_IDS)
    return RawExperiment(path=path, storage="ccsds", star_tracker=star(), grs1=grs(grs_topics[0]),
                         grs2=grs(grs_topics[1]), commands=commands(), report=reports,
                         custom_data={"taiji2.packets.time_correlation": str(decoded.correlation.as_dict())},
                         packets=decoded.report)
