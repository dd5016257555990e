"""Torque telecommands: ECSS PUS-C TCs (spacepackets ``PusTc``), one per maneuver command.

Service 130 (mission-specific), subtype 1 "set torque", APID 0x140, source id 0, acknowledgement
flags 0b1111. Application data (56 octets): the execution time as an 8-octet CUC field with
P-field (:mod:`.cuc`, onboard time), then torque x, y, z [N m] and force x, y, z [N] about the CRF
axes, IEEE-754 binary64 big-endian. The PUS packet error control (CRC-16-CCITT) ends the packet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from spacepackets.ecss.tc import InvalidTcCrc16Error, PusTc
from spacepackets.exceptions import BytesTooShortError

from taiji2_runtime.packets.cuc import CucError, cuc_pack, cuc_unpack_ns
from taiji2_runtime.packets.definition import TC_APID, TC_SERVICE, TC_SUBTYPE_TORQUE
from taiji2_runtime.packets.packetize import SEQ_MODULO, PacketError

__all__ = ["TC_APP_DATA_OCTETS", "TC_PACKET_OCTETS", "TorqueCommand", "decode_torque_tc", "encode_torque_tc"]

TC_APP_DATA_OCTETS = 8 + 6 * 8
#: primary header 6 + PUS-C TC secondary header 5 + application data + CRC 2
TC_PACKET_OCTETS = 6 + 5 + TC_APP_DATA_OCTETS + 2


@dataclass(frozen=True)
class TorqueCommand:
    """A decoded torque telecommand: its sequence count, execution time [onboard ns], torque and force."""

    seq_count: int
    execute_onboard_ns: int
    torque_n_m: np.ndarray
    force_n: np.ndarray


def encode_torque_tc(seq_count: int, execute_onboard_ns: int, torque_n_m: np.ndarray,
                     force_n: np.ndarray | None = None) -> bytes:
    """The PUS TC of one torque command to be executed at ``execute_onboard_ns``."""
    force = np.zeros(3) if force_n is None else np.asarray(force_n, dtype=np.float64)
    values = np.concatenate([np.asarray(torque_n_m, dtype=np.float64).reshape(3), force.reshape(3)])
    app_data = cuc_pack(int(execute_onboard_ns)) + values.astype(">f8").tobytes()
    tc = PusTc(service=TC_SERVICE, message_subtype=TC_SUBTYPE_TORQUE, apid=TC_APID, app_data=app_data,
               seq_count=seq_count % SEQ_MODULO)
    return bytes(tc.pack())


def unpack_telecommand(packet: bytes, service: int, subtype: int, expected: str) -> PusTc:
    """The PUS TC of APID ``TC_APID`` and service (``service``, ``subtype``) in ``packet`` (CRC checked by
    spacepackets); ``expected`` names it in the error (e.g. ``" is not TC[11,4]"``).

    Raises
    ------
    PacketError
        ``crc_error``, ``truncated``, ``bad_header`` (not a PUS-C TC spacepackets can read) or ``unknown_apid``
        (another APID or service).
    """
    try:
        tc = PusTc.unpack(bytes(packet))
    except InvalidTcCrc16Error as exc:
        raise PacketError("crc_error", f"telecommand: {exc}") from None
    except BytesTooShortError as exc:
        raise PacketError("truncated", f"telecommand: {exc}") from None
    except Exception as exc:  # spacepackets refuses a foreign or damaged header with several types (a PUS-A TC:
        # ValueError); every one of them is a defect of the packet, never an error of the caller
        raise PacketError("bad_header", f"telecommand: {type(exc).__name__}: {exc}") from None
    if tc.apid != TC_APID or tc.service != service or tc.message_subtype != subtype:
        raise PacketError("unknown_apid", f"telecommand APID 0x{tc.apid:03X} service {tc.service},{tc.message_subtype}"
                                          f"{expected}")
    return tc


def decode_torque_tc(packet: bytes) -> TorqueCommand:
    """Decode one torque TC (CRC checked by spacepackets).

    Raises
    ------
    PacketError
        ``crc_error``, ``truncated``, ``unknown_apid`` (another TC) or ``bad_time_field``.
    """
    tc = unpack_telecommand(packet, TC_SERVICE, TC_SUBTYPE_TORQUE, "")
    data = tc.app_data
    if len(data) != TC_APP_DATA_OCTETS:
        raise PacketError("wrong_length", f"torque telecommand with {len(data)} octets of application data")
    try:
        when = cuc_unpack_ns(data[:8])
    except CucError as exc:
        raise PacketError("bad_time_field", str(exc)) from None
    values = np.frombuffer(data[8:], dtype=">f8").astype(np.float64)
    return TorqueCommand(tc.seq_count, when, values[:3].copy(), values[3:].copy())
