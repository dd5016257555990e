"""Scale factors only: a large Monte Carlo (default 100 seeds x 3 h) of the default method against the CRLB.

The sample standard deviation of n seeds has a relative standard error of about 1/sqrt(2(n-1))
(13 % at 30 seeds, 7 % at 100): this settles whether error std / CRLB departs from 1.

    python benchmarks/bench_scale_factor_mc.py [--seeds 100] [--layout type1] [--processes 2]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def one(args: tuple[str, int, float]) -> tuple[list[float], list[float]]:
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.scale_factor import ScaleFactorEstimator
    from taiji2_sim_pkg.core.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    layout, seed, duration_s = args
    config = load_config(layout, overrides={"maneuver.duration_s": duration_s})
    out = simulate_batch(config, seed, maneuver_torque_commands(config))
    g = ScaleFactorEstimator(InstrumentModel.from_layout(config), (1, 2)).process_batch(
        out.t_s, out.st_quat_xyzw, out.voltages_v)
    truth = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    return ((g.values - truth) / truth).tolist(), (g.sigma / truth).tolist()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--layout", default="type1")
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--processes", type=int, default=2)
    args = parser.parse_args()
    from taiji2_estimator_pkg.core.crlb import crlb_for_layout

    jobs = [(args.layout, 5000 + s, args.duration_s) for s in range(args.seeds)]
    with ProcessPoolExecutor(max_workers=args.processes) as pool:
        rows = list(pool.map(one, jobs))
    err = np.array([r[0] for r in rows]) * 100
    sig = np.array([r[1] for r in rows]) * 100
    crlb = np.asarray(crlb_for_layout(args.layout, args.duration_s).scale_factor_relative_sigma) * 100
    se = 1 / np.sqrt(2 * (args.seeds - 1))
    print(f"{args.layout}, {args.seeds} seeds x {args.duration_s:g} s; relative standard error of a std: {se:.3f}")
    print(f"  {'parameter':14} {'mean err %':>10} {'err std %':>10} {'mean sig %':>10} {'CRLB %':>9} "
          f"{'std/sig':>8} {'std/CRLB':>8}")
    for j, name in enumerate(f"GRS{g} {p}" for g in (1, 2) for p in ("G_Pphi", "G_Ptheta", "G_Ppsi")):
        std = err[:, j].std(ddof=1)
        print(f"  {name:14} {err[:, j].mean():10.4f} {std:10.4f} {sig[:, j].mean():10.4f} {crlb[j]:9.4f} "
              f"{std / sig[:, j].mean():8.2f} {std / crlb[j]:8.2f}")


if __name__ == "__main__":
    main()
