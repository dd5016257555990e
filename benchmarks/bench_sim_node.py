"""spacecraft_sim node on simulated time, as fast as possible, with a subscriber on every topic.

Runs spacecraft_sim (accelerated clock, lock-step with time-tagged commands) and maneuver_commander
(lookahead 2 s) as separate processes, and in this process a subscriber on every topic the
simulator publishes (reliable keep-all: every sample is counted). Prints the simulated time over
wall time (goal >= 100x real time) and, as a baseline measured in the same run, the same number
of Simulator.step() calls without any middleware.

    python benchmarks/bench_sim_node.py [--duration-s 1800] [--layout type1]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")
os.environ.setdefault("ROS_DOMAIN_ID", str(120 + os.getpid() % 50))

from taiji2_model.config import load_config
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands

TOPICS = {
    "/taiji2/star_tracker": ("taiji2_msgs", "StarTracker"),
    "/taiji2/grs1/voltages": ("taiji2_msgs", "GrsVoltages"),
    "/taiji2/grs2/voltages": ("taiji2_msgs", "GrsVoltages"),
    "/taiji2/sim/angular_rate": ("geometry_msgs", "Vector3Stamped"),
    "/taiji2/sim/angular_acceleration": ("geometry_msgs", "Vector3Stamped"),
    "/taiji2/sim/attitude": ("geometry_msgs", "QuaternionStamped"),
    "/taiji2/sim/applied_wrench": ("geometry_msgs", "WrenchStamped"),
    "/taiji2/sim/grs1/scale_factors": ("taiji2_msgs", "ScaleFactorEstimate"),
    "/taiji2/sim/grs2/scale_factors": ("taiji2_msgs", "ScaleFactorEstimate"),
    "/taiji2/sim/grs1/com_offset": ("taiji2_msgs", "ComOffsetEstimate"),
    "/taiji2/sim/grs2/com_offset": ("taiji2_msgs", "ComOffsetEstimate"),
}


def _spawn(*argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "taiji2_apps.cli.main", *argv],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=1800.0)
    parser.add_argument("--layout", default="type1")
    args = parser.parse_args()
    n = round(args.duration_s * 10)

    config = load_config(args.layout)
    sim = Simulator(config, seed=1)
    commands = maneuver_torque_commands(config, n)
    start = time.perf_counter()
    for k in range(n):
        sim.step(commands[k])
    baseline_s = time.perf_counter() - start

    rclpy.init(args=["bench"])
    node = rclpy.create_node("bench_sim_node_counter")
    counts = dict.fromkeys(TOPICS, 0)
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
    for topic, (pkg, name) in TOPICS.items():
        def count(_msg: object, t: str = topic) -> None:
            counts[t] += 1
        node.create_subscription(getattr(getattr(messages, pkg), name), topic, count, qos)
    commander = _spawn("run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p", f"preset:={args.layout}",
                       "-p", "use_sim_time:=true", "-p", "lookahead_s:=2.0")
    simulator = _spawn("run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args", "-p", f"layout:={args.layout}",
                       "-p", "seed:=1", "-p", f"duration_s:={args.duration_s}",
                       "-p", "wait_for_subscribers:=[1, 1, 1]")
    first = last = None
    try:
        while counts["/taiji2/star_tracker"] < n:
            rclpy.spin_once(node, timeout_sec=0.1)
            if counts["/taiji2/star_tracker"] and first is None:
                first = time.perf_counter()
            if simulator.poll() not in (None, 0):
                raise SystemExit(f"spacecraft_sim failed: {simulator.stderr.read()}")
        last = time.perf_counter()
        deadline = time.monotonic() + 10
        while any(counts[t] < n for t in list(TOPICS)[:7]) and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        for proc in (simulator, commander):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            proc.wait(timeout=20)
        rclpy.shutdown()
    wall_s = last - first
    print(f"simulated {args.duration_s:g} s ({n} steps, {args.layout}) through the node graph in {wall_s:.1f} s wall: "
          f"{args.duration_s / wall_s:.0f}x real time (goal >= 100x)")
    print("samples received per topic (expected: every step on per-step topics, 1 Hz on truth G/d):")
    for topic, count in counts.items():
        print(f"  {topic:36s} {count}")
    print(f"baseline, Simulator.step() x {n} without middleware (same run): {baseline_s:.1f} s = "
          f"{args.duration_s / baseline_s:.0f}x real time; node graph / baseline speed = {baseline_s / wall_s:.2f}")


if __name__ == "__main__":
    main()
