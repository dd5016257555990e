"""Embedded runtime between two OS processes: discovery time and lossless message rate.

Prints the discovery time (publisher creation -> matched) and the reliable keep-all rate of
taiji2_msgs/GrsVoltages between two processes through the runtime, and the same rate with raw
Cyclone DDS (a hand-written IdlStruct, no runtime layer) measured in the same run, as a ratio.

    python benchmarks/bench_runtime.py [--messages 20000]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")
os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))

CHILD = r"""
import sys, time
from taiji2_runtime.ros import rclpy, messages
mode, n = sys.argv[1], int(sys.argv[2])
rclpy.init(args=["bench"])
node = rclpy.create_node("bench_pub")
if mode == "runtime":
    q = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
    t0 = time.perf_counter()
    pub = node.create_publisher(messages.taiji2_msgs.GrsVoltages, "/bench", q)
    while pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.001)
    print(f"DISCOVERY {time.perf_counter() - t0:.4f}", flush=True)
    msg = messages.taiji2_msgs.GrsVoltages(grs_id=1)
    msg.header.frame_id = "tmrf1"
    for i in range(n):
        msg.vx1 = float(i)
        pub.publish(msg)
    pub.wait_for_all_acked(rclpy.duration.Duration(seconds=30))
else:
    from bench_raw_types import Grs_, raw_qos
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    participant = node.context.participant()
    w = DataWriter(participant, Topic(participant, "raw_bench", Grs_), raw_qos())
    while w.get_publication_matched_status().current_count == 0:
        time.sleep(0.001)
    msg = Grs_(frame_id="tmrf1", grs_id=1)
    for i in range(n):
        msg.vx1 = float(i)
        w.write(msg)
    time.sleep(1.0)
rclpy.shutdown()
"""

RAW_TYPES = r"""
from dataclasses import dataclass
import cyclonedds.idl.types as t
from cyclonedds.idl import IdlStruct
from cyclonedds.core import Policy, Qos
from cyclonedds.util import duration

@dataclass
class Grs_(IdlStruct, typename="bench::Grs_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0
    frame_id: str = ""
    grs_id: t.uint8 = 0
    vx1: t.float64 = 0.0
    vx2: t.float64 = 0.0
    vy1: t.float64 = 0.0
    vy2: t.float64 = 0.0
    vz1: t.float64 = 0.0
    vz2: t.float64 = 0.0

def raw_qos():
    return Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll,
               Policy.DataRepresentation(use_cdrv0_representation=True))
"""


def _run(mode: str, n: int, workdir: str) -> tuple[float, float | None]:
    from taiji2_runtime.ros import messages, rclpy

    rclpy.init(args=["bench"])
    node = rclpy.create_node("bench_sub")
    received = 0
    first = last = 0.0

    def count(_msg: object) -> None:
        nonlocal received, first, last
        last = time.perf_counter()
        if received == 0:
            first = last
        received += 1

    if mode == "runtime":
        q = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        node.create_subscription(messages.taiji2_msgs.GrsVoltages, "/bench", count, q)
    else:
        sys.path.insert(0, workdir)
        from bench_raw_types import Grs_, raw_qos
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        participant = node.context.participant()
        reader = DataReader(participant, Topic(participant, "raw_bench", Grs_), raw_qos())
    env = dict(os.environ, PYTHONPATH=workdir + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen([sys.executable, "-c", CHILD, mode, str(n)], env=env, stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while received < n and time.monotonic() < deadline:
        if mode == "runtime":
            rclpy.spin_once(node, timeout_sec=0.01)
        else:
            for _ in reader.take(N=1000):
                count(None)
            time.sleep(0.0005)
    out, _ = child.communicate(timeout=60)
    rclpy.shutdown()
    if received < n:
        raise SystemExit(f"{mode}: lost messages: {received}/{n}")
    discovery = next((float(line.split()[1]) for line in out.splitlines() if line.startswith("DISCOVERY")), None)
    return n / (last - first), discovery


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=20000)
    args = parser.parse_args()
    import tempfile

    with tempfile.TemporaryDirectory() as workdir:
        with open(os.path.join(workdir, "bench_raw_types.py"), "w") as f:
            f.write(RAW_TYPES)
        raw_rate, _ = _run("raw", args.messages, workdir)
        runtime_rate, discovery = _run("runtime", args.messages, workdir)
    print(f"messages: {args.messages} GrsVoltages, reliable keep-all, between two processes, no loss")
    print(f"discovery (publisher created -> matched): {discovery:.3f} s")
    print(f"runtime rate: {runtime_rate:,.0f} msg/s")
    print(f"raw Cyclone DDS rate (same run, baseline): {raw_rate:,.0f} msg/s")
    print(f"ratio runtime / raw: {runtime_rate / raw_rate:.2f}")


if __name__ == "__main__":
    main()
