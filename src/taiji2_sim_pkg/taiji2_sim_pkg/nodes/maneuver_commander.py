"""maneuver_commander: publishes the square-wave calibration torque on /taiji2/maneuver/command.

Thin ROS glue around the maneuver that ``maneuver`` names, as every ``taiji2`` verb's ``--maneuver``
(:mod:`taiji2_model.maneuver_choice`): ``design`` (the default where the layout ``preset`` has one: its
shipped ``taiji2 design``), ``paper`` (the layout's square wave, whose keys ``period_s`` ... may be
overridden) or a maneuver file of any family of :mod:`taiji2_model.maneuver_families` (the square-wave
keys are then ignored). Parameters are
documented in ``config/maneuver_commander.yaml``. The command is published at every tick of
``publish_rate_hz`` on the node clock (so at each change, delayed by at most one tick, and at least
at 1 Hz); on simulated time (``use_sim_time``) every tick follows /clock, which lets the simulator
run in lock-step with the command stream.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_model.config import builtin_layouts, load_config
from taiji2_model.contract import COMMAND_TOPIC
from taiji2_model.maneuver import SquareWaveManeuver
from taiji2_model.maneuver_choice import MANEUVER_HELP, choose_maneuver
from taiji2_model.maneuver_families import check_thrust, maneuver_spec
from taiji2_runtime import node_parameters
from taiji2_runtime.entry import run_node
from taiji2_runtime.ros import messages, rclpy

_NS = 1e-9


def _descriptor(description: str, *, low: float | None = None, high: float | None = None) -> Any:
    """A read-only parameter (read once at start; ``ros2 param set`` is refused)."""
    rcl = messages.rcl_interfaces
    descriptor = rcl.ParameterDescriptor(description=f"{description} [read-only: read at start]", read_only=True)
    if low is not None:
        descriptor.floating_point_range = [rcl.FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    return descriptor


#: the commander's one parameter that ``ros2 param set`` may change while it runs (from the next tick on)
LOOKAHEAD_CHECK = node_parameters.within("lookahead_s", 0.0, 3600.0, "s")


class ManeuverCommander(rclpy.node.Node):
    """Publishes ``geometry_msgs/WrenchStamped`` torque commands (frame ``crf``, N m)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("maneuver_commander", **node_kwargs)
        preset = self.declare_parameter(
            "preset", "type1",
            _descriptor(f"layout whose maneuver (design or paper) is flown: {', '.join(builtin_layouts())}")).value
        layout = load_config(preset)
        nominal = layout.maneuver
        p: dict[str, Any] = {
            "period_s": self.declare_parameter(
                "period_s", float(nominal.period_s), _descriptor("square-wave period [s]")).value,
            "amplitude_n_m": self.declare_parameter(
                "amplitude_n_m", [float(v) for v in nominal.amplitude_n_m],
                _descriptor("torque amplitude about CRF X, Y, Z [N m]")).value,
            "phase_s": self.declare_parameter(
                "phase_s", [float(v) for v in nominal.phase_s],
                _descriptor("time shift of each axis' square wave [s]")).value,
            "start_s": self.declare_parameter(
                "start_s", float(nominal.start_s),
                _descriptor("maneuver start after the time origin [s] (origin: t = 0 of /clock on simulated "
                            "time, else the node start)")).value,
            "duration_s": self.declare_parameter(
                "duration_s", float(nominal.duration_s), _descriptor("maneuver duration [s]")).value,
        }
        self._lookahead_ns = round(1e9 * self.declare_parameter(
            "lookahead_s", 0.0, node_parameters.descriptor(
                "publish time-tagged commands this far ahead of the clock, 0-3600 [s] (lets an accelerated "
                "simulation run without a round trip per step)")).value)
        #: the largest lookahead in effect so far: commands up to it ahead may have gone out [ns]
        self._max_lookahead_ns = self._lookahead_ns
        node_parameters.RuntimeParameters(self, {"lookahead_s": LOOKAHEAD_CHECK}, self._set_lookahead)
        rate_hz = self.declare_parameter(
            "publish_rate_hz", 10.0, _descriptor("command publishing rate [Hz]", low=1.0, high=1000.0)).value
        self._frame_id = self.declare_parameter("frame_id", "crf", _descriptor("header.frame_id")).value
        thrusters = layout.thrusters
        lever_arm_m = self.declare_parameter(
            "thruster_lever_arm_m", float(thrusters.lever_arm_m),
            _descriptor("lever arm of the thruster making each axis' torque [m]; thrust = |torque| / arm")).value
        asked = self.declare_parameter("maneuver", "", _descriptor(
            f"{MANEUVER_HELP}; empty: the default; with paper the square-wave keys above apply")).value
        preset_square = {"period_s": nominal.period_s, "amplitude_n_m": nominal.amplitude_n_m,
                         "phase_s": nominal.phase_s, "start_s": nominal.start_s, "duration_s": nominal.duration_s}
        square_keys_set = any(not np.array_equal(np.asarray(p[k], dtype=float), np.asarray(v, dtype=float))
                              for k, v in preset_square.items())
        # square-wave keys set without a maneuver describe a square wave: the paper's, modified
        # ValueError (one line naming the choice) when the choice cannot be flown
        self._choice = choose_maneuver(preset, asked or ("paper" if square_keys_set else None), None, preset=layout)
        self._maneuver = SquareWaveManeuver(**p) if self._choice.kind == "paper" else self._choice.maneuver
        # refuse a maneuver the micro-thrusters cannot fly (ManeuverError names the axis)
        check_thrust(self._maneuver, thrusters.min_thrust_n, thrusters.max_thrust_n, lever_arm_m)
        self._wrench_type = messages.geometry_msgs.WrenchStamped
        qos = rclpy.qos.QoSProfile(
            history=rclpy.qos.HistoryPolicy.KEEP_ALL, reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        self._publisher = self.create_publisher(self._wrench_type, COMMAND_TOPIC, qos)
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        self._origin_ns: int | None = 0 if self._sim_time else None
        self._last_torque: np.ndarray | None = None
        self._period_ns = round(1e9 / rate_hz)
        self._next_stamp_ns: int | None = None
        self.create_timer(1.0 / rate_hz, self._on_tick)
        # The first clock tick comes one period after start; a subscriber (the simulator) that is
        # already waiting gets the command valid at the start at once instead.
        self._first_command_timer = self.create_timer(
            0.02, self._publish_first_command,
            clock=rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME))
        if self._choice.kind != "paper":
            self.get_logger().info(f"{self._choice.label} ({self._choice.file}): {maneuver_spec(self._maneuver)}")
        else:
            self.get_logger().info(
                f"{self._choice.label}: period {p['period_s']} s, amplitude {p['amplitude_n_m']} N m, "
                f"phase {p['phase_s']} s, start {p['start_s']} s, duration {p['duration_s']} s, "
                f"{rate_hz} Hz on {'simulated' if self._sim_time else 'system'} time")

    def _publish_first_command(self) -> None:
        if self._last_torque is not None:
            self._first_command_timer.cancel()
        elif self._publisher.get_subscription_count() > 0:
            self._on_tick()
            self._first_command_timer.cancel()

    def _set_lookahead(self, name: str, value: float) -> None:
        """``ros2 param set lookahead_s``: commands go that far ahead from the next tick on (never a stamp twice)."""
        self._lookahead_ns = round(1e9 * value)
        self._max_lookahead_ns = max(self._max_lookahead_ns, self._lookahead_ns)
        self.get_logger().info(f"lookahead_s set to {value} s")

    def _on_tick(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        if self._origin_ns is None:
            self._origin_ns = now_ns
        if self._next_stamp_ns is None:
            self._next_stamp_ns = now_ns
        elif now_ns < self._next_stamp_ns - self._max_lookahead_ns - 2 * self._period_ns:
            # the clock went back (a restarted simulation, a replay from its start): what was commanded
            # beyond it is stale for the new run, so command again from the clock
            self.get_logger().info(f"clock went back from {(self._next_stamp_ns - self._lookahead_ns) / 1e9:.1f} s "
                                   f"to {now_ns / 1e9:.1f} s: commanding again from there")
            self._next_stamp_ns = now_ns
        elif self._lookahead_ns == 0 and self._next_stamp_ns - self._period_ns <= now_ns:
            self._next_stamp_ns = now_ns  # no lookahead: one command per tick, stamped now
        # every tick up to now + lookahead, in stamp order (time-tagged commands)
        while self._next_stamp_ns <= now_ns + self._lookahead_ns:
            self._publish_command(self._next_stamp_ns)
            self._next_stamp_ns += self._period_ns

    def _publish_command(self, stamp_ns: int) -> None:
        t_s = (stamp_ns - self._origin_ns) * _NS
        torque = self._maneuver.torque_at(t_s)
        msg = self._wrench_type()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.header.frame_id = self._frame_id
        msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = (float(v) for v in torque)
        self._publisher.publish(msg)
        if self._last_torque is None or not np.array_equal(torque, self._last_torque):
            self.get_logger().debug(f"t = {t_s:.1f} s: torque {torque.tolist()} N m")
        self._last_torque = torque


def main(args: Sequence[str] | None = None) -> int:
    return run_node(ManeuverCommander, args)


if __name__ == "__main__":
    raise SystemExit(main())
