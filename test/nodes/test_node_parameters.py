"""Parameters mean what they say (issue 26 row 2), on whichever runtime runs the tests (embedded, or rclpy
in the rclpy tier): start-up-only parameters are read-only, runtime ones take effect and are refused with the
start-up message."""

from __future__ import annotations

import pytest
import yaml

from taiji2_estimator_pkg.nodes.com_offset_estimator import ComOffsetEstimatorNode
from taiji2_estimator_pkg.nodes.runtime_parameters import RUNTIME_CHECKS
from taiji2_estimator_pkg.nodes.scale_factor_estimator import ScaleFactorEstimatorNode
from taiji2_model.config import load_config
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch
from taiji2_sim_pkg.nodes.maneuver_commander import ManeuverCommander
from taiji2_sim_pkg.nodes.spacecraft_sim import SpacecraftSim

from support import REPO, spin_until

READ_ONLY = "Trying to set a read-only parameter: {}."
N = 600  # 60 s at 10 Hz


def _set(node, name, value):
    return node.set_parameters([rclpy.parameter.Parameter(name, value=value)])[0]


def _start_error(make, name, value) -> str:
    """The error a node started with ``name:=value`` ends with (a node of its own name: the first one runs)."""
    with pytest.raises(ValueError) as refused:
        make(["--ros-args", "-r", f"__node:=started_with_{name}", "-p", f"{name}:={value}"])
    return str(refused.value)


@pytest.mark.parametrize("node_class", [ScaleFactorEstimatorNode, ComOffsetEstimatorNode])
def test_estimator_parameters_are_read_only_except_the_runtime_ones(context, node_class):
    node = node_class(context=context)
    for name in ("method", "layout", "gate_probability", "max_stream_silence_s", "checkpoint_file"):
        result = _set(node, name, "bogus" if name == "method" else node.get_parameter(name).value)
        assert not result.successful and result.reason == READ_ONLY.format(name), (name, result.reason)
        assert node.describe_parameter(name).read_only
    assert node.get_parameter("method").value == "gls" and node.p["method"] == "gls"
    for name in RUNTIME_CHECKS:
        if not node.has_parameter(name):
            continue
        assert not node.describe_parameter(name).read_only
        assert _set(node, name, 0.25).successful and node.p[name] == 0.25  # in effect: what the node reads
        # a bad value: the same words as when the node is started with it
        start_error = _start_error(lambda a: node_class(context=context, cli_args=a), name, -1.0)
        result = _set(node, name, -1.0)
        assert not result.successful and result.reason == start_error, (result.reason, start_error)
        assert node.p[name] == 0.25 and node.get_parameter(name).value == 0.25


class RawFeeder:
    """A node publishing the raw contract topics from a batch simulation; collects grs1 scale-factor stamps."""

    def __init__(self, context, executor, n_samples: int):
        config = load_config("type1", overrides={"maneuver.duration_s": n_samples / 10})
        self.out = simulate_batch(config, 26, maneuver_torque_commands(config, n_samples))
        self.executor = executor
        self.node = rclpy.node.Node("feeder", context=context)
        t = messages.taiji2_msgs
        qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        self.star = self.node.create_publisher(t.StarTracker, "/taiji2/star_tracker", qos)
        self.grs = {g: self.node.create_publisher(t.GrsVoltages, f"/taiji2/grs{g}/voltages", qos) for g in (1, 2)}
        self.stamps: list[float] = []
        self.node.create_subscription(t.ScaleFactorEstimate, "/taiji2/estimates/grs1/scale_factors",
                                      lambda m: self.stamps.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9),
                                      qos)
        executor.add_node(self.node)

    def wait_for_readers(self, grs_readers: int) -> None:
        """Until the star tracker has a reader and each GRS topic ``grs_readers``."""
        assert spin_until(self.executor, lambda: self.star.get_subscription_count() >= 1 and all(
            p.get_subscription_count() >= grs_readers for p in self.grs.values()))

    def feed(self) -> float:
        """Publish every sample (spinning now and then); returns the last stamp [s]."""
        t, out = messages.taiji2_msgs, self.out
        for k in range(len(out.t_s)):
            sec, nanosec = divmod(round(out.t_s[k] * 1e9), 10**9)
            m = t.StarTracker()
            m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = sec, nanosec, "crf"
            m.attitude.x, m.attitude.y, m.attitude.z, m.attitude.w = (float(v) for v in out.st_quat_xyzw[k])
            self.star.publish(m)
            for g in (1, 2):
                v = t.GrsVoltages(grs_id=g)
                v.header.stamp.sec, v.header.stamp.nanosec, v.header.frame_id = sec, nanosec, f"tmrf{g}"
                v.vx1, v.vx2, v.vy1, v.vy2, v.vz1, v.vz2 = (float(x) for x in out.voltages_v[k][g - 1])
                self.grs[g].publish(v)
            if k % 100 == 0:
                self.executor.spin_once(timeout_sec=0.0)
        return float(out.t_s[-1])


