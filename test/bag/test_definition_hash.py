"""A bag's embedded definitions and type hashes come from one source (issue 26 row 4): rosbags' AnyReader,
which recomputes every hash from the embedded definition, opens what the recorder writes, also for types whose
Humble and Jazzy definitions differ (rosbag2's /events/write_split beside a `ros2 bag record` on Jazzy)."""

from __future__ import annotations

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from taiji2_runtime.bag.writer import BagWriter, definition_and_hash
from taiji2_runtime.typestore import rihs01, typestore

#: types whose Humble and Jazzy definitions differ (rosbags' stores), and a contract type
TYPES = ["rosbag2_interfaces/msg/WriteSplitEvent", "rmw_dds_common/msg/ParticipantEntitiesInfo",
         "sensor_msgs/msg/Range", "taiji2_msgs/msg/GrsVoltages", "std_msgs/msg/String"]
#: a message's bytes (never decoded here: opening the bag checks the definitions and hashes)
PAYLOAD = b"\x00\x01\x00\x00" + bytes(64)


def test_embedded_definitions_hash_to_the_stored_hash_which_is_the_graphs(tmp_path, monkeypatch):
    monkeypatch.delenv("ROS_DISTRO", raising=False)
    store = typestore()
    writer = BagWriter(tmp_path / "bag", store)
    for index, msgtype in enumerate(TYPES):
        writer.write(writer.add_topic(f"/t{index}", msgtype), index, PAYLOAD)
        _, digest = definition_and_hash(store, msgtype)
        assert digest == rihs01(msgtype), msgtype  # the hash Jazzy endpoints advertise
    writer.close()
    with AnyReader([tmp_path / "bag"]) as reader:  # raised "hash mismatch" for WriteSplitEvent before
        embedded = {c.msgtype: c.digest for c in reader.connections}
    assert embedded == {t: rihs01(t) for t in TYPES}
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    assert "node_name" in [name for name, _ in jazzy.fielddefs["rosbag2_interfaces/msg/WriteSplitEvent"][1]]


def test_on_humble_the_workspace_definition_goes_with_its_own_hash(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DISTRO", "humble")
    writer = BagWriter(tmp_path / "bag", typestore())
    writer.write(writer.add_topic("/events/write_split", "rosbag2_interfaces/msg/WriteSplitEvent"), 0, PAYLOAD)
    writer.close()
    with AnyReader([tmp_path / "bag"]) as reader:
        (connection,) = reader.connections
    assert connection.digest == get_typestore(Stores.ROS2_HUMBLE).hash_rihs01("rosbag2_interfaces/msg/WriteSplitEvent")
