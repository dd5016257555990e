"""Endpoints carry their REP 2011 type hash in USER_DATA, as rmw_cyclonedds_cpp (Jazzy) writes it.

ROS 2 tools (Jazzy and later) read ``typehash=RIHS01_<hex>;`` from every endpoint's USER_DATA and
warn about endpoints without it. The expected hashes are the ones rosidl generates, as shipped by
ROS 2 Jazzy in ``share/<pkg>/msg/<Type>.json`` (``type_hashes``); the rclpy tier compares our own
message types against a colcon build of this workspace.
"""


from __future__ import annotations

import pytest
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.qos import Policy

from taiji2_runtime.interfaces import type_hash
from taiji2_runtime.ros import messages, rclpy

from support import spin_until

pytestmark = pytest.mark.embedded_runtime(reason=(
    "the embedded runtime's own USER_DATA type hashes; rmw_cyclonedds writes them under rclpy (test/rclpy "
    "compares both with rosidl's)"
))

#: rosidl's hashes of standard types (ROS 2 Jazzy share/*/msg/*.json)
ROSIDL_HASHES = {
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "geometry_msgs/msg/WrenchStamped": "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77",
    # a .msg ``char`` is hashed as rosidl's IDL ``uint8``
    "std_msgs/msg/Char": "RIHS01_3ad2d04dd29ba19d04b16659afa3ccaedd691914b02a64e82e252f2fa6a586a9",
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "rcl_interfaces/msg/Log": "RIHS01_e28ce254ca8abc06abf92773b74602cdbf116ed34fbaf294fb9f81da9f318eac",
}


def test_type_hashes_are_rosidls():
    for name, expected in ROSIDL_HASHES.items():
        pkg, _, cls = name.split("/")
        assert type_hash(getattr(getattr(messages, pkg), cls)) == expected, name


def test_endpoints_announce_their_type_hash_in_user_data(context, executor):
    node = rclpy.node.Node("hashed", context=context)
    executor.add_node(node)
    node.create_publisher(messages.geometry_msgs.WrenchStamped, "/hashed_topic", 10)
    node.create_subscription(messages.geometry_msgs.WrenchStamped, "/hashed_topic", lambda m: None, 10)
    expected = f"typehash={ROSIDL_HASHES['geometry_msgs/msg/WrenchStamped']};".encode("ascii")
    found: dict[str, bytes] = {}
    # what any participant on the domain sees of these endpoints (the builtin discovery topics)
    readers = {"writer": BuiltinDataReader(context.participant(), BuiltinTopicDcpsPublication),
               "reader": BuiltinDataReader(context.participant(), BuiltinTopicDcpsSubscription)}

    def discovered() -> bool:
        for kind, reader in readers.items():
            for sample in reader.take(N=256):
                if sample.topic_name == "rt/hashed_topic":
                    found[kind] = sample.qos[Policy.Userdata].data
        return len(found) == 2

    assert spin_until(executor, discovered)
    assert found == {"writer": expected, "reader": expected}