def test_a_publish_period_set_at_run_time_takes_effect(context, executor):
    node = ScaleFactorEstimatorNode(context=context)
    executor.add_node(node)
    feeder = RawFeeder(context, executor, N)
    feeder.wait_for_readers(1)
    assert _set(node, "publish_period_s", 20.0).successful  # `ros2 param set ... publish_period_s 20.0`
    last = feeder.feed()
    stamps = feeder.stamps
    assert spin_until(executor, lambda: stamps and abs(stamps[-1] - last) < 1e-6, timeout_s=60)
    # one estimate per 20 s of data (the first epoch, 20, 40 s) and the end of data, not one per second
    assert [round(s, 1) for s in stamps] == [round(float(feeder.out.t_s[0]), 1), 20.0, 40.0, round(last, 1)], stamps


def test_commander_and_simulator_parameters_are_read_only_but_the_lookahead(context):
    commander = ManeuverCommander(context=context)
    for name in ("amplitude_n_m", "period_s", "preset", "publish_rate_hz"):
        result = _set(commander, name, commander.get_parameter(name).value)
        assert not result.successful and result.reason == READ_ONLY.format(name), (name, result.reason)
    assert _set(commander, "lookahead_s", 2.0).successful and commander._lookahead_ns == 2_000_000_000
    start_error = _start_error(lambda a: ManeuverCommander(context=context, cli_args=a), "lookahead_s", -1.0)
    result = _set(commander, "lookahead_s", -1.0)
    assert not result.successful and result.reason == start_error == "lookahead_s: -1.0 is outside [0.0, 3600.0] [s]"
    sim = SpacecraftSim(context=context, cli_args=["--ros-args", "-p", "duration_s:=1.0"])
    for name in ("seed", "clock_mode", "duration_s", "layout"):
        result = _set(sim, name, sim.get_parameter(name).value)
        assert not result.successful and result.reason == READ_ONLY.format(name), (name, result.reason)


def test_config_files_say_which_parameters_can_change_at_run_time():
    # every documented key is marked: `[runtime]` exactly for the runtime parameters, the header says the rest
    # are read-only
    estimators = (REPO / "src" / "taiji2_estimator_pkg" / "config" / "estimators.yaml").read_text()
    commander = (REPO / "src" / "taiji2_sim_pkg" / "config" / "maneuver_commander.yaml").read_text()
    simulator = (REPO / "src" / "taiji2_sim_pkg" / "config" / "spacecraft_sim.yaml").read_text()
    for text, runtime in ((estimators, set(RUNTIME_CHECKS)), (commander, {"lookahead_s"}), (simulator, set())):
        assert "read-only" in text.split("\n\n")[0]
        marked = {line.split(":")[0].strip() for line in text.splitlines() if "[runtime]" in line
                  and not line.lstrip().startswith("#")}
        documented = {key for key in runtime if f" {key}:" in text}
        assert marked == documented, (marked, documented)
        yaml.safe_load(text)


def test_link_nodes_parameters_are_read_only():
    # the link's and the commanding chain's parameters are read once at start: `ros2 param set` is refused,
    # not answered "successful" for a change that would do nothing
    from taiji2_ground_pkg.nodes.command_planner import CommandPlanner
    from taiji2_ground_pkg.nodes.ground_receiver import GroundReceiver
    from taiji2_sim_pkg.nodes.onboard_executor import OnboardExecutor
    from taiji2_sim_pkg.nodes.space_link import SpaceLink
    from taiji2_sim_pkg.nodes.telemetry_packetizer import TelemetryPacketizer
    from taiji2_sim_pkg.nodes.uplink_intruder import UplinkIntruder

    for node_class in (CommandPlanner, GroundReceiver, OnboardExecutor, SpaceLink, TelemetryPacketizer, UplinkIntruder):
        context = rclpy.context.Context()
        rclpy.init(context=context)
        node = node_class(context=context)
        try:
            names = [n for n in node._parameters if n != "use_sim_time"]
            assert names, node_class
            for name in names:
                assert node.describe_parameter(name).read_only, (node_class, name)
                result = _set(node, name, node.get_parameter(name).value)
                assert not result.successful and result.reason == READ_ONLY.format(name), (node_class, name)
        finally:
            node.destroy_node()
            rclpy.try_shutdown(context=context)
