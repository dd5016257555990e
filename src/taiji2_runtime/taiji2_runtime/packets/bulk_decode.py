"""Packet streams -> per-stream arrays in contract time (vectorised), with every defect counted.

:func:`.walk.walk_packets` finds the sound packets of each buffer; their primary-header words are
decoded by spacepackets (``PacketId.from_raw`` / ``PacketSeqCtrl.from_raw``, once per distinct
16-bit word) and spread with numpy; each APID's packets are gathered into one structured array
(big-endian fields read as numpy views), their CUC times mapped to contract time, and ordered by
sequence count (:mod:`.sequence`). Torque telecommands are decoded by spacepackets' ``PusTc``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from spacepackets.ccsds.spacepacket import PacketId, PacketSeqCtrl, PacketType

from taiji2_runtime.packets.cuc import cuc_decode_ns
from taiji2_runtime.packets.definition import CUC_PFIELD, STREAM_BY_APID, STREAMS, TC_APID, StreamDefinition
from taiji2_runtime.packets.packetize import PacketError
from taiji2_runtime.packets.report import PacketReport
from taiji2_runtime.packets.sequence import order_by_sequence
from taiji2_runtime.packets.telecommand import decode_torque_tc
from taiji2_runtime.packets.time_correlation import TimeCorrelation
from taiji2_runtime.packets.walk import walk_packets

__all__ = ["DecodedPackets", "StreamData", "decode_packet_buffers"]


@dataclass(frozen=True)
class StreamData:
    """The kept samples of one stream, in sequence (time) order.

    Attributes
    ----------
    stream : StreamDefinition
    seq_count : numpy.ndarray
        (n,) 14-bit sequence counts.
    onboard_ns, stamp_ns : numpy.ndarray
        (n,) int64 onboard (CUC) and contract times [ns].
    values : numpy.ndarray
        (n, fields) float64 user data.
    """

    stream: StreamDefinition
    seq_count: np.ndarray
    onboard_ns: np.ndarray
    stamp_ns: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


@dataclass
class DecodedPackets:
    """Everything decoded from one packet file or directory.

    Attributes
    ----------
    streams : dict
        ``{stream name: StreamData}`` for the streams present.
    telecommands : StreamData or None
        Torque telecommands (``executed_torque`` fields, stamped with their execution time), in
        sequence order; None when the input holds none.
    report : PacketReport
    correlation : TimeCorrelation
    """

    streams: dict[str, StreamData]
    telecommands: StreamData | None
    report: PacketReport
    correlation: TimeCorrelation = field(default_factory=TimeCorrelation)


def _decode_words(words: np.ndarray, decode: object) -> dict[int, object]:
    return {int(w): decode(int(w)) for w in np.unique(words)}  # type: ignore[operator]


def _finish(stream: StreamDefinition, seq: np.ndarray, onboard: np.ndarray, values: np.ndarray,
            counts: object, correlation: TimeCorrelation) -> StreamData:
    order = order_by_sequence(seq, onboard)
    for key in ("duplicate", "out_of_order", "sequence_gap", "wraps"):
        if getattr(order, key):
            counts[key] += getattr(order, key)  # type: ignore[index]
    keep = order.keep
    counts["kept"] += int(keep.shape[0])  # type: ignore[index]
    onboard = onboard[keep]
    return StreamData(stream, seq[keep], onboard, correlation.to_contract_ns(onboard), values[keep])


def decode_packet_buffers(buffers: list[tuple[str, bytes]], correlation: TimeCorrelation | None = None,
                          *, telecommands: bool = True) -> DecodedPackets:
    """Decode packet streams (files read in order: their packets are taken as one stream per APID).

    Parameters
    ----------
    buffers : list of (str, bytes)
        ``(source name, octets)`` per file.
    correlation : TimeCorrelation, optional
        Onboard -> contract time (identity by default).
    telecommands : bool
        Decode the torque telecommands (otherwise they are only counted).
    """
    correlation = correlation or TimeCorrelation()
    report = PacketReport()
    parts: dict[int, list[np.ndarray]] = {}
    tc_packets: list[bytes] = []
    for name, buf in buffers:
        report.sources.append(name)
        report.octets += len(buf)
        walk = walk_packets(buf)
        for apid, n in walk.crc_error.items():
            report.apid(apid)["crc_error"] += n
        for apid, n in walk.truncated.items():
            report.apid(apid)["truncated"] += n
        report.idle += walk.idle
        report.corrupt_header += walk.corrupt_header
        report.skipped_octets += walk.skipped_octets
        if walk.starts.size == 0:
            continue
        octets = np.frombuffer(buf, dtype=np.uint8)
        s = walk.starts
        id_word = (octets[s].astype(np.int64) << 8) | octets[s + 1]
        ctrl_word = (octets[s + 2].astype(np.int64) << 8) | octets[s + 3]
        ids = _decode_words(id_word, PacketId.from_raw)
        ctrls = _decode_words(ctrl_word, PacketSeqCtrl.from_raw)
        apid_of = {w: p.apid for w, p in ids.items()}
        apid = np.vectorize(apid_of.__getitem__, otypes=[np.int64])(id_word) if ids else id_word
        tm_of = {w: p.ptype == PacketType.TM for w, p in ids.items()}
        tm = np.vectorize(tm_of.__getitem__, otypes=[bool])(id_word)
        seq_of = np.zeros(1 << 16, dtype=np.int64)
        for w, ctrl in ctrls.items():
            seq_of[w] = ctrl.seq_count
        seq = seq_of[ctrl_word]
        length = walk.ends - walk.starts
        for a in np.unique(apid).tolist():
            mine = apid == a
            counts = report.apid(a)
            counts["packets"] += int(mine.sum())
            stream = STREAM_BY_APID.get(a)
            if a == TC_APID and not tm[mine].any():
                tc_packets.extend(buf[p:e] for p, e in zip(s[mine].tolist(), walk.ends[mine].tolist(), strict=True))
                continue
            if stream is None or not tm[mine].all():
                report.unknown_apid[a] += int(mine.sum())
                del report.per_apid[a]
                continue
            right = mine & (length == stream.packet_octets)
            if (mine & ~right).any():
                counts["wrong_length"] += int((mine & ~right).sum())
            starts = s[right].tolist()
            size = stream.packet_octets
            rows = np.frombuffer(b"".join([buf[p:p + size] for p in starts]), dtype=stream.dtype)
            good = rows["pfield"] == CUC_PFIELD
            if not good.all():
                counts["bad_time_field"] += int((~good).sum())
            fine = rows["fine"].astype(np.int64)
            onboard = cuc_decode_ns(rows["coarse"], (fine[:, 0] << 16) | (fine[:, 1] << 8) | fine[:, 2])
            parts.setdefault(a, []).append(np.rec.fromarrays(
                [seq[right][good], onboard[good]], names="seq,onboard"))
            parts.setdefault(-a - 1, []).append(rows["values"][good].astype(np.float64))
    streams: dict[str, StreamData] = {}
    for stream in STREAMS:
        if stream.apid not in parts:
            continue
        meta = np.concatenate(parts[stream.apid])
        values = np.concatenate(parts[-stream.apid - 1])
        streams[stream.name] = _finish(stream, meta["seq"], meta["onboard"], values, report.apid(stream.apid),
                                       correlation)
    tcs = None
    if tc_packets and telecommands:
        counts = report.apid(TC_APID)
        seqs, times, vals = [], [], []
        for packet in tc_packets:
            try:
                tc = decode_torque_tc(packet)
            except PacketError as exc:  # another APID cannot be (the walk sorted them): another service
                counts["wrong_service" if exc.kind == "unknown_apid" else exc.kind] += 1
                continue
            seqs.append(tc.seq_count)
            times.append(tc.execute_onboard_ns)
            vals.append(np.concatenate([tc.torque_n_m, tc.force_n]))
        if seqs:
            tcs = _finish(STREAM_BY_APID[0x121], np.asarray(seqs), np.asarray(times, dtype=np.int64),
                          np.asarray(vals), counts, correlation)
    return DecodedPackets(streams, tcs, report, correlation)
