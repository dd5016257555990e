"""Honesty of the default G estimator with both GRS against each GRS alone, on one maneuver.

Per seed (a pure function ``one(layout, maneuver_file, seed, duration_s, overrides)``, run on Dask: the
campaign engine's ``open_cluster``): the batch simulator with every noise on, then the default (``gls``)
scale-factor estimator three times on the same data: both GRS (with the GRS-pair consistency term), GRS1
alone, GRS2 alone. Prints per parameter std and mean of error / reported sigma over the seeds (goal: std 1,
mean 0; the standard error of a std over N seeds is 1/sqrt(2 (N-1)), of a mean 1/sqrt(N)).

    python benchmarks/bench_scale_factor_pair.py MANEUVER_FILE [--layout type1] [--seeds 48] [--first-seed 9100]
        [--duration-s S] [--override KEY=VALUE ...] [--workers 2] [--rows FILE.jsonl]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

CASES = (("both GRS", (1, 2)), ("GRS1 alone", (1,)), ("GRS2 alone", (2,)))


def one(layout: str, maneuver_file: str, seed: int, duration_s: float | None, overrides: dict) -> dict:
    """error / reported sigma of G for each case of :data:`CASES` on one seed."""
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
    from taiji2_model.config import load_config
    from taiji2_model.maneuver_families import load_maneuver_file
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    maneuver = load_maneuver_file(maneuver_file)
    duration_s = maneuver.duration_s if duration_s is None else duration_s
    config = load_config(layout, overrides={"maneuver.duration_s": duration_s, **overrides})
    n = round((maneuver.start_s + duration_s) / config.dt_s)
    out = simulate_batch(config, seed, maneuver_torque_commands(config, n, maneuver=maneuver))
    g_true = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    instrument = InstrumentModel.from_layout(config)
    row: dict = {"seed": seed}
    for name, ids in CASES:
        columns = [g - 1 for g in ids]
        g = ScaleFactorEstimator(instrument, ids).process_batch(out.t_s, out.st_quat_xyzw, out.voltages_v[:, columns])
        truth = np.concatenate([g_true[3 * (i - 1):3 * i] for i in ids])
        sigma = np.sqrt(np.diag(g.covariance))
        row[name] = ((g.values - truth) / sigma).tolist()
        row[name + " sigma"] = (sigma / truth).tolist()
    return row


def summarize(rows: list[dict]) -> None:
    n = len(rows)
    print(f"{n} seeds; standard error of a std {1 / np.sqrt(2 * max(n - 1, 1)):.3f}, of a mean {1 / np.sqrt(n):.3f}")
    for name, ids in CASES:
        z = np.array([r[name] for r in rows])
        sigma = np.array([r[name + " sigma"] for r in rows]).mean(axis=0)
        labels = [f"GRS{g} {a}" for g in ids for a in ("phi", "theta", "psi")]
        print(f"  {name}:")
        for k, label in enumerate(labels):
            print(f"    {label:10} std(err/sigma) {z[:, k].std(ddof=1):5.2f}  mean {z[:, k].mean():+5.2f}  "
                  f"sigma/G {sigma[k]:.3e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maneuver_file")
    parser.add_argument("--layout", default="type1")
    parser.add_argument("--seeds", type=int, default=48)
    parser.add_argument("--first-seed", type=int, default=9100)
    parser.add_argument("--duration-s", type=float, default=None, help="default: the maneuver's duration")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=VALUE", help="YAML value")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--rows", default=None, help="JSON-lines file of finished seeds (appended, resumed)")
    args = parser.parse_args()
    import yaml

    overrides = {k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in args.override)}
    path = Path(args.rows) if args.rows else None
    rows = [json.loads(line) for line in path.read_text().splitlines()] if path and path.exists() else []
    done = {r["seed"] for r in rows}
    seeds = [s for s in range(args.first_seed, args.first_seed + args.seeds) if s not in done]
    from dask.distributed import as_completed

    from taiji2_apps.campaign.engine import open_cluster

    with open_cluster(None, args.workers) as client:
        futures = client.map(one, [args.layout] * len(seeds), [args.maneuver_file] * len(seeds), seeds,
                             [args.duration_s] * len(seeds), [overrides] * len(seeds), pure=False)
        for future in as_completed(futures):
            rows.append(future.result())
            if path is not None:
                with path.open("a") as handle:
                    handle.write(json.dumps(rows[-1]) + "\n")
    summarize(sorted(rows, key=lambda r: r["seed"]))


if __name__ == "__main__":
    main()
