"""A late joiner gets the latest estimate, not the history (issue 26 row 3): estimate publishers are reliable,
transient local, keep-last 1. Runs on the embedded runtime and, in the rclpy tier, on rclpy."""

from __future__ import annotations

import math

from test_node_parameters import RawFeeder

from taiji2_estimator_pkg.nodes.com_offset_estimator import ComOffsetEstimatorNode
from taiji2_estimator_pkg.nodes.scale_factor_estimator import ScaleFactorEstimatorNode
from taiji2_runtime.ros import messages, rclpy

from support import spin_until

N = 1200  # 120 s at 10 Hz: G is determined well before the end


def _stamp(m) -> float:
    return m.header.stamp.sec + m.header.stamp.nanosec * 1e-9


def test_a_late_subscriber_gets_only_the_latest_estimate(context, executor):
    args = ["--ros-args", "-p", "max_stream_silence_s:=0.5"]
    nodes = [ScaleFactorEstimatorNode(context=context, cli_args=args),
             ComOffsetEstimatorNode(context=context, cli_args=args)]
    for node in nodes:
        executor.add_node(node)
    feeder = RawFeeder(context, executor, N)
    feeder.wait_for_readers(2)
    last = feeder.feed()
    d_stamps: list[float] = []
    feeder.node.create_subscription(messages.taiji2_msgs.ComOffsetEstimate, "/taiji2/estimates/grs1/com_offset",
                                    lambda m: d_stamps.append(_stamp(m)), 100)
    assert spin_until(executor, lambda: feeder.stamps and abs(feeder.stamps[-1] - last) < 1e-6
                      and d_stamps and abs(d_stamps[-1] - last) < 1e-6, timeout_s=60)
    spin_until(executor, lambda: False, timeout_s=1.0)  # the end of data: nothing is published any more
    # as `ros2 topic echo` subscribes to a transient-local publisher: transient local, keep-all (history given)
    late = rclpy.node.Node("late_joiner", context=context)
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                               durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
    got: dict[str, list] = {"scale_factors": [], "com_offset": [], "difference": []}
    t = messages.taiji2_msgs
    late.create_subscription(t.ScaleFactorEstimate, "/taiji2/estimates/grs1/scale_factors",
                             got["scale_factors"].append, qos)
    late.create_subscription(t.ComOffsetEstimate, "/taiji2/estimates/grs2/com_offset", got["com_offset"].append, qos)
    late.create_subscription(t.ComOffsetEstimate, "/taiji2/estimates/com_offset_difference",
                             got["difference"].append, qos)
    executor.add_node(late)
    assert spin_until(executor, lambda: all(got.values()), timeout_s=30)
    spin_until(executor, lambda: False, timeout_s=0.5)  # anything more would arrive now
    assert [len(v) for v in got.values()] == [1, 1, 1], {k: [_stamp(m) for m in v] for k, v in got.items()}
    sf, d = got["scale_factors"][0], got["com_offset"][0]
    assert abs(_stamp(sf) - last) < 1e-6 and sf.samples_used == N  # the latest, not the t = 0.1 s one
    assert all(math.isfinite(v) for v in sf.scale_factors)  # determined (d needs longer: NaN until then)
    assert d_stamps and abs(_stamp(d) - d_stamps[-1]) < 1e-9 and d.samples_used == N
