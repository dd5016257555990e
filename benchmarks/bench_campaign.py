"""Campaign engine: throughput with 1 and 2 Dask workers, and the engine's per-case overhead.

The same cases (3-h Type-1, gls, distinct seeds) run on a LocalCluster of 1 worker, then of 2
workers, in the same run. Throughput ratio = (cases/s with 2) / (cases/s with 1) (goal >= 1.8 on
2 cores). Engine overhead = (wall x workers - sum of case compute) / sum of case compute, where
case compute is timed inside the worker (goal <= 5 %); cluster start-up is excluded from wall.

    python benchmarks/bench_campaign.py [--cases 12] [--duration-s 10800]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from taiji2_estimator_pkg.campaign.engine import run_campaign
from taiji2_estimator_pkg.campaign.spec import load_spec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=12)
    parser.add_argument("--duration-s", type=float, default=10800.0)
    args = parser.parse_args()
    results = {}
    for workers in (1, 2):
        spec = load_spec({"name": f"bench_{workers}", "layouts": ["type1"], "durations_s": [args.duration_s],
                          "seeds": {"start": 7000 + 1000 * workers, "count": args.cases}, "methods": ["gls"]})
        with tempfile.TemporaryDirectory() as tmp:
            run = run_campaign(spec, Path(tmp), workers=workers, progress=None)
        results[workers] = run
        rate = run.completed / run.wall_s
        overhead = run.wall_s * run.workers / run.compute_s - 1
        print(f"{workers} worker(s): {run.completed} cases in {run.wall_s:.1f} s wall = {rate:.3f} cases/s; "
              f"mean case compute {run.compute_s / run.completed:.2f} s; engine overhead {overhead:+.1%}")
    ratio = (results[2].completed / results[2].wall_s) / (results[1].completed / results[1].wall_s)
    print(f"throughput 2 workers / 1 worker: {ratio:.2f}x (goal >= 1.8x)")


if __name__ == "__main__":
    main()
