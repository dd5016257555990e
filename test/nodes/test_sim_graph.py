"""The commander + simulator node graph: lossless, deterministic, equal to the batch core, robust to bad commands."""

from __future__ import annotations

import time

import numpy as np
import pytest

from taiji2_model.config import load_config
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch
from taiji2_sim_pkg.nodes.maneuver_commander import ManeuverCommander
from taiji2_sim_pkg.nodes.spacecraft_sim import SpacecraftSim

from support import spin_until

RAW = {"/taiji2/star_tracker": "StarTracker", "/taiji2/grs1/voltages": "GrsVoltages",
       "/taiji2/grs2/voltages": "GrsVoltages"}


class _Recorder:
    def __init__(self, node):
        self.samples: dict[str, list] = {topic: [] for topic in RAW}
        qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        for topic, name in RAW.items():
            node.create_subscription(getattr(messages.taiji2_msgs, name), topic,
                                     lambda m, t=topic: self.samples[t].append(m), qos)
        self.truth_scale_factors: list = []
        node.create_subscription(messages.taiji2_msgs.ScaleFactorEstimate, "/taiji2/sim/grs1/scale_factors",
                                 self.truth_scale_factors.append, qos)


def _new_context(args):
    ctx = rclpy.context.Context()
    rclpy.init(args=["test", "--ros-args", *args], context=ctx)
    return ctx, rclpy.executors.SingleThreadedExecutor(context=ctx)


@pytest.fixture
def sim_context():
    ctx, ex = _new_context([])
    yield ctx, ex
    ex.shutdown()
    rclpy.try_shutdown(context=ctx)


def _run_graph(context, executor, sim_context, sim_args, duration_s, commander=True):
    sim_ctx, sim_ex = sim_context
    observer = rclpy.node.Node("observer", context=context)
    recorder = _Recorder(observer)
    executor.add_node(observer)
    if commander:
        cmd = ManeuverCommander(context=context,
                                cli_args=["--ros-args", "-p", "use_sim_time:=true", "-p", "lookahead_s:=1.0",
                                          "-p", "maneuver:=paper"])  # the batch core flies the config's wave
        executor.add_node(cmd)
    sim = SpacecraftSim(context=sim_ctx, cli_args=["--ros-args", "-p", f"duration_s:={duration_s}", "-p", "seed:=42",
                                                    "-p", "wait_for_subscribers:=[1, 1, 1]", *sim_args])
    sim_ex.add_node(sim)

    def finished() -> bool:
        return not sim_ctx.ok() and all(len(v) >= round(duration_s * 10) for v in recorder.samples.values())

    # two executors, two contexts: alternate them without idling (spin_until would wait on each)
    deadline = time.monotonic() + 120.0
    while not finished() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.0)
        if sim_ctx.ok():
            sim_ex.spin_once(timeout_sec=0.001)
        else:
            executor.spin_once(timeout_sec=0.01)
    assert finished(), {k: len(v) for k, v in recorder.samples.items()}
    return recorder


def test_graph_is_lossless_and_equals_the_batch_core(context, executor, sim_context):
    duration_s = 60.0
    recorder = _run_graph(context, executor, sim_context, [], duration_s)
    n = round(duration_s * 10)
    for topic, samples in recorder.samples.items():
        assert len(samples) == n, topic  # every step delivered, none twice
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in samples]
        assert stamps == [k * 100_000_000 for k in range(1, n + 1)], topic
    config = load_config("type1")
    batch = simulate_batch(config, 42, maneuver_torque_commands(config, n))
    volts = np.array([[m.vx1, m.vx2, m.vy1, m.vy2, m.vz1, m.vz2] for m in recorder.samples["/taiji2/grs1/voltages"]])
    np.testing.assert_array_equal(volts, batch.voltages_v[:, 0, :])  # bit for bit
    quats = np.array([[m.attitude.x, m.attitude.y, m.attitude.z, m.attitude.w]
                      for m in recorder.samples["/taiji2/star_tracker"]])
    # the attitude's product is associated by step index, not by call: the node's chunks (set by
    # when commands arrive) give the batch's bits
    np.testing.assert_array_equal(quats, batch.st_quat_xyzw)
    assert all(m.header.frame_id == "tmrf2" and m.grs_id == 2 for m in recorder.samples["/taiji2/grs2/voltages"])
    # the truth's G at 1 Hz, steps 1, 11, 21, ... (the node steps in chunks: each sample its own step)
    truth = [(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.samples_used)
             for m in recorder.truth_scale_factors]
    assert truth == [(k * 100_000_000, k) for k in range(1, n + 1, 10)]


def test_bad_commands_are_rejected_counted_and_the_last_valid_one_kept(context, executor, sim_context):
    sim_ctx, sim_ex = sim_context
    sim = SpacecraftSim(context=sim_ctx, cli_args=["--ros-args", "-p", "duration_s:=2.0", "-p", "seed:=1",
                                                    "-p", "exit_when_done:=false"])
    sim_ex.add_node(sim)
    sender = rclpy.node.Node("sender", context=context)
    executor.add_node(sender)
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
    pub = sender.create_publisher(messages.geometry_msgs.WrenchStamped, "/taiji2/maneuver/command", qos)
    assert spin_until(sim_ex, lambda: pub.get_subscription_count() >= 1)

    def command(stamp_s, torque, frame="crf"):
        msg = messages.geometry_msgs.WrenchStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(stamp_s), round((stamp_s % 1) * 1e9)
        msg.header.frame_id = frame
        msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = torque
        pub.publish(msg)

    command(0.0, (1e-6, 0.0, 0.0))
    command(0.1, (float("nan"), 0.0, 0.0))
    command(0.2, (1.0, 0.0, 0.0))          # 1 N m: far beyond 100 uN x 1 m
    command(0.3, (2e-6, 0.0, 0.0), "base_link")
    for k in range(4, 21):
        command(k / 10, (1e-6, 0.0, 0.0))
    assert spin_until(sim_ex, lambda: sim._sim.step_index >= 20, timeout_s=30)
    assert sim._gate.rejected == {"non_finite": 1, "too_large": 1, "frame_id": 1}
    np.testing.assert_array_equal(sim._gate.torque_n_m, [1e-6, 0.0, 0.0])
    assert sim_ctx.ok()  # the graph keeps running


@pytest.mark.parametrize(("args", "message"), [
    (["-p", "layout:=type9"], "type9"),
    (["-p", "clock_mode:=warp"], "clock_mode"),
    (["-p", "config_overrides:=['spacecraft.inertia_kg_m2=[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]']"],
     "inertia"),
    (["-p", "config_overrides:=[maneuver.period_s=0.0]"], "period_s"),
    (["-p", "config_overrides:=[noise.srp.asd_m_s2_rthz=-1.0]"], "srp"),
])
def test_non_physical_configuration_fails_at_start_naming_the_parameter(sim_context, args, message):
    sim_ctx, _ = sim_context
    with pytest.raises(ValueError, match=message):
        SpacecraftSim(context=sim_ctx, cli_args=["--ros-args", *args])
