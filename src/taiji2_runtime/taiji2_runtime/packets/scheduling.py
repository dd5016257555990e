"""Time-tagged commanding: ECSS PUS service 11 (time-based scheduling) and service 1 (verification) packets.

* ``TC[11,4]`` *insert activities into the time-based schedule* (ECSS-E-ST-70-41C 6.11.5.4), packed
  and checked by spacepackets' ``PusTc`` on APID 0x140: application data = N (uint16), then N
  instructions, each the release time as an 8-octet CUC field with P-field (onboard time,
  :mod:`.cuc`) followed by the request: a whole torque TC ``TC[130,1]`` (:mod:`.telecommand`, its
  own execution time = the release time). No sub-schedule or group identifiers (mission option).
* The onboard executor's verification reports, ``TM[1,1]`` acceptance success, ``TM[1,2]`` acceptance
  failure (a packet that came in an authentic frame but is not a valid TC[11,4]: code
  :data:`ACCEPTANCE_FAILURE_CODES` of its defect, then 0), ``TM[1,7]``
  completion success (every activity inserted) and ``TM[1,8]`` completion failure (failure notice:
  code :data:`FAILURE_LATE` or :data:`FAILURE_CAPACITY`, 1 octet, then the number of activities
  refused, uint16), are spacepackets ``Service1Tm`` packets of APID :data:`REPORT_APID`, with the
  8-octet CUC onboard time as their PUS-C time field.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from spacepackets.ecss.fields import PacketFieldEnum
from spacepackets.ecss.pus_1_verification import (
    FailureNotice,
    ManagedParamsVerification,
    Service1Tm,
    VerificationParams,
)
from spacepackets.ecss.req_id import RequestId
from spacepackets.ecss.tc import PusTc
from spacepackets.ecss.tm import ManagedParams

from taiji2_runtime.packets.cuc import CucError, cuc_pack, cuc_unpack_ns
from taiji2_runtime.packets.definition import TC_APID
from taiji2_runtime.packets.packetize import SEQ_MODULO, PacketError
from taiji2_runtime.packets.telecommand import (
    TC_PACKET_OCTETS,
    TorqueCommand,
    decode_torque_tc,
    encode_torque_tc,
    unpack_telecommand,
)

__all__ = ["ACCEPTANCE_FAILURE_CODES", "FAILURE_CAPACITY", "FAILURE_LATE", "MAX_ACTIVITIES_PER_TC", "REPORT_APID",
           "Activity", "VerificationReport", "decode_insert_activities", "decode_report", "encode_insert_activities",
           "encode_report"]

SCHEDULING_SERVICE = 11
INSERT_ACTIVITIES = 4
#: APID of the onboard command executor's telemetry (PUS service 1 reports)
REPORT_APID = 0x141
FAILURE_LATE = 1  # an activity's release time was before its arrival plus the time margin
FAILURE_CAPACITY = 2  # the onboard schedule was full
#: TM[1,2] failure codes: the PacketError kind of a telecommand refused at acceptance
ACCEPTANCE_FAILURE_CODES = {"crc_error": 3, "truncated": 4, "unknown_apid": 5, "wrong_length": 6, "bad_time_field": 7,
                            "bad_header": 8}
#: instructions per TC[11,4]: 8 + 69 octets each, a packet of at most 15 + 12 x 77 = 939 octets, so that one
#: packet fits one SDLS-secured TC transfer frame (987 octets of frame data, :mod:`.sdls`)
MAX_ACTIVITIES_PER_TC = 12
_INSTRUCTION_OCTETS = 8 + TC_PACKET_OCTETS


@dataclass(frozen=True)
class Activity:
    """One time-tagged torque command: released onboard at ``release_ns`` [onboard ns]."""

    release_ns: int
    torque_n_m: tuple[float, float, float]
    force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)


def encode_insert_activities(seq_count: int, activities: list[Activity], first_request_seq: int = 0) -> bytes:
    """The TC[11,4] of ``activities`` (at most :data:`MAX_ACTIVITIES_PER_TC`)."""
    if not 0 < len(activities) <= MAX_ACTIVITIES_PER_TC:
        raise ValueError(f"TC[11,4]: 1..{MAX_ACTIVITIES_PER_TC} activities, got {len(activities)}")
    parts = [struct.pack(">H", len(activities))]
    for k, a in enumerate(activities):
        parts.append(cuc_pack(a.release_ns))
        parts.append(encode_torque_tc(first_request_seq + k, a.release_ns, np.asarray(a.torque_n_m),
                                      np.asarray(a.force_n)))
    tc = PusTc(service=SCHEDULING_SERVICE, message_subtype=INSERT_ACTIVITIES, apid=TC_APID,
               app_data=b"".join(parts), seq_count=seq_count % SEQ_MODULO)
    return bytes(tc.pack())


def decode_insert_activities(packet: bytes) -> tuple[PusTc, list[TorqueCommand]]:
    """The PusTc and its activities (each a :class:`TorqueCommand` whose execution time is its release time).

    Raises
    ------
    PacketError
        ``crc_error``, ``truncated``, ``bad_header``, ``unknown_apid`` (not TC[11,4] of APID 0x140),
        ``wrong_length``, ``bad_time_field``.
    """
    tc = unpack_telecommand(packet, SCHEDULING_SERVICE, INSERT_ACTIVITIES, " is not TC[11,4]")
    data = tc.app_data
    n = struct.unpack(">H", data[:2])[0] if len(data) >= 2 else -1
    if n < 1 or len(data) != 2 + n * _INSTRUCTION_OCTETS:
        raise PacketError("wrong_length", f"TC[11,4] with {len(data)} octets of application data for N = {n}")
    out = []
    for k in range(n):
        start = 2 + k * _INSTRUCTION_OCTETS
        try:
            release = cuc_unpack_ns(data[start:start + 8])
        except CucError as exc:
            raise PacketError("bad_time_field", str(exc)) from None
        command = decode_torque_tc(data[start + 8:start + _INSTRUCTION_OCTETS])
        out.append(TorqueCommand(command.seq_count, release, command.torque_n_m, command.force_n))
    return tc, out


@dataclass(frozen=True)
class VerificationReport:
    """A decoded TM[1,x]: subtype (1 acceptance, 2 acceptance failure, 7 completion success, 8 completion
    failure), the TC's sequence count, the report's onboard time, and for a failure its code and activities
    refused."""

    subtype: int
    tc_seq_count: int
    onboard_ns: int
    failure_code: int = 0
    refused: int = 0


def encode_report(subtype: int, tc: PusTc | bytes, onboard_ns: int, seq_count: int, failure_code: int = 0,
                  refused: int = 0) -> bytes:
    """The TM[1,subtype] (1, 2, 7 or 8) reporting on ``tc`` at onboard time ``onboard_ns``; ``tc`` the PusTc or,
    for an acceptance failure, the raw packet (its first 4 octets are the request id; zeros if shorter)."""
    if subtype not in (1, 2, 7, 8):
        raise ValueError(f"verification report subtype {subtype}: 1, 2, 7 or 8")
    notice = (FailureNotice(PacketFieldEnum.with_byte_size(1, failure_code), struct.pack(">H", refused))
              if subtype in (2, 8) else None)
    if isinstance(tc, PusTc):
        request = RequestId.from_sp_header(tc.sp_header)
    else:
        request = RequestId.unpack(bytes(tc[:4])) if len(tc) >= 4 else RequestId.empty()
    params = VerificationParams(request, failure_notice=notice)
    tm = Service1Tm(REPORT_APID, subtype, cuc_pack(onboard_ns), params, seq_count=seq_count % SEQ_MODULO)
    return bytes(tm.pack())


def decode_report(packet: bytes) -> VerificationReport:
    """Decode a TM[1,1|2|7|8] of :func:`encode_report`.

    Raises
    ------
    PacketError
        If it is not one (``unknown_apid``, also for a CRC failure), or its time field (``bad_time_field``) or
        failure data (``wrong_length``) are not ours.
    """
    try:
        tm = Service1Tm.unpack(bytes(packet), ManagedParams(timestamp_len=8),
                               ManagedParamsVerification(bytes_err_code=1))
    except Exception as exc:  # spacepackets raises several types for a damaged or foreign packet
        raise PacketError("unknown_apid", f"not a verification report: {exc}") from None
    if tm.sp_header.apid != REPORT_APID:
        raise PacketError("unknown_apid", f"APID 0x{tm.sp_header.apid:03X}")
    notice = tm.failure_notice
    try:  # found by the fuzzing: a report with a foreign time field raised CucError out of the ground receiver
        onboard_ns = cuc_unpack_ns(tm.timestamp)
    except CucError as exc:
        raise PacketError("bad_time_field", f"verification report: {exc}") from None
    if notice is not None and len(notice.data) != 2:
        raise PacketError("wrong_length", f"verification report: failure data of {len(notice.data)} octets, not 2")
    return VerificationReport(int(tm.message_subtype), tm.tc_req_id.tc_psc.seq_count, onboard_ns,
                              0 if notice is None else int(notice.code.val),
                              0 if notice is None else struct.unpack(">H", notice.data)[0])
