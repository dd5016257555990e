"""A plain Cyclone DDS reader of /taiji2/star_tracker (reliable, keep-all), run as its own process.

Prints "ready" once created, "first" at the first sample, then, when ``expected`` samples arrived
or the topic has been quiet for ``quiet_s``, prints the number of distinct stamps received and exits. A test stops this
process (SIGSTOP) to make it a stalled peer of the simulator.
"""

import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from taiji2_runtime.dds_rclpy.context import Context
from taiji2_runtime.interfaces import message_module


def main() -> None:
    expected, quiet_s = int(sys.argv[1]), float(sys.argv[2])
    ctx = Context()  # the project's default Cyclone configuration (loopback) and ROS_DOMAIN_ID
    ctx.init(["slow_reader"])
    star = message_module("taiji2_msgs").StarTracker
    reader = DataReader(ctx.participant(), Topic(ctx.participant(), "rt/taiji2/star_tracker", star),
                        Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll,
                            Policy.Durability.Volatile))
    print("ready", flush=True)
    stamps: set[int] = set()
    last = time.monotonic()
    # quiet_s of silence ends the reading once samples flowed; before the first one the simulator may still
    # be starting (its imports alone take seconds on a busy machine), which the test bounds itself
    while len(stamps) < expected and (not stamps or time.monotonic() - last < quiet_s):
        samples = reader.take(N=1000)
        if samples:
            if not stamps:
                print("first", flush=True)
            last = time.monotonic()
            stamps.update(s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec for s in samples)
        else:
            time.sleep(0.01)
    print(len(stamps), flush=True)
    ctx.shutdown()


if __name__ == "__main__":
    main()
