"""Monte Carlo of a designed maneuver (taiji2 design) with the batch simulator + offline estimators vs the CRLB.

Each seed is a pure function ``one(layout, maneuver_file, seed)``, run on Dask (the campaign
engine's ``connect``: an embedded LocalCluster of ``--workers`` single-threaded processes, or
``--scheduler``). Reports error std / CRLB per parameter (goal [0.8, 1.25]) with the standard error
of a std over the seeds, and the peak total linear acceleration against the range (noise included).

    python benchmarks/bench_design_mc.py MANEUVER_FILE [--layout type1] [--seeds 20] [--workers 2]
"""

from __future__ import annotations

import argparse

import numpy as np


def one(layout: str, maneuver_file: str, seed: int) -> dict:
    """Errors, sigmas and range peaks of one seed (all noises on)."""
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.pipeline import calibrate
    from taiji2_model.config import load_config
    from taiji2_model.maneuver_families import load_maneuver_file
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    maneuver = load_maneuver_file(maneuver_file)
    config = load_config(layout, overrides={"maneuver.duration_s": maneuver.duration_s})
    n = round((maneuver.start_s + maneuver.duration_s) / config.dt_s)
    out = simulate_batch(config, seed, maneuver_torque_commands(config, n, maneuver=maneuver))
    g_true = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    d_true = np.concatenate([s.com_offset_m for s in config.grs.sensors])
    r = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, InstrumentModel.from_layout(config))
    return {"g_err": (r.scale_factors.values - g_true) / g_true, "d_err": r.com_offsets.values - d_true,
            "maneuver_peak": np.max(np.abs(out.truth.grs_linear_maneuver), axis=0) / config.grs.range_m_s2,
            "total_peak": np.max(np.abs(out.truth.grs_linear_meas), axis=0) / config.grs.range_m_s2}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maneuver_file")
    parser.add_argument("--layout", default="type1")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--workers", type=int, default=None, help="local Dask workers (default: one per core)")
    parser.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler")
    args = parser.parse_args()
    from taiji2_apps.campaign.engine import connect
    from taiji2_apps.design.evaluate import PARAMETER_NAMES, DesignProblem
    from taiji2_model.maneuver_families import load_maneuver_file

    client, cluster = connect(args.scheduler, args.workers)
    try:
        seeds = [9000 + s for s in range(args.seeds)]
        rows = client.gather(client.map(one, [args.layout] * len(seeds), [args.maneuver_file] * len(seeds), seeds,
                                        pure=False))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    problem = DesignProblem(args.layout)
    maneuver = load_maneuver_file(args.maneuver_file)
    bound = problem.bound(maneuver, maneuver.start_s + maneuver.duration_s)
    g_err = np.array([r["g_err"] for r in rows])
    d_err = np.array([r["d_err"] for r in rows])
    se = 1 / np.sqrt(2 * (args.seeds - 1))
    print(f"{args.layout}, {args.maneuver_file}, {args.seeds} seeds x {maneuver.duration_s:g} s; "
          f"standard error of a std {se:.3f}")
    # one row per parameter: (name, errors over seeds, CRLB, display scale, unit), GRS1 then GRS2, G then d
    table = []
    for i in range(2):
        table += [(PARAMETER_NAMES[6 * i + k], g_err[:, 3 * i + k], bound.scale_factor_relative_sigma[3 * i + k],
                   100.0, "%") for k in range(3)]
        table += [(PARAMETER_NAMES[6 * i + 3 + k], d_err[:, 3 * i + k], bound.com_offset_sigma[3 * i + k], 1e6, "um")
                  for k in range(3)]
    for name, errors, crlb, scale, unit in table:
        std = errors.std(ddof=1)
        print(f"  {name:14} err std {scale * std:.4g} {unit}  CRLB {scale * crlb:.4g} {unit}  "
              f"std/CRLB {std / crlb:.2f}")
    man = np.max([r["maneuver_peak"] for r in rows], axis=0)
    tot = np.max([r["total_peak"] for r in rows], axis=0)
    print(f"  peak maneuver-induced |a| / range (max over seeds): {np.round(man, 3).tolist()}")
    print(f"  peak total |a| / range incl. noise (max over seeds): {np.round(tot, 3).tolist()}")


if __name__ == "__main__":
    main()
