"""The packet definition of the raw-data contract (docs/interfaces.md, *CCSDS Space Packets*).

One application process identifier (APID) per telemetry stream; every telemetry packet is

=======  ==========================================================================
octets   field
=======  ==========================================================================
0-5      CCSDS primary header (CCSDS 133.0-B-2): version 0, type 0 (TM), secondary
         header flag 1, APID, sequence flags 0b11 (unsegmented), 14-bit sequence
         count per APID, data length = octets after the primary header - 1
6-13     secondary header: CUC onboard time (CCSDS 301.0-B-4) with its P-field:
         0x2F (level 2, agency-defined epoch = the onboard clock's zero; 4 coarse
         octets [s], 3 fine octets [2**-24 s])
14-..    user data: IEEE-754 binary64, big-endian, in the contract's units
last 2   packet error control: CRC-16-CCITT (poly 0x1021, init 0xFFFF, no
         reflection, no final xor) over every preceding octet of the packet
=======  ==========================================================================

Telecommands are ECSS PUS-C TCs (:mod:`.telecommand`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taiji2_model.contract import COMMAND_TOPIC, GRS_TOPICS, STAR_TRACKER_TOPIC

__all__ = [
    "APIDS",
    "CRC_OCTETS",
    "CUC_COARSE_OCTETS",
    "CUC_FINE_OCTETS",
    "CUC_PFIELD",
    "CUC_RESOLUTION_S",
    "IDLE_APID",
    "PRIMARY_HEADER_OCTETS",
    "SECONDARY_HEADER_OCTETS",
    "STREAMS",
    "STREAM_BY_APID",
    "TC_APID",
    "TC_SERVICE",
    "TC_SUBTYPE_TORQUE",
    "StreamDefinition",
]

PRIMARY_HEADER_OCTETS = 6
CUC_COARSE_OCTETS = 4
CUC_FINE_OCTETS = 3
#: CUC P-field: extension 0, time code id 010 (agency-defined epoch), coarse octets - 1 = 3, fine octets = 3
CUC_PFIELD = 0b0_010_11_11
CUC_RESOLUTION_S = 2.0 ** (-8 * CUC_FINE_OCTETS)
SECONDARY_HEADER_OCTETS = 1 + CUC_COARSE_OCTETS + CUC_FINE_OCTETS
CRC_OCTETS = 2
IDLE_APID = 0x7FF

#: telecommands to the maneuver executor (ECSS PUS-C TC, mission-specific service)
TC_APID = 0x140
TC_SERVICE = 130
TC_SUBTYPE_TORQUE = 1


@dataclass(frozen=True)
class StreamDefinition:
    """One telemetry stream: its APID, the contract topic it carries and its user-data fields.

    Attributes
    ----------
    name : str
        Short name (``star_tracker``, ``grs1``, ``grs2``, ``executed_torque``).
    apid : int
        Application process identifier.
    topic : str
        The raw-data contract topic whose samples the packets carry.
    fields : tuple of str
        User-data fields, in order, each one big-endian binary64 in the contract's units.
    units : tuple of str
        The contract's unit of each field (``""``: dimensionless), as the XTCE database declares them.
    """

    name: str
    apid: int
    topic: str
    fields: tuple[str, ...]
    units: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.units) != len(self.fields):
            raise ValueError(f"stream {self.name}: {len(self.fields)} fields but {len(self.units)} units")

    @property
    def user_data_octets(self) -> int:
        """Octets of user data."""
        return 8 * len(self.fields)

    @property
    def packet_octets(self) -> int:
        """Octets of a whole packet."""
        return PRIMARY_HEADER_OCTETS + SECONDARY_HEADER_OCTETS + self.user_data_octets + CRC_OCTETS

    @property
    def data_length(self) -> int:
        """The primary header's packet data length field (octets after the primary header - 1)."""
        return self.packet_octets - PRIMARY_HEADER_OCTETS - 1

    @property
    def dtype(self) -> np.dtype:
        """numpy dtype of one packet (big-endian fields; the header as raw octets)."""
        return np.dtype([("primary", "u1", (PRIMARY_HEADER_OCTETS,)), ("pfield", "u1"), ("coarse", ">u4"),
                         ("fine", "u1", (CUC_FINE_OCTETS,)), ("values", ">f8", (len(self.fields),)),
                         ("crc", ">u2")])


_COV = tuple(f"attitude_covariance[{i}]" for i in range(9))
_GRS = ("vx1", "vx2", "vy1", "vy2", "vz1", "vz2")
STREAMS: tuple[StreamDefinition, ...] = (
    StreamDefinition("star_tracker", 0x101, STAR_TRACKER_TOPIC,
                     ("attitude.x", "attitude.y", "attitude.z", "attitude.w", *_COV), ("",) * 4 + ("rad^2",) * 9),
    StreamDefinition("grs1", 0x111, GRS_TOPICS[0], _GRS, ("V",) * 6),
    StreamDefinition("grs2", 0x112, GRS_TOPICS[1], _GRS, ("V",) * 6),
    StreamDefinition("executed_torque", 0x121, COMMAND_TOPIC,
                     ("wrench.torque.x", "wrench.torque.y", "wrench.torque.z",
                      "wrench.force.x", "wrench.force.y", "wrench.force.z"), ("N m",) * 3 + ("N",) * 3),
)
STREAM_BY_APID: dict[int, StreamDefinition] = {s.apid: s for s in STREAMS}
APIDS: tuple[int, ...] = tuple(STREAM_BY_APID)
