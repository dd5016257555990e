"""Benchmark: batch simulation of a whole calibration experiment against real time.

Simulates a 3 h Type-1 experiment (both GRS, all noise sources, the paper's maneuver) with
``simulate_batch`` and prints the wall time and the ratio to real time (goal: >= 100,000x, i.e.
within about 2x of drawing its random numbers alone).
Baselines measured in the same run, for scale:

- ``step()`` loop: the streaming simulator over the first 10 min, extrapolated to the whole run;
- RNG floor: drawing the same number of normal variates with plain numpy (the irreducible cost).

Then the peak linear accelerations of both layouts (maneuver-induced part and total with noise)
against the GRS range.

Usage (from the workspace root)::

    PYTHONPATH=src/taiji2_sim_pkg python benchmarks/bench_sim_batch.py [--hours 3] [--repeats 5]
"""

import argparse
import statistics
import time

import numpy as np

from taiji2_model.config import load_config
from taiji2_sim_pkg.core.range_check import peak_linear_report
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands, simulate_batch

SEED = 1234
STEP_BASELINE_S = 600.0  # streaming baseline over the first 10 min
NORMALS_PER_STEP = 3 + 3 + 3 + 6 + 6 + 6 + 12 + 3  # torque, force, SRP, LFS t/r, TM env, voltage, ST


def time_call(function, repeats):
    times = []
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return times, result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=3.0, help="experiment length [h]")
    parser.add_argument("--repeats", type=int, default=5, help="timed repetitions of the batch run")
    args = parser.parse_args()

    cfg = load_config("type1", overrides={"maneuver.duration_s": args.hours * 3600.0})
    commands = maneuver_torque_commands(cfg)
    n_steps = commands.shape[0]
    sim_time_s = n_steps * cfg.dt_s
    print(f"Type-1, all noise on, {n_steps} steps at {cfg.sample_rate_hz:g} Hz = {sim_time_s / 3600:.2f} h "
          f"of simulated time, seed {SEED}")

    simulate_batch(cfg, SEED, commands[:1000])  # warm-up (imports, caches)
    times, out = time_call(lambda: simulate_batch(cfg, SEED, commands), args.repeats)
    best, median = min(times), statistics.median(times)
    print(f"simulate_batch        : best {best:.3f} s, median {median:.3f} s of {args.repeats} -> "
          f"{sim_time_s / best:,.0f}x real time (best), {sim_time_s / median:,.0f}x (median)")

    n_baseline = round(STEP_BASELINE_S * cfg.sample_rate_hz)
    sim = Simulator(cfg, seed=SEED)
    start = time.perf_counter()
    for k in range(n_baseline):
        sim.step(commands[k])
    step_s = (time.perf_counter() - start) / n_baseline
    print(f"step() loop (first {STEP_BASELINE_S / 60:.0f} min): {step_s * 1e6:.0f} us/step -> whole run "
          f"{step_s * n_steps:.1f} s extrapolated, {cfg.dt_s / step_s:,.0f}x real time; batch is "
          f"{step_s * n_steps / median:.0f}x faster")

    rng = np.random.default_rng(SEED)
    rng_times, _ = time_call(lambda: rng.standard_normal((n_steps, NORMALS_PER_STEP)), args.repeats)
    rng_s = statistics.median(rng_times)
    print(f"numpy RNG floor       : {rng_s:.3f} s for the same {n_steps * NORMALS_PER_STEP:,} normals "
          f"({sim_time_s / rng_s:,.0f}x real time); batch costs {median / rng_s:.1f}x the bare draws")
    speed = sim_time_s / median
    print(f"goal >= 100,000x real time (median): {speed:,.0f}x, {'ok' if speed >= 1e5 else 'MISSED'}; "
          f"batch / bare draws {median / rng_s:.2f}x (goal <= 2)")

    print()
    for layout in ("type1", "type2"):
        layout_cfg = load_config(layout, overrides={"maneuver.duration_s": args.hours * 3600.0})
        layout_out = (out if layout == "type1"
                      else simulate_batch(layout_cfg, SEED, maneuver_torque_commands(layout_cfg)))
        report = peak_linear_report(layout_out, layout_cfg.grs.range_m_s2)
        print(f"{layout}, all noise on, {args.hours:g} h:")
        print(report.format())
        quiet_cfg = load_config(layout, overrides={"maneuver.duration_s": args.hours * 3600.0,
                                                   **{f"noise.{name}.enabled": False
                                                      for name in layout_cfg.to_dict()["noise"]}})
        quiet = peak_linear_report(simulate_batch(quiet_cfg, SEED, maneuver_torque_commands(quiet_cfg)),
                                   quiet_cfg.grs.range_m_s2)
        print(f"  maneuver part with all noise off: max {quiet.maneuver_fraction.max():.1%} of range "
              f"(GRS1 x y z: " + ", ".join(f"{v:.1%}" for v in quiet.maneuver_fraction[0]) + ")")
        print(f"  total with noise: max {report.total_fraction.max():.1%} of range, "
              f"{int(report.total_excursions.sum())} excursions beyond it")


if __name__ == "__main__":
    main()
