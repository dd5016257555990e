"""Campaign engine against a plain process pool: per-case compute and throughput on the same cases.

For each worker count (``--workers``, default 1,2; ``--workers 1,2,16`` on a 16-core machine) the
same cases (3-h Type-1, gls, CRLB, distinct seeds) run, in the same run,

* on a plain ``concurrent.futures.ProcessPoolExecutor`` of that many processes calling
  ``run_case`` (the baseline; spawned like Dask's workers, with the engine's worker environment:
  one BLAS thread), and
* through the campaign engine (``run_campaign``: an embedded Dask LocalCluster, Parquet chunks).

Each pool process and each Dask worker does its first case cold (imports, the CRLB) in both; the
start-up of the pool's processes and of the cluster is outside the wall time. With ``--repeats``
> 1 the order alternates (pool first, then engine first) so a drift of the shared machine's load
cancels. Printed per worker count, against the goals:

* per-case compute ratio = sum over the same cases of the compute timed inside ``run_case``,
  engine / pool (goal <= 1.1; the median of the per-case ratios is printed too), as wall time and
  as the CPU time of the process over each case (worker threads included; on a machine that other
  jobs keep busy the CPU ratio is the steadier one);
* throughput ratio = cases/s engine / cases/s pool (goal >= 0.95 with 1 and 2 workers, >= 0.9
  with 16);
* parallel efficiency = cases/s with N / (N x cases/s with 1), for each (goal >= 0.8 with 16);
* whether the engine's stderr (client, scheduler, nannies, workers: file descriptor 2 during the
  run, start and close included) was free of tracebacks and errors.

``--ablation dask-default-env`` runs the engine as it was before this fix as well (Dask's default
worker environment, with ``MALLOC_TRIM_THRESHOLD_=65536``, and no worker set-up), and
``--dask-config KEY=VALUE`` sets a Dask configuration value for the engine (e.g.
``distributed.worker.profile.enabled=false``).

    python benchmarks/bench_campaign.py [--cases 12] [--workers 1,2] [--repeats 2] [--duration-s 10800]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from taiji2_estimator_pkg.campaign import engine
from taiji2_estimator_pkg.campaign.case import run_case
from taiji2_estimator_pkg.campaign.spec import expand_cases, load_spec

ERROR_MARKERS = ("Traceback", "Error", "Exception", "WARNING", "Warning")


@dataclass
class Measured:
    """One configuration run over the cases."""

    label: str
    workers: int
    wall_s: float = 0.0
    completed: int = 0
    compute_s: dict[str, float] = field(default_factory=dict)
    cpu_s: dict[str, float] = field(default_factory=dict)
    stderr: str = ""

    @property
    def rate(self) -> float:
        return self.completed / self.wall_s


def _pool_env() -> dict[str, str]:
    """The environment of the baseline's processes: the caller's, with the engine's worker settings."""
    env = dict(os.environ)
    for key, value in engine.WORKER_PRE_SPAWN_ENV.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    return env


@contextmanager
def _environ(env: dict[str, str]):
    saved = dict(os.environ)
    os.environ.clear()
    os.environ.update(env)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)


def _started(_: int) -> int:
    time.sleep(0.3)  # held long enough that each warm-up task gets its own process
    return os.getpid()


def run_pool(cases: list[dict[str, Any]], workers: int) -> Measured:
    measured = Measured("pool", workers)
    context = multiprocessing.get_context("spawn")
    with _environ(_pool_env()):
        pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)
        pids = set(pool.map(_started, range(workers)))
    with pool:
        if len(pids) != workers:
            raise RuntimeError(f"pool started {len(pids)} processes, expected {workers}")
        started = time.perf_counter()
        futures = [pool.submit(run_case, case) for case in cases]
        for future in concurrent.futures.as_completed(futures):
            result = future.result()
            if result["status"] != "ok":
                raise RuntimeError(result["error"])
            measured.compute_s[result["case_hash"]] = result["compute_s"]
            measured.cpu_s[result["case_hash"]] = result["cpu_s"]
            measured.completed += 1
        measured.wall_s = time.perf_counter() - started
    return measured


@contextmanager
def _captured_fd2():
    """Everything written to file descriptor 2 (also by child processes) while inside."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as sink:
        os.dup2(sink.fileno(), 2)
        text: list[str] = []
        try:
            yield text
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text.append(sink.read().decode(errors="replace"))


def run_engine(cases_spec: dict[str, Any], workers: int, label: str = "engine") -> Measured:
    measured = Measured(label, workers)
    spec = load_spec(cases_spec)

    def record(result: dict[str, Any]) -> None:
        if result["status"] != "ok":
            raise RuntimeError(result["error"])
        measured.compute_s[result["case_hash"]] = result["compute_s"]
        measured.cpu_s[result["case_hash"]] = result["cpu_s"]

    with tempfile.TemporaryDirectory() as tmp, _captured_fd2() as err:
        run = engine.run_campaign(spec, Path(tmp), workers=workers, progress=None, on_result=record)
        if run.workers != workers:
            raise RuntimeError(f"engine ran {run.workers} workers, expected {workers}")
    measured.wall_s, measured.completed, measured.stderr = run.wall_s, run.completed, err[0]
    return measured


@contextmanager
def _dask_default_env():
    """The engine as it was: Dask's default worker environment, no worker set-up."""
    saved = engine.WORKER_PRE_SPAWN_ENV, engine.WORKER_SETUP
    engine.WORKER_PRE_SPAWN_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    engine.WORKER_SETUP = False
    try:
        yield
    finally:
        engine.WORKER_PRE_SPAWN_ENV, engine.WORKER_SETUP = saved


