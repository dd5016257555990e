"""Benchmark: bag record / play at >= 100x real time without loss, and bulk loading of a 3-h bag.

1. Record / play: a simulated 10-min Type-1 experiment bag (star tracker, both GRS at 10 Hz, the
   command at 10 Hz, /clock) is played with ``taiji2 bag play --rate 100`` (and ``--fast``) into a
   ``taiji2 bag record`` of the same topics, in separate processes; the recorded bag must hold every
   message byte for byte. Printed: the achieved ratio to real time and the message counts.
2. Bulk load: a 3-h two-GRS experiment bag (324,000 raw samples + 10,800 commands) is loaded with
   ``load_raw_bag``; printed are the seconds, the ratio to real time and the ratio to a baseline
   measured in the same run: plain rosbags ``Reader`` + ``typestore.deserialize_cdr`` of every message.

Usage (from the workspace root)::

    python benchmarks/bench_bag.py [--hours 3] [--play-minutes 10] [--rate 100] [--storage mcap|sqlite3]
                                   [--skip-live] [--repeats 3]
"""

import argparse
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from taiji2_model.config import load_config
from taiji2_runtime.bag.bulk_decode import encode_messages
from taiji2_runtime.bag.provenance import simulator_provenance
from taiji2_runtime.bag.writer import BagWriter
from taiji2_runtime.interfaces import typestore
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands

REPO = Path(__file__).resolve().parents[1]
try:
    from taiji2_estimator_pkg.io import load_raw_bag
except ImportError:  # an editable install made before the package had modules
    sys.path.insert(0, str(REPO / "src" / "taiji2_estimator_pkg"))
    from taiji2_estimator_pkg.io import load_raw_bag

SEED = 1234
RAW = ["/taiji2/star_tracker", "/taiji2/grs1/voltages", "/taiji2/grs2/voltages", "/taiji2/maneuver/command"]


def write_experiment_bag(path, seconds, storage="mcap", command_every=10, clock=False):
    """Simulate ``seconds`` of a Type-1 experiment and write it as the recorder would (bag stamp = t)."""
    store = typestore()
    cfg = load_config("type1", overrides={"maneuver.duration_s": float(seconds)})
    commands = maneuver_torque_commands(cfg)
    sim = Simulator(cfg, seed=SEED)
    out = sim.advance(commands)
    n = len(out)
    stamp_ns = np.round(out.t_s * 1e9).astype(np.int64)
    sec, nsec = stamp_ns // 10**9, stamp_ns % 10**9
    st = encode_messages(store, "taiji2_msgs/msg/StarTracker", {
        "header.stamp.sec": sec, "header.stamp.nanosec": nsec, "header.frame_id": "crf",
        "attitude.x": out.st_quat_xyzw[:, 0], "attitude.y": out.st_quat_xyzw[:, 1],
        "attitude.z": out.st_quat_xyzw[:, 2], "attitude.w": out.st_quat_xyzw[:, 3],
        "attitude_covariance": out.st_cov_rad2}, n)
    grs = []
    for i in range(2):
        v = out.voltages_v[:, i, :]
        grs.append(encode_messages(store, "taiji2_msgs/msg/GrsVoltages", {
            "header.stamp.sec": sec, "header.stamp.nanosec": nsec, "header.frame_id": f"tmrf{i + 1}",
            "grs_id": i + 1, **{k: v[:, j] for j, k in enumerate(("vx1", "vx2", "vy1", "vy2", "vz1", "vz2"))}}, n))
    cmd_rows = np.arange(0, n, command_every)
    cmd_ns = np.round((out.t_s[cmd_rows] - cfg.dt_s) * 1e9).astype(np.int64)
    cmd = encode_messages(store, "geometry_msgs/msg/WrenchStamped", {
        "header.stamp.sec": cmd_ns // 10**9, "header.stamp.nanosec": cmd_ns % 10**9, "header.frame_id": "crf",
        "wrench.torque.x": commands[cmd_rows, 0], "wrench.torque.y": commands[cmd_rows, 1],
        "wrench.torque.z": commands[cmd_rows, 2]}, len(cmd_rows))
    clk = encode_messages(store, "rosgraph_msgs/msg/Clock", {"clock.sec": sec, "clock.nanosec": nsec}, n)
    writer = BagWriter(path, store, storage=storage, segment_period_s=math.inf)
    types = ["taiji2_msgs/msg/StarTracker", "taiji2_msgs/msg/GrsVoltages", "taiji2_msgs/msg/GrsVoltages",
             "geometry_msgs/msg/WrenchStamped"]
    h = {t: writer.add_topic(t, mt) for t, mt in zip(RAW, types, strict=True)}
    if clock:
        h["/clock"] = writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    for key, value in simulator_provenance(json.dumps(sim.provenance())).items():
        writer.set_custom_data(key, value)
    c = 0
    for k in range(n):
        t = int(stamp_ns[k])
        if clock:
            writer.write(h["/clock"], t, clk[k])
        if c < len(cmd_rows) and cmd_rows[c] == k:
            writer.write(h["/taiji2/maneuver/command"], t, cmd[c])
            c += 1
        writer.write(h["/taiji2/star_tracker"], t, st[k])
        writer.write(h["/taiji2/grs1/voltages"], t, grs[0][k])
        writer.write(h["/taiji2/grs2/voltages"], t, grs[1][k])
    writer.close()
    return n * 3 + len(cmd_rows) + (n if clock else 0), n * cfg.dt_s


