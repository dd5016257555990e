"""CCSDS Space Data Link Security (SDLS, CCSDS 355.0-B-2) on TC transfer frames, authentication only.

A secured frame (:mod:`.tc_frame`) is::

    primary header (5) | security header: SPI (2) + IV (12) | frame data (the telecommand packet) |
    security trailer: MAC (16) | FECF (2)

Each SPI has one of two SDLS services (its key table entry, :mod:`.sdls_keys`):

* ``authentication`` (the default): the MAC is the tag of AES-256-GCM (``cryptography``) with an empty
  plaintext and as additional authenticated data everything from the primary header to the end of the frame
  data: the data travel in the clear, the tag covers the headers and the data (GMAC; the authentication
  service of SDLS, with no bit masks: every header bit is covered);
* ``authenticated_encryption``: the frame data are AES-256-GCM encrypted and the tag's additional
  authenticated data is the primary and security header under SDLS's authentication bit mask (the virtual
  channel id and the SPI kept, every other bit zeroed: 19 octets), as Yamcs 5.12's
  ``SecurityAssociationAes256Gcm128`` makes frames on its ``UdpTcFrameLink`` (test/packets/test_sdls.py
  checks a frame Yamcs made). The zeroed header fields (spacecraft id, length, frame sequence number) are
  then not authenticated; the verifier checks them in the clear as for every frame.

The IV is a 96-bit big-endian counter per SPI that also serves as the anti-replay sequence number: the
ground counts up from 1; onboard a frame is accepted only if its counter is above the last accepted one of
its SPI and at most :data:`DEFAULT_REPLAY_WINDOW` above it (a window for frames lost on the uplink, e.g. a
whole pass's).

:class:`FrameVerifier` checks, in this order, and refuses with a reason (:data:`REFUSAL_REASONS`):
``truncated``/``oversized`` (octets against the length field and the maximum), ``bad_fecf``, ``bad_header``
(version, spacecraft id, virtual channel, a Type-AD or control frame: there is no COP-1), ``no_spi`` (no room
for the security header and trailer, or a reserved SPI 0/0xFFFF), ``unknown_spi``, ``revoked_spi``,
``bad_mac``, ``replay`` (counter not above the last accepted), ``out_of_window``. The counter is updated only
for a frame that passed everything. It counts every refusal and makes the frame security report
(:class:`FrameSecurityReport`, the 32-bit FSR word of SDLS extended procedures, CCSDS 355.1-B-1, with the
counts per reason) that the onboard side sends as a PUS TM[3,25] packet (:func:`encode_frame_security_report`).
Pure bytes in and out; no middleware.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import AESGCM
from spacepackets.ecss.tm import PusTm

from taiji2_runtime.packets.cuc import CucError, cuc_pack, cuc_unpack_ns
from taiji2_runtime.packets.packetize import SEQ_MODULO, PacketError
from taiji2_runtime.packets.scheduling import REPORT_APID
from taiji2_runtime.packets.sdls_keys import ACTIVE, AUTHENTICATED_ENCRYPTION, KeyTable
from taiji2_runtime.packets.tc_frame import (
    FECF_OCTETS,
    HEADER_OCTETS,
    MAX_FRAME_OCTETS,
    SPACECRAFT_ID,
    TC_VCID,
    FrameError,
    TcFrameHeader,
    decode_frame,
    frame_crc,
)

__all__ = ["DEFAULT_REPLAY_WINDOW", "FSR_SERVICE", "FSR_SUBTYPE", "IV_OCTETS", "MAC_OCTETS", "MAX_DATA_OCTETS",
           "REFUSAL_REASONS", "SECURITY_HEADER_OCTETS", "FrameRefused", "FrameSecurityReport", "FrameSigner",
           "FrameVerifier", "decode_frame_security_report", "encode_frame_security_report", "is_frame_security_report"]

SPI_OCTETS = 2
IV_OCTETS = 12
SECURITY_HEADER_OCTETS = SPI_OCTETS + IV_OCTETS
MAC_OCTETS = 16
#: frame data octets a secured frame can carry
MAX_DATA_OCTETS = MAX_FRAME_OCTETS - HEADER_OCTETS - SECURITY_HEADER_OCTETS - MAC_OCTETS - FECF_OCTETS
#: accepted counters of an SPI: last accepted < counter <= last accepted + window
DEFAULT_REPLAY_WINDOW = 4096
REFUSAL_REASONS = ("truncated", "oversized", "bad_fecf", "bad_header", "no_spi", "unknown_spi", "revoked_spi",
                   "bad_mac", "replay", "out_of_window")
_BAD_SA = ("no_spi", "unknown_spi", "revoked_spi")
_BAD_SN = ("replay", "out_of_window")
#: the frame security report: PUS TM[3,25] (housekeeping parameter report), structure id 0x5D15
FSR_SERVICE = 3
FSR_SUBTYPE = 25
_FSR_SID = 0x5D15
_FSR_FORMAT = ">HI" + "I" * (len(REFUSAL_REASONS) + 1)


class FrameRefused(ValueError):
    """A frame refused onboard: ``reason`` one of :data:`REFUSAL_REASONS`, ``detail`` says more; ``spi`` if read."""

    def __init__(self, reason: str, detail: str, spi: int | None = None) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail
        self.spi = spi


def _aad_and_mac(frame: bytes) -> tuple[bytes, bytes]:
    return frame[:-FECF_OCTETS - MAC_OCTETS], frame[-FECF_OCTETS - MAC_OCTETS:-FECF_OCTETS]


def _masked_header(header: bytes, spi: int) -> bytes:
    """The authenticated-encryption service's additional authenticated data: the primary header with only its
    virtual channel id kept, the SPI, the IV zeroed (SDLS's authentication bit mask, as Yamcs applies it)."""
    return bytes([0, 0, header[2] & 0xFC, 0, 0]) + spi.to_bytes(SPI_OCTETS, "big") + bytes(IV_OCTETS)


class FrameSigner:
    """The ground's side: secured frames of one SPI, the IV counting up from ``first_sequence``."""

    def __init__(self, keys: KeyTable, spi: int | None = None, first_sequence: int = 1, *,
                 spacecraft_id: int = SPACECRAFT_ID, virtual_channel_id: int = TC_VCID) -> None:
        sa = keys.newest_active() if spi is None else keys.get(spi)
        if sa is None or sa.state != ACTIVE:
            raise ValueError(f"SPI {spi}: {'not in the key table' if sa is None else 'revoked'}: cannot sign with it")
        if not 0 < first_sequence < 2 ** (8 * IV_OCTETS):
            raise ValueError(f"first sequence {first_sequence}: 1..2^96-1")
        self.spi = sa.spi
        self.service = sa.service
        self._aead = AESGCM(sa.key)
        self.next_sequence = int(first_sequence)
        self._frame_count = 0
        self._scid = spacecraft_id
        self._vcid = virtual_channel_id

    def sign(self, data: bytes) -> bytes:
        """The secured frame of ``data`` (1..:data:`MAX_DATA_OCTETS` octets)."""
        if not 0 < len(data) <= MAX_DATA_OCTETS:
            raise ValueError(f"frame data of {len(data)} octets: 1..{MAX_DATA_OCTETS}")
        if self.next_sequence >= 2 ** (8 * IV_OCTETS):
            raise ValueError(f"SPI {self.spi}: the IV counter is exhausted: rotate to a new SPI")
        iv = self.next_sequence.to_bytes(IV_OCTETS, "big")
        octets = HEADER_OCTETS + SECURITY_HEADER_OCTETS + len(data) + MAC_OCTETS + FECF_OCTETS
        header = TcFrameHeader(self._scid, self._vcid, octets, self._frame_count & 0xFF).pack()
        security_header = self.spi.to_bytes(SPI_OCTETS, "big") + iv
        if self.service == AUTHENTICATED_ENCRYPTION:
            # ciphertext || tag, the tag over the masked header
            body = header + security_header + self._aead.encrypt(iv, bytes(data), _masked_header(header, self.spi))
        else:
            aad = header + security_header + bytes(data)
            body = aad + self._aead.encrypt(iv, b"", aad)
        frame = body + frame_crc(body).to_bytes(FECF_OCTETS, "big")
        self.next_sequence += 1
        self._frame_count += 1
        return frame


@dataclass(frozen=True)
class FrameSecurityReport:
    """What the verifier reports: the FSR word's fields (flags since the previous report; ``alarm`` once any
    frame has been refused), the last SPI and sequence number (8 low bits) accepted, and the counts so far."""

    alarm: bool
    bad_sn: bool
    bad_mac: bool
    bad_sa: bool
    last_spi: int
    last_sn_lsb: int
    accepted: int
    refused: dict[str, int] = field(default_factory=dict)

    def total(self) -> int:
        """Frames counted so far, accepted and refused (it only grows while the verifier runs)."""
        return self.accepted + sum(self.refused.values())

    def fsr_word(self) -> int:
        """The 32-bit FSR: control word type 1, version 100, alarm, bad SN, bad MAC, bad SA, last SPI, SN LSB."""
        return ((1 << 31) | (0b100 << 28) | (self.alarm << 27) | (self.bad_sn << 26) | (self.bad_mac << 25)
                | (self.bad_sa << 24) | ((self.last_spi & 0xFFFF) << 8) | (self.last_sn_lsb & 0xFF))


class FrameVerifier:
    """The onboard side (module docstring): :meth:`verify` each frame before anything else reads it."""

    def __init__(self, keys: KeyTable, *, window: int = DEFAULT_REPLAY_WINDOW, max_frame_octets: int = MAX_FRAME_OCTETS,
                 spacecraft_id: int = SPACECRAFT_ID, virtual_channel_id: int = TC_VCID) -> None:
        if window < 1:
            raise ValueError(f"anti-replay window {window}: at least 1")
        if not HEADER_OCTETS + FECF_OCTETS <= max_frame_octets <= MAX_FRAME_OCTETS:
            raise ValueError(f"max frame octets {max_frame_octets}: ..{MAX_FRAME_OCTETS}")
        self.keys = keys
        self.window = int(window)
        self.max_frame_octets = int(max_frame_octets)
        self._scid = spacecraft_id
        self._vcid = virtual_channel_id
        self._aead = {sa.spi: AESGCM(sa.key) for sa in keys}
        self.last_sequence: dict[int, int] = {}
        self.refused: Counter[str] = Counter({r: 0 for r in REFUSAL_REASONS})
        self.accepted = 0
        self._last_spi = 0
        self._alarm = False
        self._flags: set[str] = set()

    def verify(self, frame: bytes) -> bytes:
        """The frame data (the telecommand packet) of an authentic, fresh frame.

        Raises
        ------
        FrameRefused
            With its reason (counted); nothing of the frame may be used.
        """
        try:
            data = self._check(bytes(frame))
        except FrameRefused as exc:
            self.count_refused(exc.reason)
            raise
        self.accepted += 1
        return data

    def count_refused(self, reason: str) -> None:
        """Count a refusal found before a frame could be delimited (e.g. a burst cut short): ``reason`` one of
        :data:`REFUSAL_REASONS`."""
        if reason not in REFUSAL_REASONS:
            raise ValueError(f"refusal reason {reason!r}")
        self.refused[reason] += 1
        self._alarm = True
        self._flags.add(reason)

    def _check(self, frame: bytes) -> bytes:
        try:
            header, field_ = decode_frame(frame, self.max_frame_octets)
        except FrameError as exc:
            raise FrameRefused(exc.kind, exc.detail) from None
        if (header.version, header.spacecraft_id, header.virtual_channel_id, header.bypass,
                header.control_command) != (0, self._scid, self._vcid, True, False):
            raise FrameRefused("bad_header", f"version {header.version}, spacecraft 0x{header.spacecraft_id:03X}, "
                                             f"VC {header.virtual_channel_id}, bypass {header.bypass:d}, control "
                                             f"{header.control_command:d}: only Type-BD data frames of "
                                             f"0x{self._scid:03X} VC {self._vcid}")
        if len(field_) < SECURITY_HEADER_OCTETS + MAC_OCTETS:
            raise FrameRefused("no_spi", f"frame data field of {len(field_)} octets: no security header and trailer")
        spi = int.from_bytes(field_[:SPI_OCTETS], "big")
        if spi in (0, 0xFFFF):
            raise FrameRefused("no_spi", f"reserved SPI 0x{spi:04X} (no security association)", spi)
        sa = self.keys.get(spi)
        if sa is None:
            raise FrameRefused("unknown_spi", f"SPI {spi} is not in the key table", spi)
        if sa.state != ACTIVE:
            raise FrameRefused("revoked_spi", f"SPI {spi} is revoked", spi)
        iv = field_[SPI_OCTETS:SECURITY_HEADER_OCTETS]
        try:
            if sa.service == AUTHENTICATED_ENCRYPTION:
                data = self._aead[spi].decrypt(iv, field_[SECURITY_HEADER_OCTETS:], _masked_header(frame, spi))
            else:
                aad, mac = _aad_and_mac(frame)
                self._aead[spi].decrypt(iv, mac, aad)
                data = field_[SECURITY_HEADER_OCTETS:-MAC_OCTETS]
        except InvalidTag:
            raise FrameRefused("bad_mac", f"SPI {spi}: the MAC does not authenticate the frame", spi) from None
        sequence = int.from_bytes(iv, "big")
        last = self.last_sequence.get(spi, 0)
        if sequence <= last:
            raise FrameRefused("replay", f"SPI {spi}: sequence number {sequence}, not above the last accepted "
                                         f"{last}", spi)
        if sequence > last + self.window:
            raise FrameRefused("out_of_window", f"SPI {spi}: sequence number {sequence}, more than the window "
                                                f"{self.window} above the last accepted {last}", spi)
        self.last_sequence[spi] = sequence
        self._last_spi = spi
        return bytes(data)

    def report(self, clear_flags: bool = True) -> FrameSecurityReport:
        """The frame security report now; its bad-SN/MAC/SA flags cover the refusals since the previous report."""
        f = self._flags
        out = FrameSecurityReport(self._alarm, bool(f & set(_BAD_SN)), "bad_mac" in f, bool(f & set(_BAD_SA)),
                                  self._last_spi, self.last_sequence.get(self._last_spi, 0) & 0xFF, self.accepted,
                                  {r: self.refused[r] for r in REFUSAL_REASONS})
        if clear_flags:
            self._flags = set()
        return out


def encode_frame_security_report(report: FrameSecurityReport, onboard_ns: int, seq_count: int) -> bytes:
    """The PUS TM[3,25] of ``report`` on APID 0x141: structure id, FSR word, then uint32 counts (accepted, then
    each of :data:`REFUSAL_REASONS` in order), at onboard time ``onboard_ns``."""
    counts = [min(report.accepted, 2**32 - 1)] + [min(report.refused.get(r, 0), 2**32 - 1) for r in REFUSAL_REASONS]
    data = struct.pack(_FSR_FORMAT, _FSR_SID, report.fsr_word(), *counts)
    tm = PusTm(service=FSR_SERVICE, message_subtype=FSR_SUBTYPE, timestamp=cuc_pack(onboard_ns), source_data=data,
               apid=REPORT_APID, seq_count=seq_count % SEQ_MODULO)
    return bytes(tm.pack())


def is_frame_security_report(packet: bytes) -> bool:
    """Whether a packet of APID 0x141 is a TM[3,25] (by its PUS-C secondary header), not a TM[1,x]."""
    return len(packet) > 8 and packet[7] == FSR_SERVICE and packet[8] == FSR_SUBTYPE


def decode_frame_security_report(packet: bytes) -> tuple[FrameSecurityReport, int]:
    """The report and its onboard time [ns] of a packet of :func:`encode_frame_security_report`.

    Raises
    ------
    PacketError
        ``unknown_apid`` (not such a report, or damaged), ``wrong_length``, ``bad_time_field``.
    """
    try:
        tm = PusTm.unpack(bytes(packet), timestamp_len=8)
    except Exception as exc:  # spacepackets raises several types for a damaged or foreign packet
        raise PacketError("unknown_apid", f"not a frame security report: {exc}") from None
    if (tm.apid, tm.service, tm.message_subtype) != (REPORT_APID, FSR_SERVICE, FSR_SUBTYPE):
        raise PacketError("unknown_apid", f"APID 0x{tm.apid:03X} TM[{tm.service},{tm.message_subtype}]")
    data = bytes(tm.source_data)
    if len(data) != struct.calcsize(_FSR_FORMAT) or data[:2] != _FSR_SID.to_bytes(2, "big"):
        raise PacketError("wrong_length", f"frame security report of {len(data)} octets")
    try:
        onboard_ns = cuc_unpack_ns(bytes(tm.timestamp))
    except CucError as exc:
        raise PacketError("bad_time_field", str(exc)) from None
    _, word, accepted, *counts = struct.unpack(_FSR_FORMAT, data)
    report = FrameSecurityReport(bool(word >> 27 & 1), bool(word >> 26 & 1), bool(word >> 25 & 1),
                                 bool(word >> 24 & 1), word >> 8 & 0xFFFF, word & 0xFF, accepted,
                                 dict(zip(REFUSAL_REASONS, counts, strict=True)))
    return report, onboard_ns
