"""CCSDS TC Transfer Frames (CCSDS 232.0-B-4): the unit the uplink carries and SDLS protects (:mod:`.sdls`).

A frame is its 5-octet primary header, the frame data field, and the 2-octet frame error control field
(FECF, CRC-16-CCITT of everything before it; optional in the standard, always present here)::

    octet 0-1  version (2 bits, 00) | bypass flag | control command flag | spare (2 bits) | spacecraft id (10)
    octet 2-3  virtual channel id (6 bits) | frame length (10 bits: total octets - 1)
    octet 4    frame sequence number (8 bits)

Frames are Type-BD (bypass flag 1, control command flag 0): there is no COP-1 (no FARM retransmission),
so the frame sequence number is informative. No segment header (no MAP service): one frame carries one
whole telecommand packet. Frames are at most :data:`MAX_FRAME_OCTETS` (1024, what a 10-bit length allows).
Pure bytes in and out; no middleware.
"""

from __future__ import annotations

from dataclasses import dataclass

from fastcrc import crc16

__all__ = ["FECF_OCTETS", "HEADER_OCTETS", "MAX_FRAME_OCTETS", "SPACECRAFT_ID", "TC_VCID", "FrameError",
           "TcFrameHeader", "decode_frame", "encode_frame", "frame_crc", "split_frames"]

HEADER_OCTETS = 5
FECF_OCTETS = 2
#: the longest TC transfer frame (the 10-bit frame length field)
MAX_FRAME_OCTETS = 1024
#: the spacecraft id in every frame (assumed: SANA assigns a mission's; 10 bits)
SPACECRAFT_ID = 0x2A2
#: the virtual channel of the telecommands
TC_VCID = 0


class FrameError(ValueError):
    """A TC transfer frame that cannot be read: ``kind`` is ``truncated`` (fewer octets than the header or its
    length field says), ``oversized`` (more octets than its length field says, or longer than allowed) or
    ``bad_fecf`` (its CRC does not match); ``detail`` says more."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail


@dataclass(frozen=True)
class TcFrameHeader:
    """The primary header's fields; ``frame_octets`` is the whole frame's length (header to FECF)."""

    spacecraft_id: int
    virtual_channel_id: int
    frame_octets: int
    sequence: int
    bypass: bool = True
    control_command: bool = False
    version: int = 0

    def pack(self) -> bytes:
        if not HEADER_OCTETS + FECF_OCTETS <= self.frame_octets <= MAX_FRAME_OCTETS:
            raise ValueError(f"TC frame of {self.frame_octets} octets: {HEADER_OCTETS + FECF_OCTETS}.."
                             f"{MAX_FRAME_OCTETS}")
        if not (0 <= self.spacecraft_id < 1024 and 0 <= self.virtual_channel_id < 64 and 0 <= self.version < 4):
            raise ValueError(f"TC frame header out of range: {self}")
        first = (self.version << 14) | (self.bypass << 13) | (self.control_command << 12) | self.spacecraft_id
        second = (self.virtual_channel_id << 10) | (self.frame_octets - 1)
        return bytes([first >> 8, first & 0xFF, second >> 8, second & 0xFF, self.sequence & 0xFF])

    @classmethod
    def unpack(cls, octets: bytes) -> TcFrameHeader:
        """The header of ``octets`` (at least :data:`HEADER_OCTETS`; FrameError ``truncated`` otherwise)."""
        if len(octets) < HEADER_OCTETS:
            raise FrameError("truncated", f"{len(octets)} octets, shorter than a TC frame header")
        first = (octets[0] << 8) | octets[1]
        second = (octets[2] << 8) | octets[3]
        return cls(spacecraft_id=first & 0x3FF, virtual_channel_id=second >> 10, frame_octets=(second & 0x3FF) + 1,
                   sequence=octets[4], bypass=bool(first & 0x2000), control_command=bool(first & 0x1000),
                   version=first >> 14)


def frame_crc(octets: bytes) -> int:
    """The FECF of ``octets``: CRC-16-CCITT (poly 0x1021, init 0xFFFF), as the packets' CRC."""
    return crc16.ibm_3740(bytes(octets))


def encode_frame(data_field: bytes, sequence: int, *, spacecraft_id: int = SPACECRAFT_ID,
                 virtual_channel_id: int = TC_VCID) -> bytes:
    """The Type-BD frame of ``data_field``: header + data field + FECF (ValueError if over the maximum)."""
    header = TcFrameHeader(spacecraft_id, virtual_channel_id, HEADER_OCTETS + len(data_field) + FECF_OCTETS,
                           sequence & 0xFF)
    body = header.pack() + bytes(data_field)
    return body + frame_crc(body).to_bytes(2, "big")


def decode_frame(frame: bytes, max_octets: int = MAX_FRAME_OCTETS) -> tuple[TcFrameHeader, bytes]:
    """The header and the frame data field of one whole frame (its FECF checked and removed).

    Raises
    ------
    FrameError
        ``truncated``, ``oversized`` (also a length field over ``max_octets``) or ``bad_fecf``.
    """
    frame = bytes(frame)
    header = TcFrameHeader.unpack(frame)
    if header.frame_octets > max_octets:
        raise FrameError("oversized", f"length field {header.frame_octets} octets, more than {max_octets}")
    if len(frame) < header.frame_octets:
        raise FrameError("truncated", f"{len(frame)} of {header.frame_octets} octets")
    if len(frame) > header.frame_octets:
        raise FrameError("oversized", f"{len(frame)} octets, its length field says {header.frame_octets}")
    if header.frame_octets < HEADER_OCTETS + FECF_OCTETS:
        raise FrameError("truncated", f"length field {header.frame_octets} octets: no room for the FECF")
    if frame_crc(frame[:-FECF_OCTETS]) != int.from_bytes(frame[-FECF_OCTETS:], "big"):
        raise FrameError("bad_fecf", "frame error control field does not match")
    return header, frame[HEADER_OCTETS:-FECF_OCTETS]


def split_frames(octets: bytes) -> list[bytes]:
    """The frames of back-to-back ``octets``, each delimited by its length field (nothing else is checked).

    Raises
    ------
    FrameError
        ``truncated`` if the octets do not end on a frame boundary.
    """
    octets = bytes(octets)
    out = []
    pos = 0
    while pos < len(octets):
        if len(octets) - pos < HEADER_OCTETS:
            raise FrameError("truncated", f"{len(octets) - pos} trailing octets, not a frame")
        end = pos + (((octets[pos + 2] & 0x03) << 8) | octets[pos + 3]) + 1
        if end > len(octets):
            raise FrameError("truncated", "the last frame is cut short")
        out.append(octets[pos:end])
        pos = end
    return out
