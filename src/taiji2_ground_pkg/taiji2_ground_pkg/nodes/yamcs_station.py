"""yamcs_station (ground): the ground station's front end to Yamcs. Every packet the ground station receives
(``/ground/link/tm``: in reception order, with the link's duplicates, gaps and playback as they come) goes
to the Yamcs instance's ``ground-station`` data link over TCP (:mod:`taiji2_ground_pkg.mcs.station`);
Yamcs archives and decodes them with the XTCE database.

Yamcs's link is the TCP client: the node listens on ``station_port`` and Yamcs connects at its next retry
(every 10 s). Packets received before Yamcs connects, or while it reconnects, wait in order. (Asking Yamcs
through its API to reconnect at once, by disabling and enabling the link, made it open a second connection
over the first in one run of test_experiment_yamcs.py, and what was in flight on the first, 37 packets, was
lost: the node does not ask.)

With ``key_file`` set, the node is also the ground station's uplink when the planner commands through Yamcs
(command_planner ``yamcs_url``): each telecommand Yamcs sends on the link (a TC[11,4] the planner issued,
with Yamcs's sequence count and CRC) is matched to its table of the plan (``/ground/commanding/plan``, by the
digest of its application data), and once every planned table has come, they are signed as SDLS-secured TC
Transfer Frames (in plan order, as the planner signs without Yamcs) and handed to the link
(``/ground/link/tc``), each held until its pass as planned. A telecommand that is not in the plan (e.g. an
operator's own) is counted and not uplinked: the link carries one plan per run. Where Yamcs signs the
telecommands itself (its SDLS frame link, ``taiji2 ground serve --sdls-key-file``; ``frame_port``), its frames
come by UDP (:mod:`taiji2_ground_pkg.mcs.frame_receiver`), are opened with ``key_file`` only to read which
table each carries, and go to the uplink as Yamcs made them.

With ``yamcs_url`` set, it also sets the ground's parameters in Yamcs
(:mod:`taiji2_ground_pkg.mcs.ground_parameters`):
the latest estimates of G and d of both GRS with their sigma and missing samples
(``/taiji2/estimates/grs{1,2}/{scale_factors,com_offset}``) and the link's health (``/ground/link/reception``),
at most once a second from a thread of its own; Yamcs checks their alarm ranges (sigma above the requirement,
data missing); on stop it pushes the last values. Its account goes on ``/diagnostics`` once a second
(packets received, sent to Yamcs, queued; Yamcs connected; parameter pushes) and, at the end of the data,
on ``/ground/yamcs_station`` (latched JSON). Parameters: ``config/yamcs_station.yaml``.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Sequence
from typing import Any

from taiji2_ground_pkg.mcs.commanding import table_digest
from taiji2_ground_pkg.mcs.frame_receiver import FrameReceiver
from taiji2_ground_pkg.mcs.ground_parameters import estimate_values, reception_values
from taiji2_ground_pkg.mcs.parameter_writer import ParameterWriter
from taiji2_ground_pkg.mcs.station import StationFrontEnd
from taiji2_ground_pkg.nodes.command_planner import PLAN_TOPIC
from taiji2_ground_pkg.uplink_signer import frame_signer
from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.sdls_keys import KeyFileError, load_key_file
from taiji2_runtime.ros import messages, rclpy

REPORT_TOPIC = "/ground/yamcs_station"


class YamcsStation(rclpy.node.Node):
    """The front end (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("yamcs_station", **node_kwargs)
        dp = self.declare_parameter
        port = int(dp("station_port", 10015, read_only(
            "the TCP port the instance's ground-station link connects to (taiji2 ground serve --station-port)")).value)
        key_file = str(dp("key_file", "", read_only(
            "SDLS key file the telecommands from Yamcs are signed with before the uplink (docs/security.md); "
            "empty: no uplink here")).value)
        spi = int(dp("spi", -1, read_only("SPI to sign with (-1: the key file's highest active SPI)")).value)
        first_sequence = int(dp("first_sequence", 1, read_only(
            "the first frame's SDLS sequence number (IV counter); above the last the spacecraft accepted")).value)
        frame_port = int(dp("frame_port", 0, read_only(
            "the UDP port where Yamcs's own SDLS frame link sends its signed frames (taiji2 ground serve "
            "--sdls-key-file): they are uplinked as Yamcs made them, key_file only reads them; 0: Yamcs sends "
            "packets on its ground-station link and this node signs them")).value)
        self._tc_lock = threading.Lock()
        self._from_yamcs: dict[str, bytes] = {}  # digest -> the first telecommand of that table Yamcs sent
        self._yamcs_frames: dict[str, bytes] = {}  # digest -> Yamcs's own frame of that table (frame_port)
        self._frames = None
        self._tc_repeats = 0
        self._plan: list[dict[str, Any]] | None = None
        self._uplinked = 0
        self._signer, self._key_problem = None, ""
        if key_file and frame_port:
            self._frames = self._frame_receiver(frame_port, key_file)
        elif key_file:
            self._signer, self._key_problem, warning = frame_signer(key_file, spi, first_sequence)
            if self._key_problem:
                self.get_logger().error(f"{self._key_problem} (the spacecraft refuses frames without a valid MAC)")
            elif warning:
                self.get_logger().warn(warning)
        try:
            self._station = StationFrontEnd(port, on_telecommand=self._on_telecommand if key_file else None)
        except OSError as exc:  # one error line naming the parameter, not a traceback
            raise ValueError(f"station_port {port}: cannot listen on 127.0.0.1 ({exc.strerror or exc})") from None
        url = str(dp("yamcs_url", "", read_only(
            "the instance (yamcs://HOST:PORT/INSTANCE) whose ground parameters (estimates, link health) this "
            "node sets; empty: packets only")).value)
        self._received = 0
        self._end = False
        self.create_subscription(messages.taiji2_msgs.SpacePackets, lt.GROUND_TM, self._on_packets, lt.reliable_all())
        self._parameters = self._parameter_writer(url) if url else None
        if key_file:
            self._tc_pub = self.create_publisher(messages.taiji2_msgs.SpacePackets, lt.GROUND_TC, lt.reliable_all())
            self.create_subscription(messages.std_msgs.String, PLAN_TOPIC, self._on_plan, lt.latched())
            self._uplink_timer = self.create_timer(0.05, self._uplink, clock=rclpy.clock.Clock(
                clock_type=rclpy.clock.ClockType.STEADY_TIME))
        self._report_pub = self.create_publisher(messages.std_msgs.String, REPORT_TOPIC, lt.latched())
        self._diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME))

    def _parameter_writer(self, url: str) -> ParameterWriter:
        from taiji2_ground_pkg.mcs.yamcs_api import parse_yamcs_url, set_parameters

        parse_yamcs_url(url)  # a bad address: one error line at start (GroundError)
        writer = ParameterWriter(lambda values: set_parameters(url, values))
        reliable = rclpy.qos.QoSProfile(depth=10, reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        t = messages.taiji2_msgs
        for g in (1, 2):
            for kind, cls in (("scale_factors", t.ScaleFactorEstimate), ("com_offset", t.ComOffsetEstimate)):
                self.create_subscription(cls, f"/taiji2/estimates/grs{g}/{kind}",
                                         lambda m: writer.update(estimate_values(m)), reliable)
        self.create_subscription(messages.std_msgs.String, "/ground/link/reception",
                                 lambda m: writer.update(reception_values(json.loads(m.data))), lt.reliable_all())
        return writer

    def _frame_receiver(self, port: int, key_file: str) -> FrameReceiver:
        """Yamcs's frames on UDP ``port``, read with the key table of ``key_file`` (ValueError naming either)."""
        try:
            keys = load_key_file(key_file)
        except KeyFileError as exc:
            raise ValueError(f"key_file: {exc}") from None
        try:
            return FrameReceiver(port, keys, self._on_yamcs_frame)
        except OSError as exc:
            raise ValueError(f"frame_port {port}: cannot listen on 127.0.0.1 ({exc.strerror or exc})") from None

    def _on_yamcs_frame(self, frame: bytes, packet: bytes) -> None:
        """(The frame receiver's thread.) One of Yamcs's signed frames, kept under its table's digest."""
        self._keep(self._yamcs_frames, packet, frame)

    def _on_telecommand(self, packet: bytes) -> None:
        """(The station's reader thread.) One telecommand from Yamcs, kept under its table's digest."""
        self._keep(self._from_yamcs, packet, packet)

    def _keep(self, store: dict[str, bytes], packet: bytes, item: bytes) -> None:
        """``item`` under the digest of ``packet``'s table, the first one only (a repeat is counted)."""
        digest = table_digest(packet)
        with self._tc_lock:
            if digest in store:
                self._tc_repeats += 1
            else:
                store[digest] = item

    def _on_plan(self, msg: Any) -> None:
        self._plan = json.loads(msg.data)

    def _uplink(self) -> None:
        """Once every planned table came from Yamcs: sign them in plan order and hand them to the link."""
        if self._plan is None or self._tc_pub.get_subscription_count() == 0:
            return
        if self._frames is not None:  # Yamcs signed them
            with self._tc_lock:
                frames = [self._yamcs_frames.get(p["digest"]) for p in self._plan]
            if any(f is None for f in frames):
                return
            signer = "Yamcs's SDLS frame link"
        else:
            if self._signer is None:
                return
            with self._tc_lock:
                packets = [self._from_yamcs.get(p["digest"]) for p in self._plan]
            if any(p is None for p in packets):
                return
            frames = [self._signer.sign(p) for p in packets]
            signer = f"this node (SPI {self._signer.spi})"
        ready_ns = [round(p["ready_s"] * 1e9) for p in self._plan]
        self._tc_pub.publish(lt.burst(frames, ready_ns, lt.END_NS, end_of_data=True))
        self._uplinked = len(frames)
        self._uplink_timer.cancel()
        self.get_logger().info(f"{len(frames)} telecommand(s) from Yamcs, signed by {signer}, handed to the uplink")

    def _on_packets(self, msg: Any) -> None:
        packets = lt.split(msg)
        self._received += len(packets)
        self._station.send(packets)
        if msg.end_of_data and not self._end:
            self._end = True
            self._publish_report()

    def report(self) -> dict[str, Any]:
        """Packets received from the link, written to Yamcs, still queued; Yamcs's connections so far."""
        report = {"received": self._received, "sent": self._station.sent_packets, "queued": self._station.queued(),
                  "connections": self._station.connections, "end_of_data": self._end}
        if self._signer is not None or self._key_problem or self._frames is not None:
            with self._tc_lock:
                matched = {p["digest"] for p in self._plan or []}
                came = set(self._yamcs_frames if self._frames is not None else self._from_yamcs)
                report.update(telecommands=self._frames.frames if self._frames else self._station.telecommands,
                              planned=len(self._plan or []), matched=len(matched & came),
                              signed_by="yamcs" if self._frames is not None else "station",
                              frames_refused=dict(self._frames.refused) if self._frames else {},
                              not_in_plan=len(came - matched) if self._plan is not None else None,
                              repeated=self._tc_repeats, uplinked=self._uplinked, key_problem=self._key_problem)
        if self._parameters is not None:
            report.update(parameter_pushes=self._parameters.pushes, parameter_failures=self._parameters.failures,
                          parameter_error=self._parameters.last_error)
        return report

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
        if self._frames is not None:
            self._frames.close()
        if self._parameters is not None:
            self._parameters.close()
        self._station.close()
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    return run_node(YamcsStation, args)


if __name__ == "__main__":
    raise SystemExit(main())
