"""The ROS 2 graph topic ``ros_discovery_info`` (rmw_dds_common), as rmw_cyclonedds_cpp uses it.

ROS 2 learns which node owns which DDS reader and writer from one message per participant,
``rmw_dds_common/msg/ParticipantEntitiesInfo`` (participant GID, and per node its namespace, name,
reader GIDs and writer GIDs), published on the DDS topic ``ros_discovery_info`` (no ``rt/``
prefix), reliable, transient-local, keep-last 1. ``ros2 node list`` / ``ros2 node info`` read it.

The GID of a DDS entity is its 16-byte GUID. The message layout differs between distributions:

* Jazzy and later: ``rmw_dds_common/msg/Gid`` is ``uint8[16]`` (IDL; ``char[16]`` in the .msg),
  and every endpoint announces its type hash in USER_DATA;
* Humble: ``Gid`` is ``char[24]`` (the GUID, then 8 zero bytes) and there are no type hashes.

The DDS type name is the same for both, so the two layouts cannot share a domain; the layout
follows ``ROS_DISTRO`` (``humble`` selects the 24-byte one; anything else, or unset, Jazzy's).

The participant's USER_DATA carries ``enclave=/;`` (as rmw_cyclonedds_cpp writes it) and, for
embedded-runtime participants only, ``taiji2_start_ns=<ns>;``: the wall-clock start of the
process, which decides which of two embedded nodes with the same name is the later duplicate.
ROS 2 ignores keys it does not know.
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the field annotations at runtime

import os
import time
from dataclasses import dataclass, field
from functools import cache

import cyclonedds.idl.types as idl_types
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant
from cyclonedds.core import Policy, Qos
from cyclonedds.idl import IdlStruct
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from taiji2_runtime.dds_rclpy.topics import create_topic

DISCOVERY_TOPIC = "ros_discovery_info"
START_KEY = "taiji2_start_ns"
_ALIVE = 16  # DDS_IST_ALIVE
_GUID_BYTES = 16

def gid_bytes() -> int:
    """Size of ``rmw_dds_common/msg/Gid`` on this distribution (24 on Humble, 16 from Jazzy on)."""
    return 24 if os.environ.get("ROS_DISTRO", "").strip().lower() == "humble" else _GUID_BYTES


def discovery_type_hash() -> str | None:
    """REP 2011 hash of Jazzy's ParticipantEntitiesInfo (None for the Humble layout)."""
    if gid_bytes() != _GUID_BYTES:
        return None
    from taiji2_runtime.typestore import rihs01

    return rihs01("rmw_dds_common/msg/ParticipantEntitiesInfo")


@cache
def message_types(size: int) -> tuple[type, type, type]:
    """(Gid, NodeEntitiesInfo, ParticipantEntitiesInfo) DDS classes for a GID of ``size`` bytes."""

    @dataclass
    class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: idl_types.array[idl_types.uint8, size] = field(default_factory=lambda: [0] * size)

    @dataclass
    class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: idl_types.bounded_str[256] = ""
        node_name: idl_types.bounded_str[256] = ""
        reader_gid_seq: idl_types.sequence[Gid] = field(default_factory=list)
        writer_gid_seq: idl_types.sequence[Gid] = field(default_factory=list)

    @dataclass
    class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
        gid: Gid = field(default_factory=Gid)
        node_entities_info_seq: idl_types.sequence[NodeEntitiesInfo] = field(default_factory=list)

    return Gid, NodeEntitiesInfo, ParticipantEntitiesInfo


def participant_user_data(start_ns: int) -> bytes:
    """USER_DATA of an embedded-runtime participant: rmw_cyclonedds_cpp's enclave, our start time."""
    return f"enclave=/;{START_KEY}={start_ns};".encode("ascii")


def parse_user_data(data: bytes | None) -> dict[str, str]:
    """``key=value;`` pairs of a USER_DATA blob (rmw_dds_common's format); unparsable parts skipped."""
    pairs: dict[str, str] = {}
    for item in (data or b"").decode("utf-8", errors="replace").split(";"):
        key, sep, value = item.partition("=")
        if sep and key:
            pairs[key] = value
    return pairs


