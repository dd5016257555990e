"""Topics, QoS and the ``taiji2_msgs/SpacePackets`` helpers shared by the link nodes (docs/link.md).

Two sides, joined only through the space link:

* onboard (namespace ``/onboard``): the spacecraft's bus topics ``/onboard/taiji2/...`` (the
  contract's raw topics as the spacecraft makes them), the telemetry the transmitter takes
  (:data:`ONBOARD_TM`) and the telecommands it receives (:data:`ONBOARD_TC`);
* ground (namespace ``/ground``): what the ground station receives (:data:`GROUND_TM`), the
  telecommands it sends (:data:`GROUND_TC`), and the contract topics ``/taiji2/...`` the estimators,
  the recorder and ``taiji2 calibrate`` read, published by the ground receiver.
"""

from __future__ import annotations

from typing import Any

from taiji2_model.contract import RAW_TOPICS
from taiji2_runtime.packets.tc_frame import split_frames
from taiji2_runtime.ros import messages, rclpy

ONBOARD_NS = "/onboard"
GROUND_NS = "/ground"
ONBOARD_TM = "/onboard/link/tm"  # telemetry packets the onboard transmitter takes (packetizer -> link)
ONBOARD_TC = "/onboard/link/tc"  # telecommand frames received onboard (link -> command executor)
GROUND_TM = "/ground/link/tm"  # telemetry packets the ground station received (link -> ground receiver)
GROUND_TC = "/ground/link/tc"  # telecommand frames the ground sends (planner -> link; SDLS-secured TC frames)
RECEPTION_TOPIC = "/ground/link/reception"  # ground receiver: what has been released, when (JSON)
LINK_REPORT_TOPIC = "/taiji2/sim/link_report"  # the link's own account (evaluation only, like /taiji2/sim/)
CONTRACT_TOPICS = tuple(RAW_TOPICS)
_NS = 1_000_000_000
END_NS = (2**31 - 1) * _NS  # "complete through the end of time" (the largest header stamp)


def onboard(topic: str) -> str:
    """The onboard bus name of a contract topic: ``/taiji2/x`` -> ``/onboard/taiji2/x``."""
    return ONBOARD_NS + topic


def reliable_all() -> Any:
    """Reliable keep-all: nothing the link carries is dropped by the middleware."""
    return rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)


def latched() -> Any:
    return rclpy.qos.QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


def set_stamp(header: Any, t_ns: int) -> None:
    header.stamp.sec, header.stamp.nanosec = divmod(min(int(t_ns), END_NS), _NS)


def burst(packets: list[bytes], times_ns: list[int], complete_through_ns: int, *,
          transmitted_through_ns: int = -1, end_of_data: bool = False) -> Any:
    """A ``SpacePackets`` message."""
    msg = messages.taiji2_msgs.SpacePackets()
    set_stamp(msg.header, complete_through_ns)
    msg.data = b"".join(packets)
    msg.times_ns = [int(t) for t in times_ns]
    msg.transmitted_through_ns = int(transmitted_through_ns)
    msg.end_of_data = bool(end_of_data)
    return msg


def split(msg: Any) -> list[bytes]:
    """The packets of a ``SpacePackets`` message (by their primary headers' length fields).

    Raises
    ------
    ValueError
        If the octets do not divide into whole packets, or their number differs from ``times_ns``.
    """
    data = bytes(msg.data)
    out = []
    pos = 0
    while pos < len(data):
        if len(data) - pos < 7:
            raise ValueError(f"SpacePackets: {len(data) - pos} trailing octets, not a packet")
        end = pos + ((data[pos + 4] << 8) | data[pos + 5]) + 7
        if end > len(data):
            raise ValueError("SpacePackets: the last packet is cut short")
        out.append(data[pos:end])
        pos = end
    if len(out) != len(msg.times_ns):
        raise ValueError(f"SpacePackets: {len(out)} packets but {len(msg.times_ns)} times")
    return out


def split_tc_frames(msg: Any) -> list[bytes]:
    """The TC transfer frames of a ``SpacePackets`` message of the uplink (the units back to back are frames
    there, delimited by their length fields; :mod:`taiji2_runtime.packets.tc_frame`).

    Raises
    ------
    ValueError
        If the octets do not divide into whole frames, or their number differs from ``times_ns``.
    """
    frames = split_frames(bytes(msg.data))
    if len(frames) != len(msg.times_ns):
        raise ValueError(f"SpacePackets: {len(frames)} frames but {len(msg.times_ns)} times")
    return frames


def apid_of(packet: bytes) -> int:
    return ((packet[0] & 7) << 8) | packet[1]
