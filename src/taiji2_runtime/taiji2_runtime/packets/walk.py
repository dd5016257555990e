"""Find the packets of a byte stream: one pass over the primary headers, CRC checked per packet.

The walk follows each packet's data length field. Where a packet fails its CRC, its length field
cannot be trusted either: the walk resynchronises at the nearest offset where a sound packet starts
(a plausible primary header, version 0 and unsegmented, whose packet passes its CRC; inside a
packet that happens by chance once in 65,536 plausible headers, so the packet after it must be
sound too), and counts the damaged packets in
between: walked with the defined length of their APID (or their length field for other APIDs), each
one a ``crc_error`` of the APID as read, and what is left unreadable one ``corrupt_header``. A
packet that runs past the end of the stream is the truncated final packet. Idle packets (APID
0x7FF) are skipped without a CRC (CCSDS idle data are fill); where the walk resynchronises, a chain of
idle packets counts as sound when a sound packet or the end of the stream follows it. The work is linear
in the stream's length (at most one CRC per offset), whatever the octets.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from fastcrc import crc16

from taiji2_runtime.packets.definition import STREAM_BY_APID, TC_APID

__all__ = ["Walk", "starts_with_sound_packet", "walk_packets"]

_MIN_OCTETS = 7
_DEFINED = {apid: stream.packet_octets for apid, stream in STREAM_BY_APID.items()}
_DEFINED[TC_APID] = 6 + 5 + 56 + 2


@dataclass
class Walk:
    """What :func:`walk_packets` found.

    Attributes
    ----------
    starts, ends : numpy.ndarray
        (n,) int64 offsets of the packets that passed their CRC (file order).
    crc_error : collections.Counter
        Packets dropped for a failed CRC, per APID as read from their (possibly damaged) header.
    corrupt_header : int
        Resynchronisations after an implausible primary header (APID unreadable).
    skipped_octets : int
        Octets skipped while resynchronising.
    idle, idle_octets : int
        Idle packets (APID 0x7FF) and their octets.
    truncated : collections.Counter
        Final packets cut short, per APID as read (-1: not even a primary header).
    """

    starts: np.ndarray
    ends: np.ndarray
    crc_error: Counter = field(default_factory=Counter)
    corrupt_header: int = 0
    skipped_octets: int = 0
    idle: int = 0
    idle_octets: int = 0
    truncated: Counter = field(default_factory=Counter)


def _plausible(buf: bytes, pos: int) -> bool:
    return (buf[pos] & 0xE0) == 0 and (buf[pos + 2] & 0xC0) == 0xC0


def _sound(buf: bytes, pos: int, memo: dict[int, bool]) -> bool:
    """A plausible header at ``pos`` whose packet fits and passes its CRC; an idle one (no CRC to check it by):
    followed by a sound one or by the end of the stream. A chain of idle packets is followed once, without
    recursion, and its verdict kept in ``memo`` for every packet of the chain (a resynchronisation meets each
    of them: without it the work would grow with the square of the chain's length)."""
    n = len(buf)
    chain: list[int] = []
    while True:
        if pos in memo:
            verdict = memo[pos]
            break
        if n - pos < _MIN_OCTETS or not _plausible(buf, pos):
            verdict = False
            break
        end = pos + ((buf[pos + 4] << 8) | buf[pos + 5]) + 7
        if end > n:
            verdict = False
            break
        if (buf[pos] & 7) == 7 and buf[pos + 1] == 0xFF:
            chain.append(pos)
            if end == n:  # fill up to the end of the stream
                verdict = True
                break
            pos = end
            continue
        verdict = crc16.ibm_3740(buf[pos:end]) == 0
        memo[pos] = verdict
        break
    for p in chain:
        memo[p] = verdict
    return verdict


def starts_with_sound_packet(buf: bytes) -> bool:
    """Whether ``buf`` starts with a sound packet (an idle one: followed by a sound one or the end of ``buf``)."""
    return _sound(bytes(buf), 0, {})


def _resync(buf: bytes, pos: int, memo: dict[int, bool]) -> int:
    """The next offset >= pos where a sound packet starts that the end of the stream or another
    sound packet follows (two CRCs: a false start inside data is then a 1 in 2**32 chance), or len(buf)."""
    n = len(buf)
    for q in range(pos, n - _MIN_OCTETS + 1):
        if (buf[q] & 0xE0) == 0 and (buf[q + 2] & 0xC0) == 0xC0 and _sound(buf, q, memo):
            end = q + ((buf[q + 4] << 8) | buf[q + 5]) + 7
            if end == n or _sound(buf, end, memo):
                return q
    return n


def _count_damaged(buf: bytes, pos: int, stop: int, result: Walk, found: list[tuple[int, int]]) -> None:
    """Count the damaged packets of ``buf[pos:stop]``; sound ones met on the way go to ``found``."""
    n = len(buf)
    q = pos
    while q < stop:
        if stop - q >= _MIN_OCTETS and _plausible(buf, q):
            apid = ((buf[q] & 7) << 8) | buf[q + 1]
            size = _DEFINED.get(apid, ((buf[q + 4] << 8) | buf[q + 5]) + 7)
            if q + size <= stop:
                if crc16.ibm_3740(buf[q:q + size]) == 0:  # sound, but what follows it is damaged
                    found.append((q, q + size))
                else:
                    result.crc_error[apid] += 1
                q += size
                continue
            if stop == n:
                result.truncated[apid] += 1
                return
        elif stop == n and stop - q < _MIN_OCTETS:
            result.truncated[((buf[q] & 7) << 8 | buf[q + 1]) if stop - q >= 2 else -1] += 1
            return
        result.corrupt_header += 1
        return


def walk_packets(buf: bytes) -> Walk:
    """Locate the sound packets of ``buf`` and count what is not (see the module docstring)."""
    buf = bytes(buf)
    n = len(buf)
    crc = crc16.ibm_3740
    starts: list[int] = []
    ends: list[int] = []
    result = Walk(np.empty(0, np.int64), np.empty(0, np.int64))
    memo: dict[int, bool] = {}  # soundness per offset, shared by the resynchronisations of this walk
    pos = 0
    while pos < n:
        if n - pos >= _MIN_OCTETS:
            b0 = buf[pos]
            end = pos + ((buf[pos + 4] << 8) | buf[pos + 5]) + 7
            if (b0 & 0xE0) == 0 and (buf[pos + 2] & 0xC0) == 0xC0 and end <= n:
                if (b0 & 7) == 7 and buf[pos + 1] == 0xFF:
                    result.idle += 1
                    result.idle_octets += end - pos
                    pos = end
                    continue
                if crc(buf[pos:end]) == 0:
                    starts.append(pos)
                    ends.append(end)
                    pos = end
                    continue
        nxt = _resync(buf, pos + 1, memo)
        found: list[tuple[int, int]] = []
        _count_damaged(buf, pos, nxt, result, found)
        for start, stop in found:
            starts.append(start)
            ends.append(stop)
        result.skipped_octets += nxt - pos
        pos = nxt
    result.starts = np.asarray(starts, dtype=np.int64)
    result.ends = np.asarray(ends, dtype=np.int64)
    return result
