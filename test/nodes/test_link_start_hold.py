"""The link relays hold their output until the readers they wait for have matched them
(nodes/subscribed_publisher.py): a ground reader that subscribes after the data went through the chain still
gets every sample and every reception record, in order."""

from __future__ import annotations

import json

import numpy as np
import pytest

from taiji2_ground_pkg.nodes.ground_receiver import GroundReceiver
from taiji2_runtime.domain import reserve_private_domain
from taiji2_runtime.ros import messages, rclpy
from taiji2_runtime.subscribed_publisher import SubscribedPublisher
from taiji2_sim_pkg.nodes.space_link import SpaceLink
from taiji2_sim_pkg.nodes.telemetry_packetizer import TelemetryPacketizer

from support import ground_reader, spin_until

N = 100  # samples of 0.1 s
TOPICS = {"/taiji2/star_tracker": "StarTracker", "/taiji2/grs1/voltages": "GrsVoltages",
          "/taiji2/grs2/voltages": "GrsVoltages"}


def _publish_run(source_pubs, t):
    for k in range(1, N + 1):
        stamp = divmod(k * 100_000_000, 1_000_000_000)
        st = t.StarTracker()
        st.header.stamp.sec, st.header.stamp.nanosec = stamp
        st.header.frame_id = "crf"
        st.attitude.z, st.attitude.w = np.sin(0.01 * k), np.cos(0.01 * k)
        source_pubs["/taiji2/star_tracker"].publish(st)
        for gid in (1, 2):
            msg = t.GrsVoltages(grs_id=gid)
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
            msg.header.frame_id = f"tmrf{gid}"
            msg.vx1 = 0.01 * k
            source_pubs[f"/taiji2/grs{gid}/voltages"].publish(msg)
        cmd = messages.geometry_msgs.WrenchStamped()
        cmd.header.stamp.sec, cmd.header.stamp.nanosec = stamp
        cmd.header.frame_id = "crf"
        source_pubs["command"].publish(cmd)


@pytest.fixture
def private_graph():
    """A context and executor on a DDS domain of their own: the test counts the readers of the contract topics,
    which any other graph on the domain would add to (under real rclpy the suite shares one domain, and nodes of
    earlier tests can outlive their context until collected)."""
    reservation = reserve_private_domain()
    context = rclpy.context.Context()
    rclpy.init(args=["test"], context=context, domain_id=reservation.domain_id)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    try:
        yield context, executor
    finally:
        for node in executor.get_nodes():
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
        reservation.release()


def test_a_reader_that_matches_after_the_data_passed_gets_all_of_it(private_graph):
    context, executor = private_graph
    nodes = [TelemetryPacketizer(context=context, cli_args=["--ros-args", "-p", f"end_of_data_s:={N / 10}",
                                                            "-p", "wait_for_subscribers:=[1]"]),
             SpaceLink(context=context, cli_args=["--ros-args", "-p", "wait_for_subscribers:=[1, 0]"]),
             GroundReceiver(context=context, cli_args=["--ros-args", "-p", "wait_for_subscribers:=[1, 1, 1, 0, 1]"])]
    receiver = nodes[-1]
    source = rclpy.node.Node("onboard_source", context=context)
    for n in (*nodes, source):
        executor.add_node(n)
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                               reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
    t = messages.taiji2_msgs
    pubs = {topic: source.create_publisher(getattr(t, name), "/onboard" + topic, qos) for topic, name in TOPICS.items()}
    pubs["command"] = source.create_publisher(messages.geometry_msgs.WrenchStamped, "/onboard/taiji2/maneuver/command",
                                              qos)
    assert spin_until(executor, lambda: all(p.get_subscription_count() > 0 for p in pubs.values()))
    _publish_run(pubs, t)
    # the whole run reaches the receiver, which holds it: no ground reader yet
    held = receiver._reception_pub.held
    assert spin_until(executor, lambda: bool(held) and json.loads(held[-1].data)["end_of_data"], timeout_s=60.0)
    assert all(len(receiver._pubs[name].held) > 0.9 * N for name in ("star_tracker", "grs1", "grs2"))
    # a ground reader comes only now
    observer = rclpy.node.Node("late_ground_reader", context=context)
    executor.add_node(observer)
    got, reception = ground_reader(observer, TOPICS, qos)
    assert spin_until(executor, lambda: bool(reception) and reception[-1]["end_of_data"], timeout_s=60.0)
    final = reception[-1]["counts"]
    assert spin_until(executor, lambda: all(len(got[tp]) == final[s]["released"] for tp, s in
                                            zip(TOPICS, ("star_tracker", "grs1", "grs2"), strict=True)), timeout_s=30.0)
    for topic in TOPICS:  # the ideal link: every sample, from the first, in order
        k = [round((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec) / 1e8) for m in got[topic]]
        assert k == list(range(1, N + 1))
    assert [r["end_of_data"] for r in reception].count(True) == 1 and len(reception) > 1


class _Writer:
    def __init__(self):
        self.matched, self.sent = 0, []

    def get_subscription_count(self):
        return self.matched

    def publish(self, msg):
        self.sent.append(msg)


def test_held_messages_go_out_in_order_once_the_readers_are_there():
    writer = _Writer()
    out = SubscribedPublisher(writer, 2)
    out.publish(1)
    out.publish(2)
    writer.matched = 1
    assert not out.release() and writer.sent == []
    out.publish(3)
    writer.matched = 2
    out.publish(4)  # the first publish with the readers there sends what was held first
    assert writer.sent == [1, 2, 3, 4] and out.held == []
    writer.matched = 0  # a reader that goes away later is not waited for again
    out.publish(5)
    assert writer.sent[-1] == 5
    assert SubscribedPublisher(_Writer(), 0).open
    with pytest.raises(ValueError, match="wait_for_subscribers"):
        SubscribedPublisher(_Writer(), -1)
