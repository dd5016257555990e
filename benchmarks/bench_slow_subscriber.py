"""A 3-h accelerated spacecraft_sim run with a deliberately slow reliable subscriber.

The reader (a plain Cyclone DDS reader of /taiji2/star_tracker, reliable keep-all, in its own process)
sleeps ``--reader-delay-ms`` after each sample, so it is slower than the accelerated simulator and the
simulator must pace itself to it (back-pressure). Reports: the simulator's exit status, samples delivered
of those published, wall time, and the ratio of that wall time to a baseline run without the slow reader
measured in the same invocation (both on this machine, under its current load).

    python benchmarks/bench_slow_subscriber.py [--duration-s 10800] [--reader-delay-ms 1.0]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import textwrap
import time

READER = textwrap.dedent("""
    import sys, time
    from cyclonedds.core import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
    from taiji2_runtime.dds_rclpy.context import Context
    from taiji2_runtime.interfaces import message_module
    expected, delay_s = int(sys.argv[1]), float(sys.argv[2]) / 1000.0
    ctx = Context()
    ctx.init(["slow_subscriber"])
    star = message_module("taiji2_msgs").StarTracker
    reader = DataReader(ctx.participant(), Topic(ctx.participant(), "rt/taiji2/star_tracker", star),
                        Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll))
    print("ready", flush=True)
    stamps, last = set(), time.monotonic()
    while len(stamps) < expected and time.monotonic() - last < 60.0:
        samples = reader.take(N=1)
        if not samples:
            time.sleep(0.001)
            continue
        last = time.monotonic()
        stamps.update(s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec for s in samples)
        time.sleep(delay_s)  # the deliberately slow part
    print(len(stamps), flush=True)
    ctx.shutdown()
""")


def _sim(duration_s: float, subscribers: int) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "taiji2_apps.cli.main", "run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args",
         "-p", f"duration_s:={duration_s}", "-p", "sync_with_command:=false", "-p", "seed:=1",
         "-p", "publish_truth:=false", "-p", f"wait_for_subscribers:=[{subscribers}, 0, 0]",
         "-p", "config_overrides:=" + f'["maneuver.duration_s={duration_s}"]'],
        env=dict(os.environ, PYTHONUNBUFFERED="1"), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=10800.0, help="simulated duration [s] (default 3 h)")
    parser.add_argument("--reader-delay-ms", type=float, default=1.0, help="reader sleep after each sample [ms]")
    args = parser.parse_args()
    steps = round(args.duration_s * 10)

    start = time.monotonic()
    baseline = _sim(args.duration_s, 0)
    baseline.communicate()
    baseline_s = time.monotonic() - start

    reader = subprocess.Popen([sys.executable, "-c", READER, str(steps), str(args.reader_delay_ms)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert reader.stdout.readline().strip() == "ready"
    start = time.monotonic()
    sim = _sim(args.duration_s, 1)
    _, sim_err = sim.communicate()
    slow_s = time.monotonic() - start
    received = int(reader.communicate(timeout=120)[0].strip() or 0)
    print(f"simulated {args.duration_s:g} s ({steps} steps); baseline (no subscriber): exit {baseline.returncode}, "
          f"{baseline_s:.1f} s wall")
    print(f"slow reliable subscriber ({args.reader_delay_ms:g} ms per sample): simulator exit {sim.returncode}, "
          f"{slow_s:.1f} s wall ({slow_s / baseline_s:.2f} x baseline), {received} of {steps} samples delivered, "
          f"error lines: {sum('error' in line.lower() for line in sim_err.splitlines())}")
    return 0 if sim.returncode == 0 and received == steps else 1


if __name__ == "__main__":
    raise SystemExit(main())
