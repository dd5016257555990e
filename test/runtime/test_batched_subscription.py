"""create_batched_subscription (issue 26 row 9): every message once, in order, on either runtime; under rclpy a
callback takes what is queued (up to the batch) instead of one message per wait-set pass."""

from __future__ import annotations

from taiji2_runtime.batched import create_batched_subscription
from taiji2_runtime.ros import RUNTIME, messages, rclpy

from support import spin_until


def test_every_message_once_in_order(context, executor):
    node = rclpy.node.Node("batched_probe", context=context)
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                               reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(messages.std_msgs.String, "/batched_probe", qos)
    got: list[str] = []
    passes = []
    sub = create_batched_subscription(node, messages.std_msgs.String, "/batched_probe",
                                      lambda m: got.append(m.data), qos, batch=16)
    executor.add_node(node)
    assert spin_until(executor, lambda: pub.get_subscription_count() >= 1)
    for k in range(200):
        pub.publish(messages.std_msgs.String(data=str(k)))
    assert spin_until(executor, lambda: passes.append(len(got)) or len(got) >= 200, timeout_s=30)
    spin_until(executor, lambda: False, timeout_s=0.2)
    assert got == [str(k) for k in range(200)]
    if RUNTIME == "rclpy":  # fewer executor passes than messages: batches were taken
        assert len(set(passes)) < 200, len(set(passes))
    node.destroy_subscription(sub)
