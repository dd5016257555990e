"""spacecraft_sim: the spacecraft stand-in. Applies the received torque command and publishes the
star tracker and both GRS at the sample rate, plus ground truth under /taiji2/sim/.

Thin ROS glue around :class:`taiji2_sim_pkg.core.simulator.Simulator`; parameters are documented in
``config/spacecraft_sim.yaml``. Three clock modes:

``realtime``
    a wall timer steps the simulation at the sample rate; stamps are system time.
``accelerated``
    simulated time as fast as the graph allows: the node owns ``/clock`` and, with
    ``sync_with_command``, steps from t_k only once a command stamped >= t_k has arrived, so the
    run is deterministic and an edited or replayed command stream drives it. All raw topics are
    reliable keep-all, so every reliable subscriber gets every sample (lossless).
``follow``
    steps whenever the node clock (``use_sim_time``, e.g. ``taiji2 bag play --clock``) passes the
    next sample time.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import yaml

from taiji2_model.config import load_config
from taiji2_model.contract import (
    APPLIED_WRENCH_TOPIC,
    COMMAND_TOPIC,
    GRS_TOPICS,
    PROVENANCE_TOPIC,
    STAR_TRACKER_TOPIC,
    TRUE_ANGULAR_ACCELERATION_TOPIC,
    TRUE_ANGULAR_RATE_TOPIC,
    TRUE_ATTITUDE_TOPIC,
    TRUE_COM_OFFSET_TOPIC_OF,
    TRUE_SCALE_FACTOR_TOPIC_OF,
)
from taiji2_model.maneuver_choice import MANEUVER_HELP, choose_maneuver
from taiji2_runtime.entry import run_node
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.command_gate import CommandGate, CommandSchedule
from taiji2_sim_pkg.core.range_check import RangeMonitor
from taiji2_sim_pkg.core.simulator import SimOutput, SimSample, Simulator

TMRF_FRAMES = ("tmrf1", "tmrf2")
CLOCK_MODES = ("realtime", "accelerated", "follow")
_NS = 1_000_000_000
#: A command stamp further than this from the simulator's time is on another time base [ns].
TIME_BASE_TOLERANCE_NS = 3600 * _NS
#: Stamps after 2001-09-09 (1e9 s) are read as system (wall-clock) time in the WARN text [ns].
WALL_CLOCK_EPOCH_NS = 10**9 * _NS
#: Largest number of steps simulated in one call in accelerated mode (bounds latency of /clock).
_MAX_CHUNK_STEPS = 100


#: the 1-s diagnostics timer this much later than due is reported as a pause of the process [s]
_PAUSE_REPORTED_AFTER_S = 2.0


def _descriptor(description: str, **ranges: tuple[float, float]) -> Any:
    rcl = messages.rcl_interfaces
    # every parameter of the simulator is read once at start: read-only (ros2 param set is refused)
    descriptor = rcl.ParameterDescriptor(description=f"{description} [read-only: read at start]", read_only=True)
    if "float_range" in ranges:
        low, high = ranges["float_range"]
        descriptor.floating_point_range = [rcl.FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    if "int_range" in ranges:
        low, high = ranges["int_range"]
        descriptor.integer_range = [rcl.IntegerRange(from_value=int(low), to_value=int(high), step=0)]
    return descriptor


def _overrides(entries: Sequence[str]) -> dict[str, Any]:
    """``["noise.srp.enabled=false", ...]`` -> ``{"noise.srp.enabled": False}`` (YAML values)."""
    result: dict[str, Any] = {}
    for entry in entries:
        if "=" not in entry:
            raise ValueError(f"config_overrides: {entry!r} is not 'dotted.key=value'")
        key, text = entry.split("=", 1)
        result[key.strip()] = yaml.safe_load(text)
    return result


def _steady_clock() -> Any:
    return rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)


def _stamp(msg_header: Any, t_ns: int) -> None:
    msg_header.stamp.sec, msg_header.stamp.nanosec = divmod(int(t_ns), _NS)


class SpacecraftSim(rclpy.node.Node):
    """Publishes /taiji2/star_tracker and /taiji2/grsN/voltages from the simulated spacecraft."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("spacecraft_sim", **node_kwargs)
        dp = self.declare_parameter
        layout = dp("layout", "type1",
                    _descriptor("built-in layout (type1, type2), used when config_file is empty")).value
        config_file = dp("config_file", "", _descriptor("simulator config YAML; overrides layout")).value
        overrides = dp("config_overrides", [""], _descriptor("config overrides 'dotted.key=value'")).value
        seed = dp("seed", -1, _descriptor("run seed; -1 draws one and logs it", int_range=(-1, 2**62))).value
        self._mode = dp("clock_mode", "accelerated", _descriptor(f"one of {', '.join(CLOCK_MODES)}")).value
        if self._mode not in CLOCK_MODES:
            raise ValueError(f"clock_mode: {self._mode!r} is not one of {', '.join(CLOCK_MODES)}")
        duration_s = dp("duration_s", -1.0, _descriptor(
            "simulated duration [s]; -1: the end of the maneuver that maneuver names", float_range=(-1.0, 1e7))).value
        asked = dp("maneuver", "", _descriptor(
            f"the maneuver whose end is the default duration (the commander flies it): {MANEUVER_HELP}; "
            "empty: the default (with config_file: its own maneuver section)")).value
        self._sync = dp("sync_with_command", True, _descriptor(
            "accelerated: step from t_k only after a command stamped >= t_k arrived")).value
        self._command_timeout_s = dp("command_timeout_s", 2.0, _descriptor(
            "accelerated + sync: wall seconds to wait for a command before stepping with the last one",
            float_range=(0.0, 3600.0))).value
        self._wait_subscribers = dp("wait_for_subscribers", [0, 0, 0], _descriptor(
            "accelerated: start only once /taiji2/star_tracker, /taiji2/grs1/voltages and /taiji2/grs2/voltages "
            "have at least this many subscribers each", int_range=(0, 1000))).value
        if len(self._wait_subscribers) != 3:
            raise ValueError("wait_for_subscribers: expected 3 counts (star tracker, GRS1, GRS2), "
                             f"got {list(self._wait_subscribers)}")
        self._resubscribe_timeout_s = dp("resubscribe_timeout_s", 60.0, _descriptor(
            "accelerated: when a subscriber counted by wait_for_subscribers goes away (killed, restarting), "
            "hold the run this long for it to come back, then go on without it [s]",
            float_range=(0.0, 86400.0))).value
        self._exit_when_done = dp("exit_when_done", True, _descriptor("shut down after duration_s")).value
        self._publish_truth = dp("publish_truth", True, _descriptor("publish ground truth under /taiji2/sim/")).value
        truth_kinematics = dp("publish_truth_kinematics", True, _descriptor(
            "with publish_truth: also the per-step kinematic truth (angular rate and acceleration, attitude, "
            "applied wrench); false keeps G and d (1 Hz) only")).value
        self._linger_s = dp("linger_s", 1.0, _descriptor(
            "after the end, stay up this long before exiting, so that late subscribers (recorders) still get "
            "the latched provenance [s]", float_range=(0.0, 3600.0))).value

        config = load_config(config_file or layout, overrides=_overrides([o for o in overrides if o]))
        self._sim = Simulator(config, seed=None if seed < 0 else seed)
        self._dt_ns = round(config.dt_s * _NS)
        # overrides of the maneuver section describe the preset's square wave, modified
        if not asked and any(o.strip().startswith("maneuver.") for o in overrides if o):
            asked = "paper"
        # what the commander flies (the commands come on the topic): its end is the default duration, its
        # name goes into the provenance (bags and calibrate name it)
        self._maneuver = choose_maneuver(layout, asked or None, None, config_file=config_file, preset=config)
        end_s = self._maneuver.duration_s if duration_s < 0 else duration_s
        self._n_steps = round(end_s / config.dt_s)
        self._gate = CommandGate(config.thrusters.max_thrust_n * config.thrusters.lever_arm_m)
        self._schedule = CommandSchedule()
        self._range = RangeMonitor(config.grs.range_m_s2)
        self._started = False
        self._done = False
        self._t0_wall_ns = 0
        self._waiting_since = time.monotonic()
        self._late_commands = 0
        self._time_base_mismatches = 0
        self._last_diag_wall = time.monotonic()
        self._lost_since: float | None = None  # wall time [s] a counted subscriber went missing
        self._held_s = 0.0  # wall time the run was held for lost subscribers [s]
        self._reported_held_s = 0.0
        self._reported_late_commands = 0

        m = messages
        reliable_all = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                            reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        self._star_pub = self.create_publisher(m.taiji2_msgs.StarTracker, STAR_TRACKER_TOPIC, reliable_all)
        self._grs_pubs = [self.create_publisher(m.taiji2_msgs.GrsVoltages, t, reliable_all) for t in GRS_TOPICS]
        self._diag_pub = self.create_publisher(m.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self._clock_pub = (self.create_publisher(m.rosgraph_msgs.Clock, "/clock", 10)
                           if self._mode == "accelerated" else None)
        self._truth = _TruthPublishers(self, reliable_all, truth_kinematics) if self._publish_truth else None
        latched = rclpy.qos.QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        self._provenance_pub = self.create_publisher(m.std_msgs.String, PROVENANCE_TOPIC, latched)
        self._provenance_pub.publish(m.std_msgs.String(data=json.dumps(
            {**self._sim.provenance(), "maneuver": self._maneuver.provenance()})))
        self.create_subscription(m.geometry_msgs.WrenchStamped, COMMAND_TOPIC, self._on_command, reliable_all)

        if self._mode == "realtime":
            self.create_timer(config.dt_s, self._on_realtime_tick)
        elif self._mode == "follow":
            self.create_timer(config.dt_s, self._on_follow_tick)
        else:
            # wall-clock (steady) timer: in accelerated mode this node is the source of simulated time
            self.create_timer(0.0 if not self._sync else 0.05, self._on_accelerated_tick, clock=_steady_clock())
            # one-shot: armed by each command, runs after the queued callbacks
            self._step_timer = self.create_timer(0.0, self._on_step_timer, clock=_steady_clock())
            self._step_timer.cancel()
        self.create_timer(1.0, self._publish_diagnostics, clock=_steady_clock())
        self.get_logger().info(
            f"layout {config.layout}, seed {self._sim.seed}, {self._n_steps} steps of {config.dt_s} s, "
            f"clock mode {self._mode}"
            f"{' (lock-step with time-tagged commands)' if self._sync and self._mode == 'accelerated' else ''}")

    # -- commands ------------------------------------------------------------------------------
    def _on_command(self, msg: Any) -> None:
        torque = (msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z)
        reason = self._gate.offer(torque, msg.header.frame_id)
        if reason is not None:
            self.get_logger().warn(
                f"rejected command #{self._gate.rejected_total} on {COMMAND_TOPIC}: {reason}; "
                "keeping the last valid command", throttle_duration_sec=5.0)
            return
        stamp_ns = msg.header.stamp.sec * _NS + msg.header.stamp.nanosec
        self._check_time_base(stamp_ns)
        if not self._schedule.offer(stamp_ns, self._gate.torque_n_m):
            self.get_logger().warn(f"command stamped {stamp_ns / _NS:.3f} s arrived out of order; ignored",
                                   throttle_duration_sec=5.0)
        if self._mode == "accelerated" and self._sync and self._step_timer.is_canceled():
            self._step_timer.reset()  # step once the commands already queued are taken, in one chunk

    def _check_time_base(self, stamp_ns: int) -> None:
        """WARN once when commands are stamped on another time base than the simulator's."""
        sim_now_ns = self._t0_wall_ns + self._time_ns() if self._mode == "realtime" else self._time_ns()
        if abs(stamp_ns - sim_now_ns) <= TIME_BASE_TOLERANCE_NS:
            return
        self._time_base_mismatches += 1
        if self._time_base_mismatches > 1:
            return
        ours = "system (wall-clock) time" if self._mode == "realtime" else f"simulated time ({self._mode} mode)"
        theirs = "system (wall-clock) time" if stamp_ns > WALL_CLOCK_EPOCH_NS else "simulated time"
        self.get_logger().warn(
            f"command stamped {stamp_ns / _NS:.3f} s ({theirs}) but this simulator runs on {ours}, now "
            f"{sim_now_ns / _NS:.3f} s: the commander is on another time base, so its commands apply far in "
            "the past or future. Start the commander with `--ros-args -p use_sim_time:=true` (or this "
            "simulator with clock_mode:=realtime). Counted as time_base_mismatches on /diagnostics.")

    # -- stepping ------------------------------------------------------------------------------
    def _time_ns(self) -> int:
        return self._sim.step_index * self._dt_ns

    def _step_once(self, stamp_offset_ns: int = 0) -> None:
        if self._sim.step_index >= self._n_steps:  # never a sample past the end of the run
            return
        if self._mode == "realtime":
            torque = self._gate.torque_n_m  # wall-clock commanding: the latest valid command
        else:
            torque = self._schedule.command_at(self._time_ns())  # time-tagged: in effect at t_k
        sample = self._sim.step(torque)
        t_ns = self._time_ns() + stamp_offset_ns
        self._publish_sample(sample, t_ns)
        if self._sim.step_index >= self._n_steps:
            self._finish()

    def _on_realtime_tick(self) -> None:
        if self._done:
            return
        if not self._started:
            self._started, self._t0_wall_ns = True, self.get_clock().now().nanoseconds
        self._step_once(self._t0_wall_ns)

    def _on_follow_tick(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        while not self._done and now_ns >= self._time_ns() + self._dt_ns:
            self._step_once()

    def _ready_to_start(self) -> bool:
        pubs = [self._star_pub, *self._grs_pubs]
        return all(p.get_subscription_count() >= n for p, n in zip(pubs, self._wait_subscribers, strict=True))

    def _subscribers_missing(self) -> bool:
        """True while a subscriber counted by wait_for_subscribers is gone and resubscribe_timeout_s has not
        passed: the run is held so that a restarted estimator or recorder loses no more than it had."""
        if self._ready_to_start():
            if self._lost_since is not None:
                held = time.monotonic() - self._lost_since
                self._held_s += held
                self.get_logger().info(f"subscribers back after {held:.1f} s; run continues")
                self._lost_since = None
            return False
        now = time.monotonic()
        if self._lost_since is None:
            self._lost_since = now
            self.get_logger().warn(
                f"a subscriber of the raw topics went away at t = {self._time_ns() / _NS:.1f} s: holding the run "
                f"up to {self._resubscribe_timeout_s:g} s for it to come back")
        return now - self._lost_since <= self._resubscribe_timeout_s

    def _publish_clock(self) -> None:
        clock = messages.rosgraph_msgs.Clock()
        clock.clock.sec, clock.clock.nanosec = divmod(self._time_ns(), _NS)
        self._clock_pub.publish(clock)
        self._waiting_since = time.monotonic()

    def _on_accelerated_tick(self) -> None:
        if self._done:
            return
        if not self._started:
            if not self._ready_to_start():
                return
            self._started = True
            self._publish_clock()
            if self._sync:
                self._step_while_commanded()  # a command may have arrived before the start
            return
        if self._subscribers_missing():
            self._waiting_since = time.monotonic()  # not the commander's fault
            return
        if not self._sync:
            for _ in range(10):  # a burst per tick keeps the executor responsive to commands
                if self._done:
                    return
                self._step_once()
                self._publish_clock()
            return
        self._step_while_commanded()  # after a hold: the commands that arrived meanwhile
        if self._done:  # that reached the end (whose wait for acknowledgements may outlast the timeout)
            return
        if time.monotonic() - self._waiting_since > self._command_timeout_s:
            self._late_commands += 1
            self.get_logger().warn(
                f"no command stamped >= {self._time_ns() / _NS:.1f} s within {self._command_timeout_s} s; "
                "stepping with the last valid command", throttle_duration_sec=10.0)
            self._step_once()
            if not self._done:
                self._publish_clock()

    def _on_step_timer(self) -> None:
        self._step_timer.cancel()
        self._step_while_commanded()

    def _step_while_commanded(self) -> None:
        # every step whose command is already known is simulated in one vectorised call (identical
        # to stepping one by one); /clock then jumps to the end of the chunk
        while self._started and not self._done and not self._subscribers_missing():
            steps = min(self._schedule.covered_steps(self._time_ns(), self._dt_ns), _MAX_CHUNK_STEPS,
                        self._n_steps - self._sim.step_index)
            if steps <= 0:
                return
            t0_ns, first_step = self._time_ns(), self._sim.step_index
            torques = np.array([self._schedule.command_at(t0_ns + j * self._dt_ns) for j in range(steps)])
            out = self._sim.advance(torques)
            self._check_range(out.t_s, out.truth.grs_linear_maneuver, out.truth.grs_linear_meas)
            self._publish_chunk(out, t0_ns, first_step)
            if self._sim.step_index >= self._n_steps:
                self._finish()
            else:
                self._publish_clock()

    def _finish(self) -> None:
        self._done = True
        for pub in (self._star_pub, *self._grs_pubs):
            pub.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
        self._publish_diagnostics()
        summary = self._range.summary()
        self.get_logger().info(f"done: {self._sim.step_index} steps to t = {self._time_ns() / _NS:.1f} s; "
                               "peak |linear| / range: maneuver "
                               f"{np.round(summary['maneuver']['fraction_of_range'], 3).tolist()}, total "
                               f"{np.round(summary['total']['fraction_of_range'], 3).tolist()}; "
                               f"{self._gate.rejected_total} commands rejected, {self._late_commands} late")
        if self._exit_when_done:
            self._exit_timer = self.create_timer(self._linger_s, self._exit, clock=_steady_clock())

    def _exit(self) -> None:
        self._exit_timer.cancel()
        self._provenance_pub.wait_for_all_acked(rclpy.duration.Duration(seconds=2))
        self.context.try_shutdown()  # rclpy: no reason argument (Humble and Jazzy)

    # -- output --------------------------------------------------------------------------------
    def _check_range(self, t_s: Any, maneuver: Any, total: Any) -> None:
        for event in self._range.update_block(t_s, maneuver, total):
            self.get_logger().warn(event.message())

    def _publish_sample(self, sample: SimSample, t_ns: int) -> None:
        """Publish one stepped sample (its step: the simulator's step count)."""
        self._publish_readouts(sample.st_quat_xyzw.tolist(), sample.st_cov_rad2.tolist(), sample.voltages_v.tolist(),
                               t_ns)
        truth = sample.truth
        self._check_range([sample.t_s], truth.grs_linear_maneuver[None], truth.grs_linear_meas[None])
        if self._truth is not None:
            self._truth.publish(sample, t_ns, self._sim.step_index)

    def _publish_chunk(self, out: SimOutput, t0_ns: int, first_step: int) -> None:
        """Publish the samples of one vectorised chunk: sample j is stamped ``t0_ns + (j + 1) dt`` and is step
        ``first_step + j + 1``. The readouts become Python floats in one call per array (element by element
        that cost as much as the messages), and a sample's truth is assembled only where it is published."""
        quats, covs, volts = out.st_quat_xyzw.tolist(), out.st_cov_rad2.tolist(), out.voltages_v.tolist()
        for j in range(len(out)):
            t_ns = t0_ns + (j + 1) * self._dt_ns
            self._publish_readouts(quats[j], covs[j], volts[j], t_ns)
            step = first_step + j + 1
            if self._truth is not None and self._truth.publishes_at(step):
                self._truth.publish(out[j], t_ns, step)

    def _publish_readouts(self, quat_xyzw: list[float], cov_rad2: list[float], voltages_v: list[list[float]],
                          t_ns: int) -> None:
        """The star tracker and both GRS of one sample on their topics, stamped ``t_ns``."""
        m = messages.taiji2_msgs
        star = m.StarTracker()
        _stamp(star.header, t_ns)
        star.header.frame_id = "crf"
        star.attitude.x, star.attitude.y, star.attitude.z, star.attitude.w = quat_xyzw
        star.attitude_covariance = cov_rad2
        self._star_pub.publish(star)
        for index, pub in enumerate(self._grs_pubs):
            grs = m.GrsVoltages()
            _stamp(grs.header, t_ns)
            grs.header.frame_id = TMRF_FRAMES[index]
            grs.grs_id = index + 1
            grs.vx1, grs.vx2, grs.vy1, grs.vy2, grs.vz1, grs.vz2 = voltages_v[index]
            pub.publish(grs)

    def _publish_diagnostics(self) -> None:
        d = messages.diagnostic_msgs
        summary = self._range.summary()
        status = d.DiagnosticStatus(name="spacecraft_sim: GRS linear range", hardware_id="taiji2_sim")
        over_total = not summary["total"]["within_range"]
        over_maneuver = not summary["maneuver"]["within_range"]
        status.level = d.DiagnosticStatus.ERROR if over_maneuver else (
            d.DiagnosticStatus.WARN if over_total else d.DiagnosticStatus.OK)
        status.message = ("maneuver-induced linear acceleration leaves the GRS range" if over_maneuver else
                          "noise peaks leave the GRS range (maneuver part inside)" if over_total else
                          "inside the GRS range")
        values = {"range_m_s2": summary["range_m_s2"], "samples": summary["samples"],
                  "maneuver_peak_fraction_of_range": summary["maneuver"]["fraction_of_range"],
                  "total_peak_fraction_of_range": summary["total"]["fraction_of_range"],
                  "total_samples_outside": summary["total"]["samples_outside"],
                  "commands_rejected": self._gate.rejected,
                  "late_commands": self._late_commands, "time_base_mismatches": self._time_base_mismatches,
                  "publisher_samples_dropped": sum(getattr(p, "samples_dropped", 0)
                                                   for p in (self._star_pub, *self._grs_pubs)),
                  "sim_time_s": self._time_ns() / _NS}
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in values.items()]
        array = d.DiagnosticArray(status=[status, self._data_flow_status()])
        _stamp(array.header, self._time_ns())
        self._diag_pub.publish(array)

    def _data_flow_status(self) -> Any:
        """WARN naming what disturbed the run since the last report: a pause of this process, a silent
        commander (steps taken with the last command), writes given up for a stalled reliable reader."""
        d = messages.diagnostic_msgs
        now = time.monotonic()
        # this status goes out every second: a much longer gap means this process was not run
        paused_s = max(now - self._last_diag_wall - 1.0, 0.0)
        self._last_diag_wall = now
        dropped = sum(getattr(p, "samples_dropped", 0) for p in (self._star_pub, *self._grs_pubs))
        late = self._late_commands - self._reported_late_commands
        self._reported_late_commands = self._late_commands
        held_s = self._held_s + (0.0 if self._lost_since is None else now - self._lost_since)
        new_hold_s = held_s - self._reported_held_s
        self._reported_held_s = held_s
        problems = []
        if new_hold_s > 0.0:
            problems.append(f"subscriber lost: run held {held_s:.1f} s for it to come back")
        if paused_s > _PAUSE_REPORTED_AFTER_S:
            problems.append(f"paused: not scheduled for {paused_s:.1f} s (stopped or starved of CPU)")
        if late > 0:
            problems.append(f"commander late: {late} steps taken with the last command after "
                            f"{self._command_timeout_s} s without one")
        if dropped:
            problems.append(f"{dropped} samples given up for a stalled reliable subscriber")
        if self._time_base_mismatches:
            problems.append(f"{self._time_base_mismatches} commands on another time base")
        status = d.DiagnosticStatus(name="spacecraft_sim: data flow", hardware_id="taiji2_sim",
                                    message="; ".join(problems) or "nominal")
        status.level = d.DiagnosticStatus.WARN if problems else d.DiagnosticStatus.OK
        values = {"paused_s": paused_s, "held_for_subscribers_s": held_s, "late_commands": self._late_commands,
                  "publisher_samples_dropped": dropped,
                  "time_base_mismatches": self._time_base_mismatches}
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in values.items()]
        return status


