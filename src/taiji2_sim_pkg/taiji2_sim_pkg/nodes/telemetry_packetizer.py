"""telemetry_packetizer (onboard): the spacecraft's raw samples -> CCSDS telemetry packets for the transmitter.

Subscribes to the onboard bus (``/onboard/taiji2/star_tracker``, ``.../grs1/voltages``,
``.../grs2/voltages`` and the executed command ``.../maneuver/command``), makes one packet per sample
(:func:`taiji2_runtime.packets.packetize.encode_packet`: APID per stream, 14-bit sequence count per
APID, CUC onboard time = the sample's stamp, CRC) and publishes them on ``/onboard/link/tm`` as
``taiji2_msgs/SpacePackets`` bursts in onboard-time order (ties: star tracker, GRS1, GRS2, executed
torque), each burst complete through its stamp: once every stream has passed a time, nothing older
can follow. Because the order is fixed by the stamps and not by arrival, the link downstream is
deterministic. ``end_of_data_s``: the run's last sample time; once every sensor stream has reached
it, the rest goes out with ``end_of_data``. Parameters: ``config/telemetry_packetizer.yaml``.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from typing import Any

from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.definition import STREAMS
from taiji2_runtime.packets.packetize import encode_packet
from taiji2_runtime.ros import messages, rclpy
from taiji2_runtime.subscribed_publisher import hold_until_subscribed

_NS = 1_000_000_000



class TelemetryPacketizer(rclpy.node.Node):
    """Packetizes the onboard raw streams (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("telemetry_packetizer", **node_kwargs)
        self._burst_ns = round(_NS * self.declare_parameter(
            "burst_period_s", 1.0, read_only("onboard time per published burst [s]")).value)
        end_s = self.declare_parameter("end_of_data_s", -1.0, read_only(
            "the run's last sample time [s]: at it the telemetry ends (end_of_data); -1: never")).value
        self._end_ns = round(end_s * _NS) if end_s >= 0 else None
        self._command_margin_ns = round(_NS * self.declare_parameter("command_end_margin_s", 0.1, read_only(
            "at the end, the executed-command stream need only have reached end_of_data_s minus this [s] (a "
            "command stamped at or after end_of_data_s acts after the run: not telemetry of it)")).value)
        reports = self.declare_parameter("command_reports", False, read_only(
            "also take the onboard executor's report packets (/onboard/link/tm_reports) into the telemetry")).value
        t = messages.taiji2_msgs
        qos = lt.reliable_all()
        self._pending: list[tuple[int, int, int, bytes]] = []  # heap (time, stream order, n, packet)
        self._n = 0
        self._seq = [0] * len(STREAMS)
        self._latest = [-1] * (len(STREAMS) + bool(reports))  # the sensors, the command, the reports' horizon
        self._sent_through = -1
        self._ended = False
        (self._pub,) = hold_until_subscribed(self, [self.create_publisher(t.SpacePackets, lt.ONBOARD_TM, qos)],
                                             lt.ONBOARD_TM)
        self.create_subscription(t.StarTracker, lt.onboard(STREAMS[0].topic), self._on_star_tracker, qos)
        for k in (1, 2):
            self.create_subscription(t.GrsVoltages, lt.onboard(STREAMS[k].topic),
                                     lambda m, k=k: self._on_grs(m, k), qos)
        self.create_subscription(messages.geometry_msgs.WrenchStamped, lt.onboard(STREAMS[3].topic),
                                 self._on_command, qos)
        if reports:
            self.create_subscription(t.SpacePackets, "/onboard/link/tm_reports", self._on_reports, qos)

    def _add(self, k: int, t_ns: int, values: Sequence[float]) -> None:
        beyond = self._end_ns is not None and (t_ns > self._end_ns or (k == 3 and t_ns >= self._end_ns))
        if t_ns <= self._latest[k] or self._ended or beyond:
            if beyond and k == 3:
                self._latest[3] = max(self._latest[3], t_ns)  # the command stream has passed the end
            return  # a repeated or late stamp, or beyond the run: not telemetry of this run
        self._latest[k] = t_ns
        packet = encode_packet(STREAMS[k], self._seq[k], t_ns, values)
        self._seq[k] += 1
        self._n += 1
        heapq.heappush(self._pending, (t_ns, k, self._n, packet))
        self._flush()

    def _on_reports(self, msg: Any) -> None:
        if self._ended:
            return
        for packet, t_ns in zip(lt.split(msg), msg.times_ns, strict=True):
            if self._end_ns is None or t_ns < self._end_ns:
                self._n += 1
                heapq.heappush(self._pending, (int(t_ns), len(STREAMS), self._n, packet))
        self._latest[-1] = max(self._latest[-1], lt.stamp_ns(msg.header))
        self._flush()

    def _flush(self) -> None:
        through = min(min(self._latest), self._end_ns if self._end_ns is not None else min(self._latest))
        end = (self._end_ns is not None and min(self._latest[:3]) >= self._end_ns
               and min(self._latest[3:]) >= self._end_ns - self._command_margin_ns)
        if not end and through - self._sent_through < self._burst_ns:
            return
        if end:
            through = self._end_ns
        packets, times = [], []
        while self._pending and self._pending[0][0] <= through:
            t_ns, _, _, packet = heapq.heappop(self._pending)
            packets.append(packet)
            times.append(t_ns)
        self._sent_through = through
        self._pub.publish(lt.burst(packets, times, through, end_of_data=end))
        if end:
            self._ended = True
            self.get_logger().info(f"end of data at t = {through / _NS:.1f} s: {sum(self._seq)} packets")

    def _on_star_tracker(self, msg: Any) -> None:
        a = msg.attitude
        self._add(0, lt.stamp_ns(msg.header), [a.x, a.y, a.z, a.w, *msg.attitude_covariance])

    def _on_grs(self, msg: Any, k: int) -> None:
        self._add(k, lt.stamp_ns(msg.header), [msg.vx1, msg.vx2, msg.vy1, msg.vy2, msg.vz1, msg.vz2])

    def _on_command(self, msg: Any) -> None:
        w = msg.wrench
        self._add(3, lt.stamp_ns(msg.header), [w.torque.x, w.torque.y, w.torque.z, w.force.x, w.force.y, w.force.z])


def main(args: Sequence[str] | None = None) -> int:
    return run_node(TelemetryPacketizer, args)


if __name__ == "__main__":
    raise SystemExit(main())