def _messages_by_topic(bag):
    out = {}
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            out.setdefault(connection.topic, []).append(data)
    return out


def _env():
    env = dict(os.environ)
    env.setdefault("ROS_DOMAIN_ID", str(120 + os.getpid() % 80))
    env["PYTHONUNBUFFERED"] = "1"
    return env


def live(workdir, minutes, rate, storage):
    bag = workdir / "ten_minutes"
    count, span_s = write_experiment_bag(bag, minutes * 60, storage, command_every=1, clock=True)
    print(f"\n[record / play] {span_s / 60:.0f}-min bag: {count} messages on {len(RAW) + 1} topics")
    topics = [*RAW, "/clock"]
    original = _messages_by_topic(bag)
    env = _env()
    cli = [sys.executable, "-m", "taiji2_apps.cli.main", "bag"]
    for label, speed in ((f"--rate {rate:g}", ["--rate", str(rate)]), ("--fast", ["--fast"])):
        out = workdir / f"recorded_{label.strip('-').replace(' ', '_')}"
        recorder = subprocess.Popen([*cli, "record", *topics, "-o", str(out), "-s", storage], env=env,
                                    stderr=subprocess.PIPE, text=True)
        try:
            time.sleep(1.0)
            play = subprocess.run([*cli, "play", str(bag), *speed, "--wait-for-subscribers", "1"], env=env,
                                  capture_output=True, text=True, timeout=600)
            if play.returncode:
                raise SystemExit(f"play failed: {play.stderr}")
        finally:
            recorder.send_signal(signal.SIGINT)
            _, rec_err = recorder.communicate(timeout=120)
        if recorder.returncode:
            raise SystemExit(f"record failed: {rec_err}")
        summary = play.stderr.strip().splitlines()[0]
        recorded = _messages_by_topic(out)
        lost = {t: len(original[t]) - len(recorded.get(t, [])) for t in topics}
        exact = all(recorded.get(t) == original[t] for t in topics)
        print(f"  play {label:12s}: {summary}")
        print(f"  recorded: {sum(len(v) for v in recorded.values())} / {count} messages, "
              f"lost per topic {lost}, byte-identical and in order: {exact}")


def bulk(workdir, hours, storage, repeats):
    bag = workdir / f"three_hours_{storage}"
    start = time.perf_counter()
    count, span_s = write_experiment_bag(bag, hours * 3600, storage)
    size = sum(p.stat().st_size for p in bag.iterdir())
    print(f"\n[bulk load] {hours:g}-h two-GRS bag ({storage}): {count} messages, {size / 2**20:.1f} MiB "
          f"(written in {time.perf_counter() - start:.1f} s)")
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        exp = load_raw_bag(bag)
        times.append(time.perf_counter() - t0)
    assert len(exp.star_tracker) == len(exp.grs1) == len(exp.grs2) == round(span_s * 10)
    store = typestore()
    t0 = time.perf_counter()
    n = 0
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            store.deserialize_cdr(data, connection.msgtype)
            n += 1
    baseline = time.perf_counter() - t0
    best, median = min(times), statistics.median(times)
    print(f"  load_raw_bag          : best {best:.3f} s, median {median:.3f} s of {repeats} -> "
          f"{span_s / best:,.0f}x real time (best), {span_s / median:,.0f}x (median)")
    print(f"  baseline (rosbags Reader + deserialize_cdr, {n} messages): {baseline:.3f} s -> "
          f"{span_s / baseline:,.0f}x real time")
    print(f"  load_raw_bag vs baseline: {baseline / best:.1f}x faster (best), {baseline / median:.1f}x (median)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=3.0, help="bulk-load bag length [h]")
    parser.add_argument("--play-minutes", type=float, default=10.0, help="record/play bag length [min]")
    parser.add_argument("--rate", type=float, default=100.0, help="play rate factor")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--repeats", type=int, default=3, help="timed repetitions of the bulk load")
    parser.add_argument("--skip-live", action="store_true", help="only the bulk-load part (no DDS)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_bag_") as tmp:
        workdir = Path(tmp)
        bulk(workdir, args.hours, args.storage, args.repeats)
        if not args.skip_live:
            live(workdir, args.play_minutes, args.rate, args.storage)


if __name__ == "__main__":
    main()
