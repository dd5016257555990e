"""Sample by sample: one contract sample -> one telemetry packet, and back (pure functions on bytes).

For a node that packetizes or depacketizes a live stream. Headers are spacepackets'
(``SpacePacketHeader``), the packet error control is its CRC (fastcrc's CRC-16/IBM-3740, the
CRC-16-CCITT that spacepackets uses for PUS packets), the time field :mod:`.cuc`. The bulk codecs
(:mod:`.bulk_encode`, :mod:`.bulk_decode`) give byte-identical packets (a test checks it).
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass

import numpy as np
from fastcrc import crc16
from spacepackets.ccsds.spacepacket import PacketId, PacketSeqCtrl, PacketType, SequenceFlags, SpacePacketHeader

from taiji2_runtime.packets.cuc import CucError, cuc_pack, cuc_unpack_ns
from taiji2_runtime.packets.definition import (
    CRC_OCTETS,
    IDLE_APID,
    PRIMARY_HEADER_OCTETS,
    SECONDARY_HEADER_OCTETS,
    STREAM_BY_APID,
    StreamDefinition,
)

__all__ = ["SEQ_MODULO", "PacketError", "TelemetrySample", "decode_packet", "encode_packet", "packet_crc"]

SEQ_MODULO = 1 << 14


class PacketError(ValueError):
    """A packet that cannot be decoded; ``kind`` names the defect (``truncated``, ``crc_error``,
    ``unknown_apid``, ``idle``, ``wrong_length``, ``bad_time_field``, ``not_telemetry``, ``bad_header``)."""

    def __init__(self, kind: str, detail: str) -> None:
        self.kind = kind
        super().__init__(f"{kind}: {detail}")


@dataclass(frozen=True)
class TelemetrySample:
    """One decoded telemetry packet.

    Attributes
    ----------
    stream : StreamDefinition
    seq_count : int
        14-bit sequence count.
    onboard_ns : int
        Onboard (CUC) time [ns since the onboard epoch].
    values : numpy.ndarray
        User-data fields (float64) in the order of ``stream.fields``.
    """

    stream: StreamDefinition
    seq_count: int
    onboard_ns: int
    values: np.ndarray


def packet_crc(octets: bytes) -> int:
    """CRC-16-CCITT (poly 0x1021, init 0xFFFF) of ``octets``."""
    return crc16.ibm_3740(bytes(octets))


def encode_packet(stream: StreamDefinition, seq_count: int, onboard_ns: int, values: np.ndarray) -> bytes:
    """The telemetry packet of one sample.

    Parameters
    ----------
    stream : StreamDefinition
        Which stream (APID and fields).
    seq_count : int
        The APID's sequence count (taken modulo 2**14).
    onboard_ns : int
        Onboard time [ns since the onboard epoch] (see :class:`.time_correlation.TimeCorrelation`).
    values : array_like
        ``len(stream.fields)`` values in the contract's units.
    """
    # Python floats packed by struct: one sample's values without numpy's per-call cost (the same octets
    # as a big-endian float64 array)
    values = [float(v) for v in (values.reshape(-1) if isinstance(values, np.ndarray) else values)]
    if len(values) != len(stream.fields):
        raise ValueError(f"{stream.name}: {len(stream.fields)} values expected, got {len(values)}")
    header = SpacePacketHeader(PacketType.TM, stream.apid, seq_count % SEQ_MODULO, stream.data_length,
                               sec_header_flag=True, seq_flags=SequenceFlags.UNSEGMENTED)
    body = header.pack() + cuc_pack(int(onboard_ns)) + struct.pack(f">{len(values)}d", *values)
    return bytes(body) + struct.pack(">H", packet_crc(body))


def decode_packet(packet: bytes) -> TelemetrySample:
    """Decode one telemetry packet (exactly one packet's octets).

    Raises
    ------
    PacketError
        With ``kind`` naming the defect.
    """
    packet = bytes(packet)
    if len(packet) < PRIMARY_HEADER_OCTETS:
        raise PacketError("truncated", f"{len(packet)} octets, shorter than a primary header")
    # the primary header's three words, each decoded by spacepackets once per distinct value (a receiver
    # decodes ~10^6 packets a day; building a SpacePacketHeader for each was a tenth of its CPU)
    word_id, word_seq, length_field = _HEADER_WORDS.unpack_from(packet)
    packet_id, seq_count = _packet_id(word_id), _seq_ctrl(word_seq).seq_count
    apid, packet_len = packet_id.apid, length_field + PRIMARY_HEADER_OCTETS + 1
    if packet_len > len(packet):
        raise PacketError("truncated", f"APID 0x{apid:03X}: {len(packet)} of {packet_len} octets")
    if apid == IDLE_APID:
        raise PacketError("idle", "idle packet (APID 0x7FF)")
    packet = packet[:packet_len]
    if packet_crc(packet) != 0:
        raise PacketError("crc_error", f"APID 0x{apid:03X} sequence count {seq_count}")
    if packet_id.ptype != PacketType.TM:
        raise PacketError("not_telemetry", f"telecommand APID 0x{apid:03X}")
    stream = STREAM_BY_APID.get(apid)
    if stream is None:
        raise PacketError("unknown_apid", f"APID 0x{apid:03X}")
    if packet_len != stream.packet_octets:
        raise PacketError("wrong_length", f"{stream.name}: {packet_len} octets, {stream.packet_octets} defined")
    start = PRIMARY_HEADER_OCTETS
    try:
        onboard_ns = cuc_unpack_ns(packet[start:start + SECONDARY_HEADER_OCTETS])
    except CucError as exc:
        raise PacketError("bad_time_field", str(exc)) from None
    data = packet[start + SECONDARY_HEADER_OCTETS:len(packet) - CRC_OCTETS]
    return TelemetrySample(stream, seq_count, onboard_ns, np.frombuffer(data, dtype=">f8").astype(np.float64))


_HEADER_WORDS = struct.Struct(">HHH")  # packet identification, sequence control, data length - 1


@functools.cache  # a few values: one per APID and packet type
def _packet_id(word: int) -> PacketId:
    return PacketId.from_raw(word)


@functools.lru_cache(maxsize=1 << 16)  # at most every value of the 16-bit word
def _seq_ctrl(word: int) -> PacketSeqCtrl:
    return PacketSeqCtrl.from_raw(word)
