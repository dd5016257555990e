"""space_link: the deep-space link between the onboard and the ground side (docs/link.md).

Thin ROS glue around :class:`taiji2_sim_pkg.core.link.Downlink` and :class:`~taiji2_sim_pkg.core.link.Uplink`.

* Downlink: takes the onboard telemetry bursts (``/onboard/link/tm``, complete through their stamp),
  offers each packet to the model at its onboard generation time, advances the model to the burst's
  stamp and publishes what the ground has received by then on ``/ground/link/tm`` (reception times,
  the transmitted-through time, complete through stamp + light time). The model runs on the data's
  own time, so accelerated runs are exact and a seed gives the same link whatever the DDS timing.
  At ``end_of_data`` it plays back what is still stored over the following passes and ends.
* Uplink: telecommand bursts from the ground (``/ground/link/tc``: SDLS-secured TC transfer frames, each
  stamped with the ground time from which it may be sent) go out in the next pass at the uplink rate and
  reach ``/onboard/link/tc`` one light time later (each frame with its onboard arrival time); lost ones are
  counted and named. The link carries frames as they are: it neither checks nor changes them.
* ``/diagnostics`` names each link fault (a missed pass, the onboard memory overwriting, a lost
  uplink) with counts; ``/taiji2/sim/link_report`` (latched JSON, evaluation only) is the link's own
  account per stream. Parameters: ``config/space_link.yaml``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.definition import STREAM_BY_APID, TC_APID
from taiji2_runtime.packets.scheduling import REPORT_APID
from taiji2_runtime.ros import messages, rclpy
from taiji2_runtime.subscribed_publisher import hold_until_subscribed
from taiji2_sim_pkg.core.link import Downlink, Uplink, load_link_model

_NS = 1_000_000_000
#: packets per published burst at most
MAX_BURST_PACKETS = 4096



def _apid_name(apid: int) -> str:
    if apid in STREAM_BY_APID:
        return STREAM_BY_APID[apid].name
    return "command_reports" if apid == REPORT_APID else "telecommands" if apid == TC_APID else f"apid_0x{apid:03X}"


class SpaceLink(rclpy.node.Node):
    """The link node (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("space_link", **node_kwargs)
        model_name = self.declare_parameter("model", "ideal", read_only(
            "link model: a preset of config/link.yaml (ideal, deep_space) or a YAML file")).value
        seed = self.declare_parameter("seed", 0, read_only("seed of the loss and duplicate draws")).value
        missed = self.declare_parameter("missed_contacts", [-1], read_only(
            "more faults: passes missed entirely (0 = the first; -1: none)")).value
        lost_up = self.declare_parameter("lost_uplinks", [-1], read_only(
            "more faults: passes whose uplink is lost (-1: none)")).value
        self.model = load_link_model(model_name).with_faults([k for k in missed if k >= 0],
                                                             [k for k in lost_up if k >= 0])
        self.downlink = Downlink(self.model, int(seed))
        self.uplink = Uplink(self.model, int(seed))
        self._lt_ns = round(self.model.light_time_s * _NS)
        self._through_ns = -1
        self._ended = False
        self._faults: dict[str, str] = {}
        self._uplink_lost: list[dict[str, Any]] = []
        t = messages.taiji2_msgs
        qos = lt.reliable_all()
        self._ground_tm, self._onboard_tc = hold_until_subscribed(
            self, [self.create_publisher(t.SpacePackets, lt.GROUND_TM, qos),
                   self.create_publisher(t.SpacePackets, lt.ONBOARD_TC, qos)], f"{lt.GROUND_TM}, {lt.ONBOARD_TC}")
        self._report_pub = self.create_publisher(messages.std_msgs.String, lt.LINK_REPORT_TOPIC, lt.latched())
        self._diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(t.SpacePackets, lt.ONBOARD_TM, self._on_telemetry, qos)
        self.create_subscription(t.SpacePackets, lt.GROUND_TC, self._on_telecommands, qos)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME))
        self.get_logger().info(f"link model {self.model.name}: light time {self.model.light_time_s:g} s, "
                               f"contacts {self.model.contacts.to_dict()}, seed {seed}")

    # -- downlink --------------------------------------------------------------------------------------
    def _on_telemetry(self, msg: Any) -> None:
        if self._ended:
            return
        try:
            packets = lt.split(msg)
        except ValueError as exc:
            self.get_logger().error(f"telemetry burst refused: {exc}", throttle_duration_sec=10.0)
            return
        through_ns = lt.stamp_ns(msg.header)
        for packet, t_ns in zip(packets, msg.times_ns, strict=True):
            self.downlink.offer(t_ns / _NS, lt.apid_of(packet), packet)
        self._through_ns = max(self._through_ns, through_ns)
        if msg.end_of_data:
            self._ended = True
            deliveries = self.downlink.advance(through_ns / _NS) + self.downlink.drain()
            self._deliver(deliveries, lt.END_NS, end=True)
            stuck = self.downlink.stored_at_end
            self.get_logger().info(f"end of data: played back; {sum(stuck.values())} packets never transmitted")
            self._publish_report()
            self._publish_diagnostics()
        else:
            self._deliver(self.downlink.advance(through_ns / _NS), through_ns + self._lt_ns)

    def _deliver(self, deliveries: list[Any], complete_through_ns: int, end: bool = False) -> None:
        """Publish ``deliveries`` in bursts of at most :data:`MAX_BURST_PACKETS` (a playback after the end of
        the data is days of telemetry): each complete through the next one's first reception."""
        if not deliveries and not end:
            return
        chunks = [deliveries[i:i + MAX_BURST_PACKETS] for i in range(0, len(deliveries), MAX_BURST_PACKETS)] or [[]]
        for j, chunk in enumerate(chunks):
            last = j == len(chunks) - 1
            through = round(chunk[-1].transmitted_through_s * _NS) if chunk else -1
            complete = complete_through_ns if last else round(chunks[j + 1][0].receive_s * _NS)
            self._ground_tm.publish(lt.burst([d.packet for d in chunk], [round(d.receive_s * _NS) for d in chunk],
                                             complete, transmitted_through_ns=through, end_of_data=end and last))

    # -- uplink ----------------------------------------------------------------------------------------
    def _on_telecommands(self, msg: Any) -> None:
        try:
            packets = lt.split_tc_frames(msg)
        except ValueError as exc:
            self.get_logger().error(f"telecommand burst refused: {exc}", throttle_duration_sec=10.0)
            return
        arrived, times = [], []
        for packet, ready_ns in zip(packets, msg.times_ns, strict=True):
            d = self.uplink.send(ready_ns / _NS, packet)
            if d is None or d.lost:
                reason = "no pass left to send it in" if d is None else d.reason
                self._uplink_lost.append({"ready_s": ready_ns / _NS, "pass": None if d is None else d.contact,
                                          "reason": reason})
                self._faults["uplink lost"] = (f"{len(self._uplink_lost)} telecommand frame(s) lost on the "
                                               f"uplink (last: {reason})")
                self.get_logger().warn(f"telecommand frame ready at {ready_ns / _NS:.1f} s lost on the uplink: "
                                       f"{reason}")
                continue
            arrived.append(d.packet)
            times.append(round(d.arrival_s * _NS))
        self._onboard_tc.publish(lt.burst(arrived, times, lt.stamp_ns(msg.header) + self._lt_ns,
                                          end_of_data=msg.end_of_data))

    # -- reporting -------------------------------------------------------------------------------------
    def report(self) -> dict[str, Any]:
        """The link's own account: per stream and the faults."""
        d = self.downlink
        missed = sorted(k for k in self.model.missed_contacts)
        return {"model": self.model.to_dict(),
                "streams": {_apid_name(a): s.to_dict() for a, s in sorted(d.stats.items())},
                "contacts_used": sorted(d.contacts_used), "missed_contacts": missed,
                "memory_peak_octets": d.memory_peak_octets,
                "overwrite_started_s": d.overwrite_started_s,
                "never_transmitted": {_apid_name(a): n for a, n in sorted(d.stored_at_end.items())},
                "uplink": {"sent": self.uplink.sent, "lost": len(self._uplink_lost), "lost_packets": self._uplink_lost},
                "faults": dict(self._faults)}

    def _publish_report(self) -> None:
        self._report_pub.publish(messages.std_msgs.String(data=json.dumps(self.report())))

    def _check_faults(self) -> None:
        now_s = self._through_ns / _NS
        for k in sorted(self.model.missed_contacts):
            for index, start, _ in self.model.contacts.passes():
                if index >= k:
                    if index == k and start <= now_s + self.model.light_time_s:
                        self._faults[f"missed contact {k}"] = f"pass {k} at {start:.0f} s missed entirely"
                    break
        if self.downlink.overwrite_started_s is not None:
            n = sum(s.overwritten for s in self.downlink.stats.values())
            self._faults["onboard memory full"] = (
                f"outage longer than the onboard memory: {n} packets overwritten since "
                f"t = {self.downlink.overwrite_started_s:.0f} s")

    def _publish_diagnostics(self) -> None:
        self._check_faults()
        d = messages.diagnostic_msgs
        status = d.DiagnosticStatus(name="space_link", hardware_id="taiji2_link")
        status.level = d.DiagnosticStatus.WARN if self._faults else d.DiagnosticStatus.OK
        status.message = "; ".join(f"{k}: {v}" for k, v in self._faults.items()) or "nominal"
        s = self.downlink.stats.values()
        values = {"model": self.model.name, "onboard_time_s": self._through_ns / _NS,
                  "generated": sum(x.generated for x in s), "delivered": sum(x.delivered for x in s),
                  "lost": sum(x.lost for x in s), "duplicated": sum(x.duplicated for x in s),
                  "overwritten": sum(x.overwritten for x in s), "stored_octets": self.downlink.stored_octets,
                  "uplink_lost": len(self._uplink_lost), "faults": sorted(self._faults)}
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in values.items()]
        array = d.DiagnosticArray(status=[status])
        lt.set_stamp(array.header, max(self._through_ns, 0))
        self._diag_pub.publish(array)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SpaceLink, args)


if __name__ == "__main__":
    raise SystemExit(main())
