"""Contract bags <-> packet streams: what ``taiji2 bag export --ccsds`` and ``taiji2 bag import`` do.

Export reads the four raw topics of a contract bag (bulk read and decode, messages in bag order;
messages of another type or undecodable ones are left out and counted) and writes one packet per
message: the header stamp becomes the CUC onboard time through the time correlation, the
command topic becomes the executed-torque stream (and, on request, torque telecommands). Import
writes a contract bag with the project's writer (:class:`~taiji2_runtime.bag.writer.BagWriter`):
one message per kept sample, header stamp = contract time, bag (receive) stamp = the same.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from taiji2_model.contract import RAW_FRAME_IDS, RAW_TOPICS
from taiji2_runtime.packets.bulk_decode import DecodedPackets, StreamData
from taiji2_runtime.packets.definition import STREAMS

__all__ = ["read_bag_streams", "write_bag"]

_NS = 1_000_000_000


def read_bag_streams(path: str | Path) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, Counter]]:
    """``{stream: (stamp_ns, values)}`` of the raw topics of a contract bag, and what was left out per topic.

    Raises
    ------
    BagError
        One line naming the bag and the problem (unreadable, not a bag, no raw topic).
    """
    from taiji2_runtime.bag.bulk_decode import decode_messages
    from taiji2_runtime.bag.bulk_read import read_raw_messages
    from taiji2_runtime.bag.errors import BagError
    from taiji2_runtime.bag.reading import open_reader
    from taiji2_runtime.typestore import contract_typestore

    store = contract_typestore()
    with open_reader(path) as reader:
        raw = read_raw_messages(reader, topics=set(RAW_TOPICS))
    streams: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    left_out: dict[str, Counter] = {}
    for stream in STREAMS:
        parts = [m for (topic, msgtype), m in raw.items() if topic == stream.topic and msgtype == RAW_TOPICS[topic]]
        other = sum(m.count for (topic, msgtype), m in raw.items() if topic == stream.topic
                    and msgtype != RAW_TOPICS[topic])
        counts = left_out.setdefault(stream.topic, Counter())
        if other:
            counts["wrong_type"] += other
        if not parts:
            continue
        log_time = np.concatenate([p.log_time_ns for p in parts])
        decoded = decode_messages(store, RAW_TOPICS[stream.topic], [piece for p in parts for piece in p.pieces])
        order = np.argsort(log_time, kind="stable")
        keep = decoded.valid[order]
        if not keep.all():
            counts["undecodable"] += int((~keep).sum())
        rows = order[keep]
        c = decoded.columns
        stamp = c["header.stamp.sec"].astype(np.int64) * _NS + c["header.stamp.nanosec"].astype(np.int64)
        values = np.column_stack([np.asarray(c[f], dtype=np.float64) if f in c else
                                  np.asarray(c[f.split("[")[0]], dtype=np.float64)[:, int(f[f.index("[") + 1:-1])]
                                  for f in stream.fields])
        streams[stream.name] = (stamp[rows], values[rows])
    if not streams:
        raise BagError(Path(path), "no raw-contract topic to export")
    return streams, left_out


def _columns(data: StreamData) -> dict[str, object]:
    stamp = data.stamp_ns
    columns: dict[str, object] = {"header.stamp.sec": (stamp // _NS).astype(np.int32),
                                  "header.stamp.nanosec": (stamp % _NS).astype(np.uint32),
                                  "header.frame_id": RAW_FRAME_IDS[data.stream.topic]}
    cov = []
    for k, name in enumerate(data.stream.fields):
        if name.startswith("attitude_covariance["):
            cov.append(data.values[:, k])
        else:
            columns[name] = data.values[:, k]
    if cov:
        columns["attitude_covariance"] = np.column_stack(cov)
    if data.stream.name in ("grs1", "grs2"):
        columns["grs_id"] = int(data.stream.name[-1])
    return columns


def write_bag(path: str | Path, decoded: DecodedPackets, *, storage: str = "mcap",
              custom_data: dict[str, str] | None = None) -> dict[str, int]:
    """Write the kept samples as a contract bag; returns the messages written per topic.

    The command topic comes from the executed-torque stream, or from the torque telecommands
    when the input holds no executed-torque packets.

    Raises
    ------
    BagError
        If the bag cannot be created (exists, unwritable).
    """
    from taiji2_runtime.bag.bulk_decode import encode_messages
    from taiji2_runtime.bag.writer import BagWriter
    from taiji2_runtime.typestore import contract_typestore

    store = contract_typestore()
    streams = dict(decoded.streams)
    if "executed_torque" not in streams and decoded.telecommands is not None:
        streams["executed_torque"] = decoded.telecommands
    writer = BagWriter(path, store, storage=storage, segment_period_s=float("inf"), journal_period_s=3600.0)
    written: dict[str, int] = {}
    try:
        for key, value in (custom_data or {}).items():
            writer.set_custom_data(key, value)
        handles = {s.name: writer.add_topic(s.topic, RAW_TOPICS[s.topic]) for s in STREAMS if s.name in streams}
        messages = []
        for stream in STREAMS:
            if stream.name not in streams:
                continue
            data = streams[stream.name]
            encoded = encode_messages(store, RAW_TOPICS[stream.topic], _columns(data), len(data))
            written[stream.topic] = len(encoded)
            messages.extend(zip(data.stamp_ns.tolist(), [handles[stream.name]] * len(encoded), encoded,
                                strict=True))
        messages.sort(key=lambda m: m[0])
        for stamp, handle, blob in messages:
            writer.write(handle, stamp, blob)
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return written