def _qos(history: object) -> Qos:
    policies = [Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, history,
                Policy.DataRepresentation(use_cdrv0_representation=True)]
    type_hash = discovery_type_hash()
    if type_hash:
        policies.append(Policy.Userdata(f"typehash={type_hash};".encode("ascii")))
    return Qos(*policies)


@dataclass(frozen=True)
class GraphNode:
    """A node somewhere in the graph, as ``ros_discovery_info`` announces it."""

    namespace: str
    name: str
    participant: bytes  # GUID of the owning participant (16 bytes)
    start_ns: int | None  # start of an embedded-runtime process; None for any other participant

    @property
    def fqn(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.name}"


class DiscoveryInfo:
    """Publishes this participant's nodes and endpoints; reads everyone else's."""

    def __init__(self, participant: object, start_ns: int) -> None:
        self._size = gid_bytes()
        self._gid, self._node_info, self._participant_info = message_types(self._size)
        self._participant = participant
        self._guid = participant.get_guid().bytes
        self._start_ns = start_ns
        self._topic = create_topic(participant, DISCOVERY_TOPIC, self._participant_info)
        # keep-last 1 per writer (as rmw_cyclonedds_cpp); the topic is keyless, so the reader keeps
        # every sample until taken, or one participant's update would overwrite another's
        self._writer = DataWriter(participant, self._topic, _qos(Policy.History.KeepLast(1)))
        self._reader = DataReader(participant, self._topic, _qos(Policy.History.KeepAll))
        self._participants = BuiltinDataReader(participant, BuiltinTopicDcpsParticipant)
        self._alive: dict[bytes, int | None] = {}  # participant GUID -> embedded start ns (None: other)
        self._infos: dict[bytes, object] = {}

    def _to_gid(self, guid: bytes) -> object:
        return self._gid(data=list(guid) + [0] * (self._size - len(guid)))

    def announce(self, nodes: list[tuple[str, str, list[bytes], list[bytes]]]) -> None:
        """Publish ``[(namespace, name, reader GUIDs, writer GUIDs), ...]`` of this participant."""
        self._writer.write(self._participant_info(
            gid=self._to_gid(self._guid),
            node_entities_info_seq=[
                self._node_info(node_namespace=ns, node_name=name,
                                reader_gid_seq=[self._to_gid(g) for g in readers],
                                writer_gid_seq=[self._to_gid(g) for g in writers])
                for ns, name, readers, writers in nodes
            ],
        ))

    def nodes(self) -> list[GraphNode]:
        """Every node of every live participant on the domain (this one included), sorted by name."""
        for sample in self._participants.take(N=4096):
            guid = sample.key.bytes
            if sample.sample_info.instance_state == _ALIVE:
                start = parse_user_data(sample.qos[Policy.Userdata].data if Policy.Userdata in sample.qos
                                        else None).get(START_KEY)
                self._alive[guid] = int(start) if start and start.isdigit() else None
            else:
                self._alive.pop(guid, None)
                self._infos.pop(guid, None)
        for info in self._reader.take(N=4096):
            if hasattr(info, "gid"):
                self._infos[bytes(info.gid.data[:_GUID_BYTES])] = info
        found = []
        for guid, info in self._infos.items():
            if guid not in self._alive and guid != self._guid:
                continue
            start = self._start_ns if guid == self._guid else self._alive.get(guid)
            found += [GraphNode(n.node_namespace, n.node_name, guid, start) for n in info.node_entities_info_seq]
        return sorted(found, key=lambda n: (n.fqn, n.participant))

    def conflict(self, mine: set[str]) -> str | None:
        """A message naming the clash if one of ``mine`` duplicates an earlier embedded node elsewhere.

        Only embedded-runtime participants take part: ROS 2 itself allows duplicate node names
        (``ros2 node list`` warns), so a node of another participant never ends ours.
        """
        for other in self.nodes():
            if other.fqn not in mine or other.participant == self._guid or other.start_ns is None:
                continue
            if (other.start_ns, other.participant) < (self._start_ns, self._guid):
                return (f"a node named {other.fqn!r} already runs in the graph (participant "
                        f"{other.participant.hex()}); node names must be unique")
        return None


def process_start_ns() -> int:
    """Wall-clock stamp of this participant's start (ns since the epoch)."""
    return time.time_ns()
