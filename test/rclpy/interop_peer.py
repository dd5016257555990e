"""One side of the interop test: every taiji2 message type, sent and echoed back.

``python interop_peer.py echo``: republish each ``/interop/<Type>/ping`` message unchanged on
``/interop/<Type>/pong`` until SIGINT. ``python interop_peer.py drive``: publish one filled message of
each type on the ping topics, wait for the pongs, print one JSON line per type with what was sent and
what came back; exit 0 when every type came back equal. The runtime is whatever
``taiji2_runtime.ros`` picks (``TAIJI2_RUNTIME``), so either side can be rclpy or the embedded runtime.
"""

from __future__ import annotations

import json
import sys
import time

from taiji2_runtime.interfaces import to_plain
from taiji2_runtime.ros import messages, rclpy

TYPES = ("GrsVoltages", "StarTracker", "ScaleFactorEstimate", "ComOffsetEstimate", "SpacePackets")
TIMEOUT_S = 60.0


def _filled(name: str) -> object:
    """A message with every field set to a value that a wrong decoder would not reproduce."""
    msg = getattr(messages.taiji2_msgs, name)()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 2_000_000_001, 999_999_999
    msg.header.frame_id = "tmrf2-\u00fc"
    if name == "GrsVoltages":
        msg.grs_id = 255
        msg.vx1, msg.vx2, msg.vy1, msg.vy2, msg.vz1, msg.vz2 = 1e-300, -0.0, 1.5, -2.25, 1e300, 3.0e-7
    elif name == "StarTracker":
        msg.attitude.x, msg.attitude.y, msg.attitude.z, msg.attitude.w = 0.1, -0.2, 0.3, 0.927
        msg.attitude_covariance = [1e-10 * (k + 1) for k in range(9)]
    elif name == "SpacePackets":
        msg.data = [0, 255, 7, 129, 64, 3]
        msg.times_ns = [-(2**63), 0, 2**63 - 1]
        msg.transmitted_through_ns = -1
        msg.end_of_data = True
    else:
        msg.grs_id = 2
        msg.method = "gls"
        msg.samples_missing, msg.latency_s = 123, float("inf")
        msg.covariance = [-(k + 0.5) for k in range(9)]
        msg.samples_used, msg.samples_rejected = 4_294_967_295, 7
        msg.nis, msg.nis_mean = 2.5, 0.99
        if name == "ScaleFactorEstimate":
            msg.scale_factors = [5.5e-8, 5.6e-8, 7.4e-8]
            msg.cross_covariance = [1e-20 * k for k in range(9)]
        else:
            msg.offset.x, msg.offset.y, msg.offset.z = 5e-4, -0.18, 1.35e-6
    return msg


def _qos() -> object:
    # transient-local: a pong written before the driver's reader matched the echo's writer (the graph
    # already lists the writer, DDS has not matched it yet) is still delivered
    return rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE,
                                durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)


def echo(node: object) -> None:
    for name in TYPES:
        cls = getattr(messages.taiji2_msgs, name)
        pong = node.create_publisher(cls, f"/interop/{name}/pong", _qos())
        node.create_subscription(cls, f"/interop/{name}/ping", pong.publish, _qos())
    # spin_once with a timeout until shutdown: SIGINT ends the loop at the next wake-up at the latest (once in
    # CI, an echo in rclpy.spin(node) did not end within 60 s of SIGINT)
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.1)


def drive(node: object) -> int:
    sent = {name: _filled(name) for name in TYPES}
    received: dict[str, object] = {}
    pings = {}
    for name in TYPES:
        cls = getattr(messages.taiji2_msgs, name)
        pings[name] = node.create_publisher(cls, f"/interop/{name}/ping", _qos())
        node.create_subscription(cls, f"/interop/{name}/pong", lambda m, k=name: received.setdefault(k, m), _qos())
    deadline = time.monotonic() + TIMEOUT_S
    while (any(p.get_subscription_count() < 1 for p in pings.values())
           or any(node.count_publishers(f"/interop/{n}/pong") < 1 for n in TYPES)):
        rclpy.spin_once(node, timeout_sec=0.1)
        if time.monotonic() > deadline:
            print("error: the echo peer did not match within 60 s", file=sys.stderr)
            return 1
    for name in TYPES:
        pings[name].publish(sent[name])
    while len(received) < len(TYPES) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    equal = True
    for name in TYPES:
        back = to_plain(received[name]) if name in received else None
        equal &= back == to_plain(sent[name])
        print(json.dumps({"type": name, "sent": to_plain(sent[name]), "received": back}))
    return 0 if equal else 1


def main() -> int:
    rclpy.init(args=sys.argv)
    node = rclpy.create_node(f"interop_{sys.argv[1]}")
    try:
        return drive(node) if sys.argv[1] == "drive" else echo(node) or 0
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
