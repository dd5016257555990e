"""onboard_executor (onboard): the time-based schedule of ECSS PUS service 11 and the maneuver it flies.

Takes the TC transfer frames the uplink delivers (``/onboard/link/tc``; each frame with its onboard
arrival time) and, once the onboard clock reaches a frame's arrival, in the order of arrival whatever the
order the bursts came in, authenticates it before anything else reads it (SDLS,
:class:`taiji2_runtime.packets.sdls.FrameVerifier` with the onboard key table ``key_file``): a refused
frame (truncated, oversized, bad FECF or header, no or unknown or revoked SPI, bad MAC, replayed or
out-of-window sequence number) is counted per reason on ``/diagnostics`` and in a frame security
report (TM[3,25]) in telemetry, and nothing of it is read further. The telecommand packet of an
authentic frame that is not a valid TC[11,4] is refused with ``TM[1,2]`` (its defect's code). Each
valid ``TC[11,4]`` inserts its activities into :class:`taiji2_sim_pkg.core.onboard_schedule.OnboardSchedule`
at its arrival, which refuses an activity due before arrival + time margin (late: never executed late)
or beyond the capacity; acceptance ``TM[1,1]`` and completion ``TM[1,7]`` / ``TM[1,8]`` (refused
activities counted, code late or capacity) are reported in telemetry (``/onboard/link/tm_reports``,
taken by the telemetry packetizer; APID 0x141). Each verification report is sent twice, the same packet
again ``report_repeat_s`` later: the downlink loses packets (in bursts), and a table whose reports are
all lost would stay unverified on the ground; the ground keeps the first copy (same sequence count and
time, a duplicate). Releases each activity at its onboard time: on the
onboard bus ``/onboard/taiji2/maneuver/command`` it publishes, at every tick of ``publish_rate_hz``
up to ``lookahead_s`` ahead of the clock (time-tagged, as maneuver_commander, so the accelerated
simulator runs in lock-step), the torque of the last activity released at or before each stamp, but
never beyond the time through which the uplink is complete (the link's stamp): what it commands for
a time cannot change afterwards. Parameters: ``config/onboard_executor.yaml``.
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Sequence
from typing import Any

from taiji2_model.contract import COMMAND_TOPIC
from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.packetize import PacketError
from taiji2_runtime.packets.scheduling import (
    ACCEPTANCE_FAILURE_CODES,
    FAILURE_CAPACITY,
    FAILURE_LATE,
    decode_insert_activities,
    encode_report,
)
from taiji2_runtime.packets.sdls import (
    DEFAULT_REPLAY_WINDOW,
    REFUSAL_REASONS,
    FrameRefused,
    FrameVerifier,
    encode_frame_security_report,
)
from taiji2_runtime.packets.sdls_keys import KeyFileError, KeyTable, key_file_warning, load_key_file
from taiji2_runtime.packets.tc_frame import MAX_FRAME_OCTETS, FrameError, split_frames
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.onboard_schedule import OnboardSchedule

_NS = 1_000_000_000
REPORTS_TOPIC = "/onboard/link/tm_reports"



class OnboardExecutor(rclpy.node.Node):
    """The onboard command executor (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("onboard_executor", **node_kwargs)
        dp = self.declare_parameter
        capacity = dp("schedule_capacity", 3000, read_only("activities the onboard schedule holds")).value
        margin = dp("time_margin_s", 60.0, read_only(
            "an activity due within this time of its arrival is refused [s]")).value
        rate_hz = dp("publish_rate_hz", 10.0, read_only("command rate on the onboard bus [Hz]")).value
        self._lookahead_ns = round(_NS * dp("lookahead_s", 10.0, read_only(
            "publish time-tagged commands this far ahead of the clock [s]")).value)
        self._period_ns = round(_NS / rate_hz)
        key_file = dp("key_file", "", read_only(
            "the onboard SDLS key table (a key file, docs/security.md); empty: no keys, every frame refused")).value
        window = dp("replay_window", DEFAULT_REPLAY_WINDOW, read_only(
            "anti-replay window: a frame's sequence number at most this far above the last accepted")).value
        max_frame = dp("max_frame_octets", MAX_FRAME_OCTETS, read_only("longest TC frame accepted [octets]")).value
        repeat_s = dp("report_repeat_s", 10.0, read_only(
            "send each verification report again this much later, the same packet [s]; 0: once")).value
        if repeat_s < 0:
            raise ValueError(f"parameter report_repeat_s = {repeat_s}: must be >= 0 s")
        self._repeat_ns = round(_NS * repeat_s)
        self.verifier = FrameVerifier(self._key_table(key_file), window=window, max_frame_octets=max_frame)
        self.schedule = OnboardSchedule(capacity, margin)
        self._horizon_ns = -1  # the uplink is complete through this onboard time
        self._arrived: list[tuple[int, int, bytes]] = []  # heap (arrival [ns], n, frame) of frames not yet read
        self._frames_in = 0
        self._fsr_ns = -1  # the time of the last frame security report [ns]
        self._next_ns = 0
        self._reports: list[tuple[int, bytes]] = []
        self._report_seq = 0
        self._tables = 0
        self._invalid = 0
        qos = lt.reliable_all()
        t = messages.taiji2_msgs
        self._cmd_pub = self.create_publisher(messages.geometry_msgs.WrenchStamped,
                                              lt.onboard(COMMAND_TOPIC), qos)
        self._report_pub = self.create_publisher(t.SpacePackets, REPORTS_TOPIC, qos)
        self._diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(t.SpacePackets, lt.ONBOARD_TC, self._on_telecommands, qos)
        self.create_timer(1.0 / rate_hz, self._on_tick)
        steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
        self._first_timer = self.create_timer(0.05, self._first_tick, clock=steady)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)

    def _key_table(self, key_file: str) -> KeyTable:
        if not key_file:
            self.get_logger().error("no key_file: every telecommand frame will be refused (unknown SPI)")
            return KeyTable()
        try:
            table = load_key_file(key_file)
        except KeyFileError as exc:
            self.get_logger().error(f"{exc}: every telecommand frame will be refused")
            return KeyTable()
        warning = key_file_warning(key_file)
        if warning:
            self.get_logger().warn(warning)
        return table

    def _on_telecommands(self, msg: Any) -> None:
        """Hold each frame of a burst until the onboard time reaches its arrival (:meth:`_take_arrived`).

        Bursts reach this node in DDS order, which across writers (the link, an intruder's transmitter) is
        not the order the frames reach the spacecraft; a frame is read in the order of its arrival time."""
        try:
            frames = split_frames(bytes(msg.data))
            if len(frames) != len(msg.times_ns):
                raise FrameError("truncated", f"{len(frames)} frames but {len(msg.times_ns)} times")
        except FrameError as exc:  # nothing of a burst that does not divide into its frames is read
            self.verifier.count_refused(exc.kind)
            self.get_logger().warn(f"telecommand burst refused: {exc}", throttle_duration_sec=10.0)
            self._report_frame_security(self.get_clock().now().nanoseconds)
            return
        for frame, arrival_ns in zip(frames, msg.times_ns, strict=True):
            self._frames_in += 1
            heapq.heappush(self._arrived, (int(arrival_ns), self._frames_in, frame))
        self._horizon_ns = max(self._horizon_ns, lt.stamp_ns(msg.header))

    def _take_arrived(self, through_ns: int) -> None:
        """Authenticate and execute, in arrival order, every held frame that has arrived by ``through_ns``."""
        refused_at = -1
        while self._arrived and self._arrived[0][0] <= through_ns:
            arrival_ns, _, frame = heapq.heappop(self._arrived)
            try:
                packet = self.verifier.verify(frame)
            except FrameRefused as exc:
                refused_at = arrival_ns
                self.get_logger().warn(f"telecommand frame refused: {exc}", throttle_duration_sec=10.0)
                continue
            self._on_packet(packet, arrival_ns)
        if refused_at >= 0:
            self._report_frame_security(refused_at)

    def _report_frame_security(self, t_ns: int) -> None:
        """A TM[3,25] of the counts now, stamped ``t_ns`` or, if later, the previous one's time: the counts
        are cumulative and the ground keeps the latest report."""
        self._fsr_ns = max(self._fsr_ns, t_ns)
        self._report(encode_frame_security_report(self.verifier.report(), self._fsr_ns, self._report_seq),
                     self._fsr_ns)

    def _on_packet(self, packet: bytes, arrival_ns: int) -> None:
        """One authenticated telecommand packet, arrived onboard at ``arrival_ns``."""
        try:
            tc, commands = decode_insert_activities(packet)
        except PacketError as exc:
            self._invalid += 1
            self._verification(encode_report(2, packet, arrival_ns, self._report_seq,
                                             ACCEPTANCE_FAILURE_CODES.get(exc.kind, 0)), arrival_ns)
            self.get_logger().warn(f"telecommand refused at acceptance (TM[1,2]): {exc}")
            return
        late, full = self.schedule.insert(arrival_ns / _NS, [(c.execute_onboard_ns / _NS, tuple(c.torque_n_m))
                                                             for c in commands])
        self._tables += 1
        self._verification(encode_report(1, tc, arrival_ns, self._report_seq), arrival_ns)
        if late or full:
            code = FAILURE_LATE if late else FAILURE_CAPACITY
            self._verification(encode_report(8, tc, arrival_ns, self._report_seq, code, late + full), arrival_ns)
            self.get_logger().warn(f"TC[11,4] #{tc.seq_count} arriving at {arrival_ns / _NS:.1f} s: {late} "
                                   f"activities refused as late, {full} for capacity (never executed)")
        else:
            self._verification(encode_report(7, tc, arrival_ns, self._report_seq), arrival_ns)

    def _report(self, packet: bytes, t_ns: int) -> None:
        self._reports.append((t_ns, packet))
        self._report_seq += 1

    def _verification(self, packet: bytes, t_ns: int) -> None:
        """A TM[1,x] report: sent now and, the same packet, ``report_repeat_s`` later."""
        self._report(packet, t_ns)
        if self._repeat_ns > 0:
            self._reports.append((t_ns + self._repeat_ns, packet))

    def _first_tick(self) -> None:
        if self._horizon_ns >= 0 and self._cmd_pub.get_subscription_count() > 0:
            self._on_tick()
            self._first_timer.cancel()

    def _on_tick(self) -> None:
        if self._horizon_ns < 0:
            return  # nothing known of the uplink yet: commanding now could be contradicted later
        until = min(self.get_clock().now().nanoseconds + self._lookahead_ns, self._horizon_ns)
        self._take_arrived(until)
        published = -1
        while self._next_ns <= until:
            torque = self.schedule.torque_at(self._next_ns / _NS)
            msg = messages.geometry_msgs.WrenchStamped()
            lt.set_stamp(msg.header, self._next_ns)
            msg.header.frame_id = "crf"
            msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = (float(v) for v in torque)
            self._cmd_pub.publish(msg)
            published = self._next_ns
            self._next_ns += self._period_ns
        if published < 0:
            return
        ready = [r for r in self._reports if r[0] <= published]
        self._reports = [r for r in self._reports if r[0] > published]
        ready.sort(key=lambda r: r[0])
        self._report_pub.publish(lt.burst([p for _, p in ready], [t for t, _ in ready], published))

    def _publish_diagnostics(self) -> None:
        d = messages.diagnostic_msgs
        s = self.schedule
        refused = s.refused_late + s.refused_full
        sec = self.verifier
        frames_refused = {r: sec.refused[r] for r in REFUSAL_REASONS if sec.refused[r]}
        status = d.DiagnosticStatus(name="onboard_executor", hardware_id="taiji2_onboard")
        status.level = (d.DiagnosticStatus.WARN if refused or self._invalid or frames_refused
                        else d.DiagnosticStatus.OK)
        problems = []
        if frames_refused:
            problems.append(f"telecommand frames refused: {sum(frames_refused.values())} ("
                            + ", ".join(f"{k} {n}" for k, n in frames_refused.items()) + ")")
        if self._invalid:
            problems.append(f"{self._invalid} telecommands refused at acceptance (TM[1,2])")
        if refused:
            problems.append(f"{s.refused_late} activities refused as late, {s.refused_full} for capacity")
        status.message = "; ".join(problems) or "nominal"
        values = {"tables": self._tables, "inserted": s.inserted, "refused_late": s.refused_late,
                  "refused_full": s.refused_full, "invalid_telecommands": self._invalid,
                  "uplink_complete_through_s": self._horizon_ns / _NS, "frames_accepted": sec.accepted,
                  "frames_refused": {r: sec.refused[r] for r in REFUSAL_REASONS},
                  "last_spi": sec.report(clear_flags=False).last_spi}
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in values.items()]
        self._diag_pub.publish(d.DiagnosticArray(status=[status]))


def main(args: Sequence[str] | None = None) -> int:
    return run_node(OnboardExecutor, args)


if __name__ == "__main__":
    raise SystemExit(main())
