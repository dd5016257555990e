"""yamcs_station (ground): the ground station's front end to Yamcs. Every packet the ground station receives
(``/ground/link/tm``: in reception order, with the link's duplicates, gaps and playback as they come) goes
to the Yamcs instance's ``ground-station`` data link over TCP (:mod:`taiji2_ground_pkg.mcs.station`);
Yamcs archives and decodes them with the XTCE database.

Yamcs's link is the TCP client: the node listens on ``station_port`` and Yamcs connects at its next retry
(every 10 s). Packets received before Yamcs connects, or while it reconnects, wait in order. (Asking Yamcs
through its API to reconnect at once, by disabling and enabling the link, made it open a second connection
over the first in one run of test_experiment_yamcs.py, and what was in flight on the first, 37 packets, was
lost: the node does not ask.) Its account goes on
``/diagnostics`` once a second (packets received, sent to Yamcs, queued; Yamcs connected) and, at the
end of the data, on ``/ground/yamcs_station`` (latched JSON). Parameters: ``config/yamcs_station.yaml``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from taiji2_ground_pkg.mcs.station import StationFrontEnd
from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.ros import messages, rclpy

REPORT_TOPIC = "/ground/yamcs_station"


class YamcsStation(rclpy.node.Node):
    """The front end (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("yamcs_station", **node_kwargs)
        dp = self.declare_parameter
        port = int(dp("station_port", 10015, read_only(
            "the TCP port the instance's ground-station link connects to (taiji2 ground serve --station-port)")).value)
        try:
            self._station = StationFrontEnd(port)
        except OSError as exc:  # one error line naming the parameter, not a traceback
            raise ValueError(f"station_port {port}: cannot listen on 127.0.0.1 ({exc.strerror or exc})") from None
        self._received = 0
        self._end = False
        self.create_subscription(messages.taiji2_msgs.SpacePackets, lt.GROUND_TM, self._on_packets, lt.reliable_all())
        self._report_pub = self.create_publisher(messages.std_msgs.String, REPORT_TOPIC, lt.latched())
        self._diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME))

    def _on_packets(self, msg: Any) -> None:
        packets = lt.split(msg)
        self._received += len(packets)
        self._station.send(packets)
        if msg.end_of_data and not self._end:
            self._end = True
            self._publish_report()

    def report(self) -> dict[str, Any]:
        """Packets received from the link, written to Yamcs, still queued; Yamcs's connections so far."""
        return {"received": self._received, "sent": self._station.sent_packets, "queued": self._station.queued(),
                "connections": self._station.connections, "end_of_data": self._end}

    def _publish_report(self) -> None:
        self._report_pub.publish(messages.std_msgs.String(data=json.dumps(self.report())))

    def _publish_diagnostics(self) -> None:
        d = messages.diagnostic_msgs
        report = self.report()
        connected = report["connections"] > 0
        status = d.DiagnosticStatus(name="yamcs_station", hardware_id="ground",
                                    level=d.DiagnosticStatus.OK if connected else d.DiagnosticStatus.WARN,
                                    message="Yamcs connected" if connected else "waiting for Yamcs's link")
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in report.items()]
        self._diag_pub.publish(d.DiagnosticArray(status=[status]))
        if self._end:
            self._publish_report()  # the counts move on while the queue drains

    def destroy_node(self) -> None:
        self._station.close()
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    return run_node(YamcsStation, args)


if __name__ == "__main__":
    raise SystemExit(main())
