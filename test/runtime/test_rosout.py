"""Log lines of embedded nodes reach ``/rosout`` as rcl_interfaces/msg/Log (what rcl does for rclpy)."""

from __future__ import annotations

import pytest

from taiji2_runtime.dds_rclpy.rosout import qos_profile_rosout_default
from taiji2_runtime.ros import messages, rclpy

from support import spin_until

pytestmark = pytest.mark.embedded_runtime(reason=(
    "the embedded runtime's own /rosout publisher; rcl's logging provides it under rclpy"
))


def test_node_log_lines_and_child_logger_lines_arrive_on_rosout(context, executor):
    talker = rclpy.node.Node("chatty", namespace="/lab", context=context)
    listener = rclpy.node.Node("console", context=context, enable_rosout=False)
    executor.add_node(listener)
    received: list = []
    listener.create_subscription(messages.rcl_interfaces.Log, "/rosout", received.append, qos_profile_rosout_default)
    talker.get_logger().warning("pressure low")
    talker.get_logger().get_child("valve").error("stuck")
    talker.get_logger().debug("below the default level: not logged, not published")

    assert spin_until(executor, lambda: len(received) >= 2)  # transient-local: earlier lines are kept
    lines = [(m.name, m.level, m.msg) for m in received]
    assert lines == [("lab.chatty", 30, "pressure low"), ("lab.chatty.valve", 40, "stuck")]
    assert received[0].file.endswith("test_rosout.py") and received[0].line > 0
