"""Estimator nodes' throughput: raw messages per second through each node, as a multiple of real time.

For each runtime available in this interpreter (the embedded runtime always; real rclpy when ``import rclpy``
works, i.e. in a shell that sourced ROS 2 and the colcon workspace) and each estimator node, in the same run:
a feeder process publishes a batch-simulated Type-1 record (reliable keep-all, as the simulator does, so the
node's speed back-pressures the feeder and nothing is lost) and the node under test runs in this process on
its own executor until it has processed the last epoch. Printed per node: messages/s, epochs/s and simulated
time over wall time (goal >= 100x real time), and, as a baseline measured in the same run, the node's core
estimator fed the same epochs directly (no middleware, no node glue). The feeder's own publishing rate is
printed too: a node rate close to it means the feeder, not the node, was the limit.

    python benchmarks/bench_estimator_nodes.py [--duration-s 600] [--repeats 1]
    # both runtimes: source /opt/ros/jazzy/setup.bash and the workspace's install/setup.bash first
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 10))

HERE = Path(__file__).resolve()
NODES = ("scale_factor_estimator", "com_offset_estimator")
STREAMS = {"scale_factor_estimator": ("star_tracker", "grs1", "grs2"), "com_offset_estimator": ("grs1", "grs2")}
TOPICS = {"star_tracker": "/taiji2/star_tracker", "grs1": "/taiji2/grs1/voltages", "grs2": "/taiji2/grs2/voltages"}
SEED = 26
#: G of both GRS in the Type-1 layout [rad s^-2 V^-1] (the scale factors the c.m.-offset estimator is given)
NOMINAL_G = (5.524e-8, 5.524e-8, 7.365e-8)


def _experiment(duration_s: float):
    from taiji2_model.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    n = round(duration_s * 10)
    config = load_config("type1", overrides={"maneuver.duration_s": duration_s})
    return config, simulate_batch(config, SEED, maneuver_torque_commands(config, n))


def feed(node_name: str, duration_s: float) -> None:
    """Publish the record's raw streams (and, for the c.m.-offset estimator, one nominal G) as fast as taken."""
    from taiji2_runtime.ros import messages, rclpy

    _, out = _experiment(duration_s)
    rclpy.init()
    node = rclpy.node.Node("bench_feeder")
    t = messages.taiji2_msgs
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                               reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
    streams = STREAMS[node_name]
    pubs = {s: node.create_publisher(t.StarTracker if s == "star_tracker" else t.GrsVoltages, TOPICS[s], qos)
            for s in streams}
    msgs = []
    for k in range(out.t_s.size):
        sec, nanosec = divmod(round(out.t_s[k] * 1e9), 10**9)
        for s in streams:
            if s == "star_tracker":
                m = t.StarTracker()
                m.header.frame_id = "crf"
                m.attitude.x, m.attitude.y, m.attitude.z, m.attitude.w = (float(v) for v in out.st_quat_xyzw[k])
            else:
                g = int(s[-1])
                m = t.GrsVoltages(grs_id=g)
                m.header.frame_id = f"tmrf{g}"
                m.vx1, m.vx2, m.vy1, m.vy2, m.vz1, m.vz2 = (float(x) for x in out.voltages_v[k][g - 1])
            m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
            msgs.append((pubs[s], m))
    if node_name == "com_offset_estimator":
        latched = rclpy.qos.QoSProfile(depth=1, reliability=rclpy.qos.ReliabilityPolicy.RELIABLE,
                                       durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        for g in (1, 2):
            pub = node.create_publisher(t.ScaleFactorEstimate, f"/taiji2/estimates/grs{g}/scale_factors", latched)
            m = t.ScaleFactorEstimate(grs_id=g, method="gls")
            m.header.frame_id = f"tmrf{g}"
            # stamped at the record's end: the node waits (up to 30 s of wall time) for scale factors as new as
            # the data, which a feeder of raw data alone never sends; stamped 0 this measured that wait (18x)
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(round(out.t_s[-1] * 1e9), 10**9)
            m.scale_factors = list(NOMINAL_G)
            m.covariance = [1e-22 if i % 4 == 0 else 0.0 for i in range(9)]
            m.cross_covariance = [0.0] * 9
            pub.publish(m)
    while not all(p.get_subscription_count() >= 1 for p in pubs.values()):
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)  # the node's readers matched every writer
    start = time.perf_counter()
    for pub, m in msgs:
        pub.publish(m)
    for pub in pubs.values():
        pub.wait_for_all_acked(rclpy.duration.Duration(seconds=60))
    wall = time.perf_counter() - start
    print(json.dumps({"feeder_msgs_per_s": len(msgs) / wall}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def run_node(node_name: str, duration_s: float) -> dict:
    """The node under test in this process, fed by a feeder process; returns its rates."""
    from taiji2_runtime.ros import RUNTIME, rclpy
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()
    if node_name == "scale_factor_estimator":
        from taiji2_estimator_pkg.nodes.scale_factor_estimator import ScaleFactorEstimatorNode as Cls
    else:
        from taiji2_estimator_pkg.nodes.com_offset_estimator import ComOffsetEstimatorNode as Cls
    n = round(duration_s * 10)
    last_ns = round(n * 1e8)  # the record's last stamp: n samples at 0.1 s from 0.1 s
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = Cls(context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    feeder = subprocess.Popen([sys.executable, str(HERE), "--role", "feed", "--node", node_name,
                               "--duration-s", str(duration_s)], stdout=subprocess.PIPE, text=True)
    start = None
    deadline = time.monotonic() + 600
    while node.last_t_ns < last_ns and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
        if start is None and node.last_t_ns >= 0:
            start = time.perf_counter()
    end = time.perf_counter()
    out, _ = feeder.communicate(timeout=120)
    feeder_rate = json.loads(out.strip().splitlines()[-1])["feeder_msgs_per_s"] if out.strip() else float("nan")
    done = node.last_t_ns >= last_ns
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    wall = end - (start or end)
    msgs = n * len(STREAMS[node_name])
    return {"runtime": RUNTIME, "node": node_name, "complete": done, "wall_s": wall, "msgs_per_s": msgs / wall,
            "epochs_per_s": n / wall, "x_real_time": duration_s / wall, "feeder_msgs_per_s": feeder_rate}


def core_baseline(node_name: str, duration_s: float) -> dict:
    """The node's core estimator fed the same epochs in a loop (no middleware, no node glue)."""
    import numpy as np

    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.parameters import DEFAULTS, com_offset_options, scale_factor_options
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()
    _, out = _experiment(duration_s)
    params = dict(DEFAULTS[node_name])
    instrument = InstrumentModel.from_layout("type1")
    start = time.perf_counter()
    if node_name == "scale_factor_estimator":
        from taiji2_estimator_pkg.core.scale_factor import ScaleFactorEstimator

        est = ScaleFactorEstimator(instrument, (1, 2), scale_factor_options(params))
        for k in range(out.t_s.size):
            est.update(float(out.t_s[k]), out.st_quat_xyzw[k], {1: out.voltages_v[k][0], 2: out.voltages_v[k][1]})
    else:
        from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator

        est = ComOffsetEstimator(instrument, (1, 2), com_offset_options(params))
        g = np.array(NOMINAL_G * 2)
        prior = (g, np.diag((g * 1e-3) ** 2))
        for k in range(out.t_s.size):
            est.update(float(out.t_s[k]), {1: out.voltages_v[k][0], 2: out.voltages_v[k][1]}, None,
                       scale_factors=prior)
    wall = time.perf_counter() - start
    return {"runtime": "none (core)", "node": node_name, "wall_s": wall, "epochs_per_s": out.t_s.size / wall,
            "x_real_time": duration_s / wall}


def _rclpy_available() -> bool:
    probe = subprocess.run([sys.executable, "-c", "import rclpy, taiji2_msgs.msg"], capture_output=True)
    return probe.returncode == 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=600.0, help="simulated record length [s]")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--role", choices=("all", "node", "feed"), default="all", help=argparse.SUPPRESS)
    parser.add_argument("--node", choices=NODES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "feed":
        feed(args.node, args.duration_s)
        return
    if args.role == "node":
        print(json.dumps(run_node(args.node, args.duration_s)), flush=True)
        return
    runtimes = ["cyclonedds"] + (["rclpy"] if _rclpy_available() else [])
    if "rclpy" not in runtimes:
        print("rclpy not importable here: the embedded runtime only (source ROS 2 and the workspace for both)")
    rows = []
    for _ in range(args.repeats):
        for node_name in NODES:
            rows.append(core_baseline(node_name, args.duration_s))
            for runtime in runtimes:
                env = {**os.environ, "TAIJI2_RUNTIME": runtime}
                out = subprocess.run([sys.executable, str(HERE), "--role", "node", "--node", node_name,
                                      "--duration-s", str(args.duration_s)], env=env, capture_output=True,
                                     text=True, timeout=900)
                lines = [line for line in out.stdout.splitlines() if line.startswith("{")]
                if out.returncode != 0 or not lines:
                    print(f"{node_name} on {runtime} failed:\n{out.stderr[-2000:]}")
                    continue
                rows.append(json.loads(lines[-1]))
    print(f"\n{args.duration_s:.0f} s Type-1 record ({round(args.duration_s * 10)} epochs), goal >= 100x real time")
    print(f"{'node':24s} {'runtime':12s} {'msgs/s':>9s} {'epochs/s':>9s} {'x real time':>12s} {'feeder msgs/s':>14s}")
    for r in rows:
        incomplete = "" if r.get("complete", True) else "  INCOMPLETE"
        print(f"{r['node']:24s} {r['runtime']:12s} {r.get('msgs_per_s', float('nan')):9.0f} "
              f"{r['epochs_per_s']:9.0f} {r['x_real_time']:11.1f}x {r.get('feeder_msgs_per_s', float('nan')):14.0f}"
              f"{incomplete}")


if __name__ == "__main__":
    main()
