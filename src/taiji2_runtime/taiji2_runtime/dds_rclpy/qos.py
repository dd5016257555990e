"""rclpy.qos subset, and its mapping onto Cyclone DDS QoS as rmw_cyclonedds_cpp does it."""

from __future__ import annotations

from enum import IntEnum

from cyclonedds.core import Policy, Qos
from cyclonedds.util import duration


class ReliabilityPolicy(IntEnum):
    """rclpy.qos.ReliabilityPolicy."""

    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2
    UNKNOWN = 3


class HistoryPolicy(IntEnum):
    """rclpy.qos.HistoryPolicy."""

    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2
    UNKNOWN = 3


class DurabilityPolicy(IntEnum):
    """rclpy.qos.DurabilityPolicy."""

    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2
    UNKNOWN = 3


QoSReliabilityPolicy = ReliabilityPolicy
QoSHistoryPolicy = HistoryPolicy
QoSDurabilityPolicy = DurabilityPolicy


class QoSProfile:
    """rclpy.qos.QoSProfile: history, depth, reliability, durability.

    As in rclpy, either ``history`` or ``depth`` must be given; ``depth`` alone means KEEP_LAST.
    """

    def __init__(
        self,
        *,
        history: HistoryPolicy | None = None,
        depth: int | None = None,
        reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE,
        durability: DurabilityPolicy = DurabilityPolicy.VOLATILE,
    ) -> None:
        if history is None and depth is None:
            raise TypeError("QoSProfile: either 'history' or 'depth' must be given")
        if depth is not None and (not isinstance(depth, int) or depth < 0):
            raise ValueError(f"QoSProfile: depth must be a non-negative int, got {depth!r}")
        self.history = HistoryPolicy.KEEP_LAST if history is None else HistoryPolicy(history)
        self.depth = 10 if depth is None else depth
        self.reliability = ReliabilityPolicy(reliability)
        self.durability = DurabilityPolicy(durability)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, QoSProfile) and vars(self) == vars(other)

    def __hash__(self) -> int:
        return hash(tuple(vars(self).values()))

    def __repr__(self) -> str:
        return (
            f"QoSProfile(history={self.history.name}, depth={self.depth}, "
            f"reliability={self.reliability.name}, durability={self.durability.name})"
        )


qos_profile_sensor_data = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
qos_profile_system_default = QoSProfile(
    history=HistoryPolicy.SYSTEM_DEFAULT,
    depth=0,
    reliability=ReliabilityPolicy.SYSTEM_DEFAULT,
    durability=DurabilityPolicy.SYSTEM_DEFAULT,
)
qos_profile_parameter_events = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
#: rclpy's ClockQoS (/clock): best effort, keep last 1.
qos_profile_clock = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)

#: rmw_cyclonedds_cpp's max_blocking_time for reliable writers [s].
_MAX_BLOCKING_TIME_S = 0.1


def coerce_qos(qos: QoSProfile | int) -> QoSProfile:
    """rclpy accepts a depth (int) wherever a profile is expected."""
    if isinstance(qos, QoSProfile):
        return qos
    if isinstance(qos, int) and not isinstance(qos, bool):
        return QoSProfile(depth=qos)
    raise TypeError(f"expected a QoSProfile or a history depth (int), got {qos!r}")


def to_dds_qos(profile: QoSProfile, type_hash: str | None = None) -> Qos:
    """Cyclone DDS QoS for an rclpy profile: ROS 2 semantics, XCDR1 data representation.

    ``type_hash`` (``RIHS01_<hex>``, REP 2011) goes into the endpoint's USER_DATA as
    ``typehash=<hash>;``, as rmw_cyclonedds_cpp (Jazzy and later) writes it: ROS tools read the
    type hash of every endpoint from there and warn about endpoints without it.
    """
    policies = []
    if profile.reliability == ReliabilityPolicy.BEST_EFFORT:
        policies.append(Policy.Reliability.BestEffort)
    else:
        policies.append(Policy.Reliability.Reliable(duration(seconds=_MAX_BLOCKING_TIME_S)))
    if profile.history == HistoryPolicy.KEEP_ALL:
        policies.append(Policy.History.KeepAll)
    else:
        policies.append(Policy.History.KeepLast(max(1, profile.depth)))
    if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        policies.append(Policy.Durability.TransientLocal)
    else:
        policies.append(Policy.Durability.Volatile)
    # ROS 2 data is XCDR1 (rosidl typesupport); without this Cyclone may pick XCDR2.
    policies.append(Policy.DataRepresentation(use_cdrv0_representation=True))
    if type_hash:
        policies.append(Policy.Userdata(f"typehash={type_hash};".encode("ascii")))
    return Qos(*policies)
