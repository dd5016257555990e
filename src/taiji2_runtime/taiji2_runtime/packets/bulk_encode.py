"""Whole records -> one packet stream (vectorised; byte-identical to :func:`.packetize.encode_packet`).

Each APID's packets are built as rows of a numpy structured array: the primary headers come from
spacepackets (``SpacePacketHeader.pack``, once per distinct sequence count of the APID, at most
2**14), the CUC fields from :mod:`.cuc`, the user data as big-endian binary64 and the CRC from
fastcrc per packet. Packets are interleaved in onboard-time order (ties: star tracker, GRS1, GRS2,
executed torque), as a spacecraft's downlink interleaves its sources.
"""

from __future__ import annotations

import numpy as np
from fastcrc import crc16
from spacepackets.ccsds.spacepacket import PacketType, SequenceFlags, SpacePacketHeader

from taiji2_runtime.packets.cuc import cuc_encode_ns
from taiji2_runtime.packets.definition import CUC_PFIELD, STREAMS, StreamDefinition
from taiji2_runtime.packets.packetize import SEQ_MODULO
from taiji2_runtime.packets.telecommand import TC_PACKET_OCTETS, encode_torque_tc
from taiji2_runtime.packets.time_correlation import TimeCorrelation

__all__ = ["encode_stream", "encode_streams", "encode_telecommands"]


def _headers(stream: StreamDefinition, count: int) -> np.ndarray:
    """(min(count, 2**14), 6) primary headers of sequence counts 0, 1, ... from spacepackets."""
    n = min(count, SEQ_MODULO)
    raw = b"".join(SpacePacketHeader(PacketType.TM, stream.apid, k, stream.data_length, sec_header_flag=True,
                                     seq_flags=SequenceFlags.UNSEGMENTED).pack() for k in range(n))
    return np.frombuffer(raw, dtype=np.uint8).reshape(n, 6)


def encode_stream(stream: StreamDefinition, onboard_ns: np.ndarray, values: np.ndarray,
                  first_seq_count: int = 0) -> np.ndarray:
    """(n, packet_octets) uint8: the packets of n samples of one stream, sequence counts from ``first_seq_count``."""
    onboard_ns = np.asarray(onboard_ns, dtype=np.int64)
    values = np.asarray(values, dtype=np.float64).reshape(onboard_ns.shape[0], len(stream.fields))
    n = onboard_ns.shape[0]
    rows = np.zeros(n, dtype=stream.dtype)
    seq = (first_seq_count + np.arange(n)) % SEQ_MODULO
    rows["primary"] = _headers(stream, int(seq.max()) + 1 if n else 0)[seq] if n else 0
    coarse, fine = cuc_encode_ns(onboard_ns)
    rows["pfield"] = CUC_PFIELD
    rows["coarse"] = coarse
    rows["fine"] = np.stack([(fine >> 16) & 0xFF, (fine >> 8) & 0xFF, fine & 0xFF], axis=1)
    rows["values"] = values
    octets = rows.view(np.uint8).reshape(n, stream.packet_octets)
    size = stream.packet_octets
    flat = octets.tobytes()
    crc = crc16.ibm_3740
    rows["crc"] = np.fromiter((crc(flat[k:k + size - 2]) for k in range(0, n * size, size)), dtype=np.uint16, count=n)
    return octets


def encode_telecommands(execute_onboard_ns: np.ndarray, torque_n_m: np.ndarray, force_n: np.ndarray,
                        first_seq_count: int = 0) -> np.ndarray:
    """(n, 69) uint8: one torque PUS TC per command (spacepackets ``PusTc``, packet by packet)."""
    n = len(execute_onboard_ns)
    raw = b"".join(encode_torque_tc(first_seq_count + k, int(execute_onboard_ns[k]), torque_n_m[k], force_n[k])
                   for k in range(n))
    return np.frombuffer(raw, dtype=np.uint8).reshape(n, TC_PACKET_OCTETS)


def encode_streams(streams: dict[str, tuple[np.ndarray, np.ndarray]],
                   correlation: TimeCorrelation | None = None, *, telecommands: bool = False) -> bytes:
    """One interleaved packet stream of whole records.

    Parameters
    ----------
    streams : dict
        ``{stream name: (contract stamps [ns] (n,), values (n, fields))}`` for any of ``star_tracker``,
        ``grs1``, ``grs2``, ``executed_torque`` (see :data:`.definition.STREAMS`).
    correlation : TimeCorrelation, optional
        Contract -> onboard time (identity by default).
    telecommands : bool
        Also write each ``executed_torque`` sample as a torque PUS TC (APID 0x140), just before it.

    Returns
    -------
    bytes
        The packets in onboard-time order.

    Raises
    ------
    ValueError
        If a stream is unknown or a time falls outside the CUC range.
    """
    correlation = correlation or TimeCorrelation()
    by_name = {s.name: s for s in STREAMS}
    unknown = sorted(set(streams) - set(by_name))
    if unknown:
        raise ValueError(f"unknown packet streams {', '.join(unknown)}")
    blocks: list[np.ndarray] = []
    times: list[np.ndarray] = []
    ranks: list[np.ndarray] = []
    for rank, stream in enumerate(STREAMS):
        if stream.name not in streams:
            continue
        stamp_ns, values = streams[stream.name]
        onboard = correlation.to_onboard_ns(stamp_ns)
        if telecommands and stream.name == "executed_torque":
            vals = np.asarray(values, dtype=np.float64)
            blocks.append(encode_telecommands(onboard, vals[:, :3], vals[:, 3:]))
            times.append(onboard)
            ranks.append(np.full(onboard.shape[0], -1))
        blocks.append(encode_stream(stream, onboard, values))
        times.append(onboard)
        ranks.append(np.full(onboard.shape[0], rank))
    if not blocks:
        return b""
    order = np.lexsort((np.concatenate(ranks), np.concatenate(times)))
    pieces: list[bytes] = []
    for block in blocks:
        flat, size = block.tobytes(), block.shape[1]
        pieces.extend(flat[k:k + size] for k in range(0, len(flat), size))
    return b"".join([pieces[k] for k in order.tolist()])