def _sum(m: Measured, keys: list[str], what: str = "compute_s") -> float:
    return sum(getattr(m, what)[k] for k in keys)


def _verdict(ok: bool) -> str:
    return "ok" if ok else "MISSED"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=12, help="cases per configuration (default 12)")
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts (default 1,2)")
    parser.add_argument("--repeats", type=int, default=2, help="rounds, order alternating (default 2)")
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--ablation", choices=["dask-default-env", "no-profiler"], action="append", default=[])
    parser.add_argument("--dask-config", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    counts = [int(w) for w in args.workers.split(",")]
    import dask
    import yaml

    for item in args.dask_config:
        key, _, value = item.partition("=")
        dask.config.set({key: yaml.safe_load(value)})

    cases_spec = {"name": "bench", "layouts": ["type1"], "durations_s": [args.duration_s],
                  "seeds": {"start": 7000, "count": args.cases}, "methods": ["gls"], "chunk_size": 25}
    cases = expand_cases(load_spec(cases_spec))
    keys = [c["case_hash"] for c in cases]
    print(f"{args.cases} cases of {args.duration_s:g} s (Type-1, gls, CRLB), workers {counts}, {args.repeats} "
          f"round(s); {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start", flush=True)
    labels = ["pool", "engine"] + [f"engine[{a}]" for a in args.ablation]
    results: dict[tuple[str, int], list[Measured]] = {}
    for round_index in range(args.repeats):
        for n in counts:
            order = labels if round_index % 2 == 0 else labels[::-1]
            for label in order:
                if label == "pool":
                    m = run_pool(cases, n)
                elif label == "engine":
                    m = run_engine(cases_spec, n)
                elif label == "engine[no-profiler]":
                    with dask.config.set({"distributed.worker.profile.enabled": False}):
                        m = run_engine(cases_spec, n, label)
                else:
                    with _dask_default_env():
                        m = run_engine(cases_spec, n, label)
                results.setdefault((label, n), []).append(m)
                print(f"  round {round_index + 1}, {n} worker(s), {label:24s}: {m.completed} cases in "
                      f"{m.wall_s:6.2f} s = {m.rate:6.3f} cases/s, mean case compute "
                      f"{_sum(m, keys) / len(keys):.3f} s wall, {_sum(m, keys, 'cpu_s') / len(keys):.3f} s CPU",
                      flush=True)

    print(f"\nload average {os.getloadavg()[0]:.2f} at end")
    rate = {k: sum(m.completed for m in v) / sum(m.wall_s for m in v) for k, v in results.items()}
    compute = {k: sum(_sum(m, keys) for m in v) for k, v in results.items()}
    cpu = {k: sum(_sum(m, keys, "cpu_s") for m in v) for k, v in results.items()}
    all_ok = True
    for n in counts:
        pool = ("pool", n)
        for label in labels[1:]:
            this = (label, n)
            compute_ratio = compute[this] / compute[pool]
            per_case = statistics.median(
                a.compute_s[k] / b.compute_s[k]
                for a, b in zip(results[this], results[pool], strict=True) for k in keys)
            throughput = rate[this] / rate[pool]
            goal = 0.9 if n >= 16 else 0.95
            cpu_ratio = cpu[this] / cpu[pool]
            print(f"{n} worker(s), {label}: per-case compute {label}/pool {compute_ratio:.3f}x wall (median per "
                  f"case {per_case:.3f}x), {cpu_ratio:.3f}x CPU (goal <= 1.1: {_verdict(compute_ratio <= 1.1)} wall, "
                  f"{_verdict(cpu_ratio <= 1.1)} CPU); throughput {rate[this]:.3f} / {rate[pool]:.3f} cases/s = "
                  f"{throughput:.3f}x (goal >= {goal}: {_verdict(throughput >= goal)})")
            if label == "engine":
                all_ok &= compute_ratio <= 1.1 and throughput >= goal
        if n != 1 and counts[0] == 1:
            for label in labels:
                efficiency = rate[(label, n)] / (n * rate[(label, 1)])
                goal_text = " (goal >= 0.8)" if n >= 16 and label == "engine" else ""
                print(f"  parallel efficiency {label} {n} vs 1 worker: {efficiency:.3f}{goal_text}")
    dirty = [m for v in results.values() for m in v if m.stderr.strip()]
    bad = [m for m in dirty if any(marker in m.stderr for marker in ERROR_MARKERS)]
    engine_bad = [m for m in bad if m.label == "engine"]
    print(f"engine stderr (start, run, close): {'clean' if not engine_bad else 'NOT CLEAN'} in "
          f"{len(results.get(('engine', counts[0]), [])) * len(counts)} runs")
    for m in bad:
        print(f"--- stderr of {m.label} with {m.workers} worker(s):\n{m.stderr.rstrip()}\n---")
    all_ok &= not engine_bad
    print(f"all goals met: {all_ok}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
