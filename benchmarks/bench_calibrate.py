"""Offline calibration of a 3-h, two-GRS experiment bag: `taiji2 calibrate` end to end.

Writes a contract bag (MCAP, the raw topics only, as a ground segment would with rosbags) of a
simulated 3-h Type-1 experiment, then times, in the same run:
  * calibrate: bulk bag load + alignment + both estimator cores (the work of `taiji2 calibrate`);
  * baseline: plain rosbags Reader + deserialize_cdr of every message of the same bag.
Prints seconds, the ratio to real time (goal >= 5000x) and the ratio to the baseline.

    python benchmarks/bench_calibrate.py [--duration-s 10800] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
from taiji2_estimator_pkg.calibration import align_streams, calibrate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.io import load_raw_bag
from taiji2_sim_pkg.core.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

from contract_bags import ground_segment_store, simulated_data, write_ground_segment_bag


def calibrate_bag(path: Path) -> object:
    raw = load_raw_bag(path)
    instrument = InstrumentModel.from_layout("type1")
    grs = {g: (raw.grs(g).stamp_ns, raw.grs(g).voltages_v) for g in (1, 2)}
    record = align_streams(raw.star_tracker.stamp_ns, raw.star_tracker.quat_xyzw, grs, instrument.sample_rate_hz)
    return calibrate(record, instrument)


def baseline_read(path: Path) -> int:
    store = ground_segment_store()
    count = 0
    with Reader(path) as reader:
        for connection, _, raw in reader.messages():
            store.deserialize_cdr(raw, connection.msgtype)
            count += 1
    return count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    config = load_config("type1", overrides={"maneuver.duration_s": args.duration_s})
    out = simulate_batch(config, 7, maneuver_torque_commands(config))
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "experiment"
        write_ground_segment_bag(bag, "mcap", simulated_data(out))
        calib_s, base_s = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            table = calibrate_bag(bag)
            calib_s.append(time.perf_counter() - start)
            start = time.perf_counter()
            messages = baseline_read(bag)
            base_s.append(time.perf_counter() - start)
    best, base = min(calib_s), min(base_s)
    g = table.grs[0]
    truth = np.asarray(config.grs.sensors[0].angular_scale_factors)
    print(f"bag: {args.duration_s:g} s, {messages} messages (raw contract topics, MCAP)")
    print(f"taiji2 calibrate work (load + align + both cores): best {best:.2f} s of {args.repeats} -> "
          f"{args.duration_s / best:,.0f}x real time (goal >= 5000x)")
    print(f"baseline, rosbags Reader + deserialize_cdr of every message (same run): best {base:.2f} s; "
          f"calibrate / baseline time = {best / base:.2f}")
    z = (g.scale_factors - truth) / np.sqrt(np.diag(g.scale_factors_cov))
    print(f"sanity: GRS1 G error / sigma = {np.round(z, 2)}")


if __name__ == "__main__":
    main()
