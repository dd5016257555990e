"""Embedded nodes announce themselves on ``ros_discovery_info`` as rmw_cyclonedds_cpp (Jazzy) does.

What ROS 2 tools rely on, checked with plain Cyclone DDS readers (no ROS 2 needed): the message
arrives on the DDS topic ``ros_discovery_info`` with the participant's GID and, per node, the
GIDs of its readers and writers, which must be the GUIDs the DDS builtin topics announce for those
endpoints (that is how ``ros2 node info`` maps endpoints to nodes); the participant's USER_DATA
names its enclave; the topic's type hash is rosidl's. The rclpy tier checks ``ros2 node list``.
"""


from __future__ import annotations

import pytest
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant, BuiltinTopicDcpsPublication
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from taiji2_runtime.dds_rclpy.discovery_info import DISCOVERY_TOPIC, discovery_type_hash, message_types
from taiji2_runtime.ros import messages, rclpy

from support import spin_until

pytestmark = pytest.mark.embedded_runtime(reason=(
    "the embedded runtime's own ros_discovery_info writer and graph cache; under rclpy rmw_cyclonedds "
    "writes it (test/rclpy checks ros2 node list/info on embedded nodes)"
))

#: rosidl's hash of rmw_dds_common/msg/ParticipantEntitiesInfo (ROS 2 Jazzy share/rmw_dds_common/msg/*.json)
ROSIDL_PARTICIPANT_ENTITIES_INFO = "RIHS01_91a0593bacdcc50ea9bdcf849a938b128412cc1ea821245c663bcd26f83c295e"


def test_discovery_topic_type_hash_is_rosidls():
    assert discovery_type_hash() == ROSIDL_PARTICIPANT_ENTITIES_INFO


def test_nodes_and_their_endpoint_gids_reach_an_independent_reader(context, executor):
    node = rclpy.node.Node("announced", namespace="/probe", context=context, start_parameter_services=False,
                           enable_rosout=False)
    executor.add_node(node)
    publisher = node.create_publisher(messages.std_msgs.String, "said", 10)
    node.create_subscription(messages.std_msgs.String, "heard", lambda m: None, 10)
    # an independent participant on the same domain, as a ROS 2 process would have
    observer = DomainParticipant(context.domain_id)
    info_type = message_types(16)[2]
    qos = Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, Policy.History.KeepAll,
              Policy.DataRepresentation(use_cdrv0_representation=True))
    infos = DataReader(observer, Topic(observer, DISCOVERY_TOPIC, info_type), qos)
    writers = BuiltinDataReader(observer, BuiltinTopicDcpsPublication)
    participants = BuiltinDataReader(observer, BuiltinTopicDcpsParticipant)
    seen: dict[str, object] = {}

    def announced() -> bool:
        for info in infos.take(N=64):
            for entry in info.node_entities_info_seq:
                if entry.node_name == "announced" and entry.reader_gid_seq and entry.writer_gid_seq:
                    seen["participant"], seen["node"] = bytes(info.gid.data), entry
        for sample in writers.take(N=256):
            if sample.topic_name == "rt/probe/said":
                seen["writer"] = sample.key.bytes
        for sample in participants.take(N=64):
            if Policy.Userdata in sample.qos:
                seen.setdefault("user_data", []).append(sample.qos[Policy.Userdata].data)
        return {"participant", "node", "writer"} <= seen.keys()

    assert spin_until(executor, announced)
    entry = seen["node"]
    assert entry.node_namespace == "/probe"
    assert seen["participant"] == context.participant().get_guid().bytes
    assert [bytes(g.data) for g in entry.writer_gid_seq] == [publisher.guid] == [seen["writer"]]
    assert any(data.startswith(b"enclave=/;") for data in seen.get("user_data", [])), seen.get("user_data")
    assert [(n.namespace, n.name) for n in context.graph_nodes()] == [("/probe", "announced")]


def test_a_destroyed_node_leaves_the_graph(context, executor):
    node = rclpy.node.Node("short_lived", context=context)
    assert spin_until(executor, lambda: [n.name for n in context.graph_nodes()] == ["short_lived"])
    node.destroy_node()
    assert spin_until(executor, lambda: context.graph_nodes() == [])


def test_humble_layout_carries_the_guid_in_a_24_byte_gid(context, executor, monkeypatch):
    monkeypatch.setenv("ROS_DISTRO", "humble")  # read when the context's participant starts
    assert discovery_type_hash() is None  # Humble's rmw neither writes nor reads type hashes
    rclpy.node.Node("old_timer", context=context)
    observer = DomainParticipant(context.domain_id)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, Policy.History.KeepAll,
              Policy.DataRepresentation(use_cdrv0_representation=True))
    infos = DataReader(observer, Topic(observer, DISCOVERY_TOPIC, message_types(24)[2]), qos)
    gids: list[bytes] = []

    def announced() -> bool:
        gids.extend(bytes(i.gid.data) for i in infos.take(N=64)
                    if any(n.node_name == "old_timer" for n in i.node_entities_info_seq))
        return bool(gids)

    assert spin_until(executor, announced)
    assert gids[-1] == context.participant().get_guid().bytes + bytes(8)
    assert [n.name for n in context.graph_nodes()] == ["old_timer"]  # and it reads its own layout back