class _TruthPublishers:
    """Ground truth for evaluation only (never read by estimators): rate, acceleration, torque, G, d."""

    def __init__(self, node: rclpy.node.Node, qos: Any, kinematics: bool = True) -> None:
        g, t = messages.geometry_msgs, messages.taiji2_msgs
        #: the per-step kinematic truth is most of this node's messages (4 of 7 per step): a graph whose
        #: evaluation needs only G and d (experiment --link) turns it off
        self._kinematics = kinematics
        if kinematics:
            self._rate = node.create_publisher(g.Vector3Stamped, TRUE_ANGULAR_RATE_TOPIC, qos)
            self._accel = node.create_publisher(g.Vector3Stamped, TRUE_ANGULAR_ACCELERATION_TOPIC, qos)
            self._attitude = node.create_publisher(g.QuaternionStamped, TRUE_ATTITUDE_TOPIC, qos)
            self._torque = node.create_publisher(g.WrenchStamped, APPLIED_WRENCH_TOPIC, qos)
        self._scale = [node.create_publisher(t.ScaleFactorEstimate, TRUE_SCALE_FACTOR_TOPIC_OF[i], qos)
                       for i in (1, 2)]
        self._offset = [node.create_publisher(t.ComOffsetEstimate, TRUE_COM_OFFSET_TOPIC_OF[i], qos)
                        for i in (1, 2)]
        self._mass_kg = None

    def publishes_at(self, step: int) -> bool:
        """Whether :meth:`publish` sends anything at simulator step ``step`` (counted from 1)."""
        return self._kinematics or step % 10 == 1

    def publish(self, sample: SimSample, t_ns: int, step: int) -> None:
        t = messages.taiji2_msgs
        truth = sample.truth
        if self._kinematics:
            self._publish_kinematics(truth, t_ns)
        if step % 10 != 1:
            return  # scale factors and offsets change slowly: 1 Hz is plenty
        for i in range(2):
            sf = t.ScaleFactorEstimate(grs_id=i + 1, method="truth", samples_used=step)
            _stamp(sf.header, t_ns)
            sf.header.frame_id = TMRF_FRAMES[i]
            sf.scale_factors = [float(v) for v in truth.grs_angular_scale_factors[i]]
            self._scale[i].publish(sf)
            d = t.ComOffsetEstimate(grs_id=i + 1, method="truth", samples_used=step)
            _stamp(d.header, t_ns)
            d.header.frame_id = "crf"
            d.offset.x, d.offset.y, d.offset.z = (float(v) for v in truth.com_offset_m[i])
            self._offset[i].publish(d)

    def _publish_kinematics(self, truth: Any, t_ns: int) -> None:
        g = messages.geometry_msgs
        for pub, vector in ((self._rate, truth.omega_rad_s), (self._accel, truth.omega_dot_rad_s2)):
            msg = g.Vector3Stamped()
            _stamp(msg.header, t_ns)
            msg.header.frame_id = "crf"
            msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in vector)
            pub.publish(msg)
        attitude = g.QuaternionStamped()
        _stamp(attitude.header, t_ns)
        attitude.header.frame_id = "crf"
        attitude.quaternion.x, attitude.quaternion.y, attitude.quaternion.z, attitude.quaternion.w = (
            float(v) for v in truth.quat_xyzw)
        self._attitude.publish(attitude)
        wrench = g.WrenchStamped()
        _stamp(wrench.header, t_ns)
        wrench.header.frame_id = "crf"
        wrench.wrench.torque.x, wrench.wrench.torque.y, wrench.wrench.torque.z = (
            float(v) for v in truth.torque_applied_n_m)
        # force field carries the spacecraft non-gravitational acceleration [m s^-2] (documented)
        wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z = (float(v) for v in truth.a_sc_m_s2)
        self._torque.publish(wrench)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SpacecraftSim, args)


if __name__ == "__main__":
    raise SystemExit(main())
