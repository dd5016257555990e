"""The runtime across OS processes: a plain Cyclone DDS peer, discovery, shutdown, and the taiji2 CLI.

No `from __future__ import annotations` here: Cyclone resolves the IDL field annotations at runtime.
"""


import signal
import subprocess
import time
from dataclasses import dataclass, field

import cyclonedds.idl.types as t
import pytest
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from taiji2_runtime.ros import RUNTIME

from support import PYTHON, python_subprocess_env


# Hand-written from the ROS 2 conventions only (rosidl IDL of geometry_msgs/WrenchStamped):
# no code of this project is involved on the receiving side.
@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_ = field(default_factory=Time_)
    frame_id: str = ""


@dataclass
class Vector3_(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Wrench_(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    force: Vector3_ = field(default_factory=Vector3_)
    torque: Vector3_ = field(default_factory=Vector3_)


@dataclass
class WrenchStamped_(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    header: Header_ = field(default_factory=Header_)
    wrench: Wrench_ = field(default_factory=Wrench_)


def _start_commander(*ros_args: str) -> subprocess.Popen:
    cmd = [PYTHON, "-m", "taiji2_apps.cli.main", "run", "taiji2_sim_pkg", "maneuver_commander",
           "--ros-args", "-p", "publish_rate_hz:=20.0", "-p", "maneuver:=paper", *ros_args]
    return subprocess.Popen(cmd, env=python_subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


@pytest.fixture
def plain_reader():
    from taiji2_runtime.dds_rclpy.context import Context, ros_domain_id

    ctx = Context()  # only to get the same default Cyclone configuration (loopback) and domain
    ctx.init(["plain"])
    participant: DomainParticipant = ctx.participant()
    topic = Topic(participant, "rt/taiji2/maneuver/command", WrenchStamped_)
    reader = DataReader(participant, topic, Qos(Policy.Reliability.Reliable(duration(seconds=1)),
                                                Policy.History.KeepLast(100)))
    assert ros_domain_id() == ctx.domain_id
    yield reader
    ctx.shutdown()


@pytest.mark.embedded_runtime(reason="a plain Cyclone DDS reader in the embedded runtime's participant "
                              "configuration; test/rclpy has the rclpy <-> embedded exchange")
def test_plain_cyclone_subscriber_receives_the_square_wave_and_sees_shutdown(plain_reader):
    started = time.monotonic()
    proc = _start_commander()
    try:
        samples: list[WrenchStamped_] = []
        deadline = time.monotonic() + 15
        while len(samples) < 10 and time.monotonic() < deadline:
            samples.extend(plain_reader.take(N=100))
            time.sleep(0.02)
        first_sample_s = time.monotonic() - started
        assert len(samples) >= 10, proc.stderr.read() if proc.poll() is not None else "no samples"
        assert all(s.header.frame_id == "crf" for s in samples)
        # Type-1 preset: |torque| = (3, 3, 13) uN m on every sample
        for s in samples:
            assert abs(abs(s.wrench.torque.x) - 3e-6) < 1e-12
            assert abs(abs(s.wrench.torque.z) - 13e-6) < 1e-12
        assert plain_reader.get_subscription_matched_status().current_count == 1
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=5)
        stopped = time.monotonic()
        while plain_reader.get_subscription_matched_status().current_count and time.monotonic() - stopped < 5:
            time.sleep(0.01)
        dropped_after_s = time.monotonic() - stopped
        assert plain_reader.get_subscription_matched_status().current_count == 0
        assert dropped_after_s < 2.0, f"peer dropped only after {dropped_after_s:.2f} s"
        assert proc.returncode == 0, proc.stderr.read()
        print(f"first sample {first_sample_s:.2f} s after process start; dropped {dropped_after_s:.3f} s after exit")
    finally:
        if proc.poll() is None:
            proc.kill()


BAD_INPUT = [
    (["run", "no_such_package", "x"], "package 'no_such_package' not found"),
    (["run", "taiji2_sim_pkg", "no_such_exe"], "no executable 'no_such_exe'"),
    (["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", "period_s"], "period_s"),
    (["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", "period_s:=fast"], "expecting type 'DOUBLE'"),
    (["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", "period_s:=-5.0"], "period_s"),
    (["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", "amplitude_n_m:=[2.0e-4, 0.0, 0.0]"],
     "thruster range"),
    (["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", "preset:=type9"], "type9"),
    (["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", "publish_rate_hz:=0.5"], "range"),
]


@pytest.mark.parametrize(("argv", "message"), BAD_INPUT)
def test_bad_input_gives_one_line_error_and_nonzero_exit(argv, message):
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", *argv], env=python_subprocess_env(),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and message in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_no_usable_network_interface_is_a_one_line_error():
    env = python_subprocess_env()
    env["CYCLONEDDS_URI"] = ("<CycloneDDS><Domain><General><Interfaces><NetworkInterface name=\"nonexist0\"/>"
                             "</Interfaces></General></Domain></CycloneDDS>")
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "run", "taiji2_sim_pkg", "maneuver_commander"],
                          env=env, capture_output=True, text=True, timeout=60)
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(errors) == 1 and "nonexist0" in proc.stderr, proc.stderr
    if RUNTIME != "rclpy":  # under rclpy, Cyclone and rcl also log to stderr themselves (their own lines)
        assert proc.stderr.strip().count("\n") == 0 and "cannot start DDS" in proc.stderr and "nonexist0" in proc.stderr


def test_two_processes_with_the_embedded_runtime_exchange_messages_losslessly(tmp_path):
    script = tmp_path / "pub.py"
    script.write_text(
        "import sys\n"
        "from taiji2_runtime.ros import rclpy, messages\n"
        "rclpy.init(args=sys.argv)\n"
        "node = rclpy.create_node('bulk_pub')\n"
        "q = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)\n"
        "pub = node.create_publisher(messages.std_msgs.Header, '/bulk', q)\n"
        "while pub.get_subscription_count() == 0:\n"
        "    rclpy.spin_once(node, timeout_sec=0.01)\n"
        "for i in range(5000):\n"
        "    m = messages.std_msgs.Header(frame_id=str(i))\n"
        "    pub.publish(m)\n"
        "pub.wait_for_all_acked(rclpy.duration.Duration(seconds=10))\n"
        "rclpy.shutdown()\n")
    from taiji2_runtime.ros import messages, rclpy

    ctx = rclpy.context.Context()
    rclpy.init(args=["sub"], context=ctx)
    executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
    proc = None
    try:
        node = rclpy.node.Node("bulk_sub", context=ctx)
        executor.add_node(node)
        got: list[int] = []
        q = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        node.create_subscription(messages.std_msgs.Header, "/bulk", lambda m: got.append(int(m.frame_id)), q)
        proc = subprocess.Popen([PYTHON, str(script)], env=python_subprocess_env(), stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while len(got) < 5000 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert got == list(range(5000))
        assert proc.wait(timeout=15) == 0, proc.stderr.read()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        executor.shutdown()
        rclpy.try_shutdown(context=ctx)


@pytest.mark.embedded_runtime(reason="ROS 2 allows two nodes of one name (rcl only warns); the embedded runtime "
                              "refuses them graph-wide (docs/runtime.md)")
def test_a_second_node_with_the_same_name_in_another_process_exits_with_one_line():
    first = _start_commander()
    try:
        time.sleep(1.0)  # the first one is up and announced
        second = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "run", "taiji2_sim_pkg",
                                 "maneuver_commander"], env=python_subprocess_env(), capture_output=True, text=True,
                                timeout=60)
        assert second.returncode == 2
        errors = [line for line in second.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and "already runs in the graph" in errors[0], second.stderr
        assert first.poll() is None  # the earlier node keeps running
    finally:
        first.send_signal(signal.SIGTERM)
        first.wait(timeout=10)
