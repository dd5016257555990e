"""ground_receiver (ground): the packets the ground station received -> the raw-data contract topics, in order.

Subscribes to ``/ground/link/tm`` and runs :class:`taiji2_ground_pkg.reception.GroundReception`:
per APID in sequence-count order, each count once (duplicates dropped), real-time data held until
the played-back data before them have arrived, gaps declared lost once the spacecraft's
transmitted-through time has passed them. Publishes what it releases on the contract topics
(``/taiji2/star_tracker``, ``/taiji2/grs{1,2}/voltages``, ``/taiji2/maneuver/command`` from the
executed-torque packets; header stamp = onboard time through the time correlation) in stamp order,
so the estimators, the recorder and ``taiji2 calibrate`` get in-order data with gaps. The onboard
executor's verification reports (APID 0x141, PUS TM[1,x]) are decoded, deduplicated and passed on in
the reception record (``command_reports``); its frame security reports (APID 0x141, TM[3,25]: the uplink
frames the spacecraft refused, per reason) likewise, the latest in ``frame_security``. After each
burst it publishes on ``/ground/link/reception`` (JSON) the ground time, the onboard time through
which each stream has been released and the counts (received, released, duplicate, out_of_order,
missing, held), and the same on ``/diagnostics`` (WARN naming missing samples) once a second of wall
time, at once when its level changes, and at the end of the data (a playback burst brings a reception
record per telemetry burst, ~100 a second; each on ``/diagnostics`` cost CPU here, in the recorder and
in every monitor for nothing a person or ``rqt_robot_monitor`` reads). Parameters:
``config/ground_receiver.yaml``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_ground_pkg.reception import GroundReception, ReleasedSample
from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.packetize import PacketError
from taiji2_runtime.packets.scheduling import REPORT_APID, decode_report
from taiji2_runtime.packets.sdls import decode_frame_security_report, is_frame_security_report
from taiji2_runtime.packets.time_correlation import TimeCorrelation
from taiji2_runtime.ros import messages, rclpy
from taiji2_runtime.subscribed_publisher import hold_until_subscribed

_NS = 1_000_000_000
_FRAMES = {"grs1": "tmrf1", "grs2": "tmrf2"}
#: wall time between the receiver's /diagnostics [s] (as the other nodes' health timers)
DIAGNOSTICS_PERIOD_S = 1.0


class GroundReceiver(rclpy.node.Node):
    """Depacketizes the received telemetry in order (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("ground_receiver", **node_kwargs)
        offset_s = self.declare_parameter("time_correlation_offset_s", 0.0, read_only(
            "contract time of the onboard clock's zero [s] (contract = offset + rate x onboard)")).value
        rate = self.declare_parameter("time_correlation_rate", 1.0, read_only("onboard clock rate")).value
        self._correlation = TimeCorrelation(float(offset_s), float(rate))
        self._rx = GroundReception()
        qos = lt.reliable_all()
        t, g = messages.taiji2_msgs, messages.geometry_msgs
        topics = dict(zip(("star_tracker", "grs1", "grs2", "executed_torque"), lt.CONTRACT_TOPICS, strict=True))
        types = {"star_tracker": t.StarTracker, "grs1": t.GrsVoltages, "grs2": t.GrsVoltages,
                 "executed_torque": g.WrenchStamped}
        held = hold_until_subscribed(self, [*(self.create_publisher(types[name], topic, qos)
                                              for name, topic in topics.items()),
                                            self.create_publisher(messages.std_msgs.String, lt.RECEPTION_TOPIC, qos)],
                                     ", ".join([*topics.values(), lt.RECEPTION_TOPIC]))
        self._pubs = dict(zip(topics, held[:-1], strict=True))
        self._reception_pub = held[-1]
        self._diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(t.SpacePackets, lt.GROUND_TM, self._on_burst, qos)
        self._ground_ns = -1
        self._ended = False
        self._samples_out = 0
        self._reports_seen: set[tuple[int, int]] = set()
        self._report_packets = 0  # verification and frame security reports decoded (duplicates included)
        self._new_reports: list[dict[str, Any]] = []
        self._frame_security: dict[str, Any] | None = None  # the latest frame security report (onboard time order)
        self._last_diagnostics: tuple[float, int] | None = None  # (monotonic time, level) of the last sent
        self._unsent_state: dict[str, Any] | None = None  # a reception record not yet on /diagnostics
        steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics, clock=steady)

    def _on_burst(self, msg: Any) -> None:
        try:
            packets = lt.split(msg)
        except ValueError as exc:  # nothing of a burst that does not divide into its packets is read
            self._rx.rejected["unsplittable_burst"] += 1
            self.get_logger().error(f"burst refused: {exc}", throttle_duration_sec=10.0)
            return
        for packet, receive_ns in zip(packets, msg.times_ns, strict=True):
            if lt.apid_of(packet) == REPORT_APID and is_frame_security_report(packet):
                self._on_frame_security(packet, int(receive_ns))
            elif lt.apid_of(packet) == REPORT_APID:
                self._on_report(packet, int(receive_ns))
            else:
                self._rx.offer(packet, int(receive_ns))
        if msg.times_ns:
            self._ground_ns = max(self._ground_ns, int(msg.times_ns[-1]))
        through = int(msg.transmitted_through_ns)
        released = self._rx.finish() if msg.end_of_data else self._rx.release(through if through >= 0 else None)
        if released:
            # the contract stamps of the whole burst in one call (numpy's per-call cost, per packet, was a
            # tenth of this node's CPU)
            stamps = self._correlation.to_contract_ns(np.array([r.sample.onboard_ns for r in released],
                                                                dtype=np.int64))
            for r, t_ns in zip(released, stamps.tolist(), strict=True):
                self._publish_sample(r, t_ns)
        self._ended = bool(msg.end_of_data)
        self._publish_reception()

    def _on_report(self, packet: bytes, receive_ns: int) -> None:
        try:
            r = decode_report(packet)
        except PacketError as exc:
            self._rx.rejected[f"report_{exc.kind}"] += 1
            return
        self._report_packets += 1
        key = (r.subtype, r.tc_seq_count)
        if key in self._reports_seen:
            return  # a duplicate
        self._reports_seen.add(key)
        self._new_reports.append({"subtype": r.subtype, "tc_seq": r.tc_seq_count, "onboard_s": r.onboard_ns / _NS,
                                  "ground_s": receive_ns / _NS, "failure_code": r.failure_code,
                                  "refused": r.refused})

    def _on_frame_security(self, packet: bytes, receive_ns: int) -> None:
        try:
            fsr, onboard_ns = decode_frame_security_report(packet)
        except PacketError as exc:
            self._rx.rejected[f"report_{exc.kind}"] += 1
            return
        self._report_packets += 1
        last = self._frame_security
        if last is not None and (onboard_ns, fsr.total()) <= (last["onboard_ns"], last["total"]):
            return  # a duplicate or an older one played back late (at one time: the counts only grow)
        self._frame_security = {"onboard_s": onboard_ns / _NS, "onboard_ns": onboard_ns, "total": fsr.total(),
                                "ground_s": receive_ns / _NS,
                                "fsr": f"0x{fsr.fsr_word():08X}", "alarm": fsr.alarm, "last_spi": fsr.last_spi,
                                "accepted": fsr.accepted, "refused": fsr.refused}

    def _publish_sample(self, r: ReleasedSample, t_ns: int) -> None:
        """Publish one released sample on its contract topic, stamped ``t_ns`` (contract time [ns])."""
        s = r.sample
        name = s.stream.name
        v = s.values.tolist()
        m = messages
        if name == "star_tracker":
            msg = m.taiji2_msgs.StarTracker()
            msg.header.frame_id = "crf"
            msg.attitude.x, msg.attitude.y, msg.attitude.z, msg.attitude.w = v[:4]
            msg.attitude_covariance = v[4:13]
        elif name in _FRAMES:
            msg = m.taiji2_msgs.GrsVoltages(grs_id=int(name[-1]))
            msg.header.frame_id = _FRAMES[name]
            msg.vx1, msg.vx2, msg.vy1, msg.vy2, msg.vz1, msg.vz2 = v
        else:
            msg = m.geometry_msgs.WrenchStamped()
            msg.header.frame_id = "crf"
            w = msg.wrench
            w.torque.x, w.torque.y, w.torque.z, w.force.x, w.force.y, w.force.z = v
        lt.set_stamp(msg.header, int(t_ns))
        self._pubs[name].publish(msg)
        self._samples_out += 1

    def reception(self) -> dict[str, Any]:
        """Ground time, the onboard time released through per stream, the counts, end of data."""
        return {"ground_time_s": self._ground_ns / _NS if self._ground_ns >= 0 else None,
                "released_through_s": {k: (v / _NS if v >= 0 else None)
                                       for k, v in self._rx.released_through_ns().items()},
                "counts": self._rx.counts(), "rejected": dict(self._rx.rejected), "end_of_data": self._ended,
                "command_reports": self._new_reports, "command_reports_total": len(self._reports_seen),
                "report_packets": self._report_packets,
                "frame_security": self._frame_security}

    def _publish_reception(self) -> None:
        state = self.reception()
        self._new_reports = []
        self._reception_pub.publish(messages.std_msgs.String(data=json.dumps(state)))
        self._unsent_state = state
        last = self._last_diagnostics
        if last is None or self._ended or self._level(state) != last[1] \
                or time.monotonic() - last[0] >= DIAGNOSTICS_PERIOD_S:
            self._publish_diagnostics()

    @staticmethod
    def _level(state: dict[str, Any]) -> int:
        d = messages.diagnostic_msgs.DiagnosticStatus
        return d.WARN if any(c["missing"] for c in state["counts"].values()) else d.OK

    def _publish_diagnostics(self) -> None:
        """The last reception record on ``/diagnostics`` (the health timer's tick: if not sent yet)."""
        state, self._unsent_state = self._unsent_state, None
        if state is None:
            return
        d = messages.diagnostic_msgs
        missing = {k: c["missing"] for k, c in state["counts"].items() if c["missing"]}
        status = d.DiagnosticStatus(name="ground_receiver", hardware_id="taiji2_ground")
        status.level = self._level(state)
        self._last_diagnostics = (time.monotonic(), status.level)
        status.message = ("samples lost on the link: " + ", ".join(f"{k} {n}" for k, n in missing.items())
                          if missing else "nominal")
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in state.items()]
        array = d.DiagnosticArray(status=[status])
        lt.set_stamp(array.header, max(self._ground_ns, 0))
        self._diag_pub.publish(array)

def main(args: Sequence[str] | None = None) -> int:
    return run_node(GroundReceiver, args)


if __name__ == "__main__":
    raise SystemExit(main())
