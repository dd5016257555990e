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

``--ablation dask-default-env`` runs the engine as it was before its fixes as well (Dask's default
worker environment, with ``MALLOC_TRIM_THRESHOLD_=65536``, Dask's worker configuration: the sampling
profiler and a 20-ms health tick, and no worker set-up), ``--ablation dask-default-loop`` the engine with
only Dask's worker configuration back (profiler, tick), and
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

from taiji2_apps.campaign import engine
from taiji2_apps.campaign.case import run_case
from taiji2_apps.campaign.spec import expand_cases, load_spec

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
    #: cases in the order each process completed them: its first is its cold case
    by_pid: dict[int, list[str]] = field(default_factory=dict)
    stderr: str = ""

    def add(self, result: dict[str, Any]) -> None:
        if result["status"] != "ok":
            raise RuntimeError(result["error"])
        self.compute_s[result["case_hash"]] = result["compute_s"]
        self.cpu_s[result["case_hash"]] = result["cpu_s"]
        self.by_pid.setdefault(result["worker_pid"], []).append(result["case_hash"])

    def warm_keys(self) -> list[str]:
        """The cases that were not their process's first (no imports, no CRLB of their own)."""
        return [k for keys in self.by_pid.values() for k in keys[1:]]

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
            measured.add(future.result())
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

    with tempfile.TemporaryDirectory() as tmp, _captured_fd2() as err:
        run = engine.run_campaign(spec, Path(tmp), workers=workers, progress=None, on_result=measured.add)
        if run.workers != workers:
            raise RuntimeError(f"engine ran {run.workers} workers, expected {workers}")
    measured.wall_s, measured.completed, measured.stderr = run.wall_s, run.completed, err[0]
    return measured


@contextmanager
def _dask_default_env():
    """The engine as it was: Dask's default worker environment, no worker set-up."""
    saved = engine.WORKER_PRE_SPAWN_ENV, engine.WORKER_CONFIG, engine.WORKER_SETUP
    engine.WORKER_PRE_SPAWN_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    engine.WORKER_CONFIG, engine.WORKER_SETUP = {}, False
    try:
        yield
    finally:
        engine.WORKER_PRE_SPAWN_ENV, engine.WORKER_CONFIG, engine.WORKER_SETUP = saved


@contextmanager
def _dask_default_loop():
    """The engine with Dask's worker configuration (sampling profiler, 20-ms tick) and no worker set-up."""
    saved = engine.WORKER_CONFIG, engine.WORKER_SETUP
    engine.WORKER_CONFIG, engine.WORKER_SETUP = {}, False
    try:
        yield
    finally:
        engine.WORKER_CONFIG, engine.WORKER_SETUP = saved


def _cpu_task(_: int) -> float:
    """Pure-Python arithmetic (no memory traffic): what one core gives, timed inside the task."""
    started = time.perf_counter()
    x = 0
    for i in range(8_000_000):
        x += i * i % 7
    return time.perf_counter() - started


def _memory_task(_: int) -> float:
    """numpy on 3-h-record-sized arrays (108,000 x 3 doubles, 2.6 MB each): memory-bandwidth bound."""
    import numpy as np

    started = time.perf_counter()
    a = np.ones((108_000, 3))
    for _ in range(500):
        b = a * 1.0001 + 0.5
        a = np.sqrt(b * b)
    return time.perf_counter() - started


def machine_control(counts: list[int]) -> dict[tuple[str, int], float]:
    """Mean task time of the two controls in a plain pool of each size (4 tasks per process)."""
    context = multiprocessing.get_context("spawn")
    means: dict[tuple[str, int], float] = {}
    with _environ(_pool_env()):
        for n in counts:
            with concurrent.futures.ProcessPoolExecutor(max_workers=n, mp_context=context) as pool:
                list(pool.map(_started, range(n)))
                for name, task in (("cpu", _cpu_task), ("memory", _memory_task)):
                    times = list(pool.map(task, range(4 * n)))
                    means[(name, n)] = statistics.mean(times)
    return means


def _verdict(ok: bool) -> str:
    return "ok" if ok else "MISSED"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=12, help="cases per configuration (default 12)")
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts (default 1,2)")
    parser.add_argument("--repeats", type=int, default=2, help="rounds, order alternating (default 2)")
    parser.add_argument("--cases-per-worker", type=int, default=0,
                        help="at least this many cases per worker (default 0: --cases for every worker count)")
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--ablation", choices=["dask-default-env", "dask-default-loop"], action="append", default=[])
    parser.add_argument("--dask-config", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--control", action="store_true",
                        help="also time a pure-CPU and a memory-bound numpy task in pools of each size: the "
                             "parallel efficiency the machine itself gives (vCPUs sharing cores, memory bandwidth)")
    args = parser.parse_args()
    counts = [int(w) for w in args.workers.split(",")]
    import dask
    import yaml

    for item in args.dask_config:
        key, _, value = item.partition("=")
        dask.config.set({key: yaml.safe_load(value)})

    def spec_for(n: int) -> dict[str, Any]:
        # at least --cases-per-worker cases per worker: a 16-worker run of a few cases would time
        # mostly each process's cold first case
        count = max(args.cases, args.cases_per_worker * n)
        return {"name": "bench", "layouts": ["type1"], "durations_s": [args.duration_s],
                "seeds": {"start": 7000, "count": count}, "methods": ["gls"], "chunk_size": 25}

    cases = {n: expand_cases(load_spec(spec_for(n))) for n in counts}
    print(f"{', '.join(str(len(cases[n])) for n in counts)} cases of {args.duration_s:g} s (Type-1, gls, CRLB), "
          f"workers {counts}, {args.repeats} round(s); {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.2f} at start", flush=True)
    labels = ["pool", "engine"] + [f"engine[{a}]" for a in args.ablation]
    results: dict[tuple[str, int], list[Measured]] = {}
    for round_index in range(args.repeats):
        for n in counts:
            order = labels if round_index % 2 == 0 else labels[::-1]
            for label in order:
                if label == "pool":
                    m = run_pool(cases[n], n)
                elif label == "engine":
                    m = run_engine(spec_for(n), n)
                elif label == "engine[dask-default-loop]":
                    with _dask_default_loop():
                        m = run_engine(spec_for(n), n, label)
                else:
                    with _dask_default_env():
                        m = run_engine(spec_for(n), n, label)
                results.setdefault((label, n), []).append(m)
                print(f"  round {round_index + 1}, {n} worker(s), {label:24s}: {m.completed} cases in "
                      f"{m.wall_s:6.2f} s = {m.rate:6.3f} cases/s, mean case compute "
                      f"{statistics.mean(m.compute_s.values()):.3f} s wall, "
                      f"{statistics.mean(m.cpu_s.values()):.3f} s CPU",
                      flush=True)

    print(f"\nload average {os.getloadavg()[0]:.2f} at end")
    rate = {k: sum(m.completed for m in v) / sum(m.wall_s for m in v) for k, v in results.items()}
    all_ok = True
    for n in counts:
        pool = ("pool", n)
        for label in labels[1:]:
            this = (label, n)
            # warm cases only (not their process's first in either run): a Dask worker imports the
            # project when it unpickles its first task, before run_case's clock starts, so its cold
            # case looks cheaper than the pool's (whose clock includes the imports)
            pairs = [(a.compute_s[k], b.compute_s[k], a.cpu_s[k], b.cpu_s[k])
                     for a, b in zip(results[this], results[pool], strict=True)
                     for k in set(a.warm_keys()) & set(b.warm_keys())]
            if not pairs:  # too few cases for a warm one in both runs
                pairs = [(float("nan"),) * 4]
            compute_ratio = sum(p[0] for p in pairs) / sum(p[1] for p in pairs)
            per_case = statistics.median(p[0] / p[1] for p in pairs)
            throughput = rate[this] / rate[pool]
            goal = 0.9 if n >= 16 else 0.95
            cpu_ratio = sum(p[2] for p in pairs) / sum(p[3] for p in pairs)
            print(f"{n} worker(s), {label}: per-case compute {label}/pool {compute_ratio:.3f}x wall over {len(pairs)} "
                  f"cases warm in both (median per case {per_case:.3f}x), {cpu_ratio:.3f}x CPU (goal <= 1.1: "
                  f"{_verdict(compute_ratio <= 1.1)} wall, "
                  f"{_verdict(cpu_ratio <= 1.1)} CPU); throughput {rate[this]:.3f} / {rate[pool]:.3f} cases/s = "
                  f"{throughput:.3f}x (goal >= {goal}: {_verdict(throughput >= goal)})")
            if label == "engine":
                all_ok &= compute_ratio <= 1.1 and throughput >= goal
        if n != 1 and counts[0] == 1:
            for label in labels:
                efficiency = rate[(label, n)] / (n * rate[(label, 1)])
                goal_text = " (goal >= 0.8)" if n >= 16 and label == "engine" else ""
                print(f"  parallel efficiency {label} {n} vs 1 worker: {efficiency:.3f}{goal_text}")
    for n in counts:
        for label in labels:
            warm_count = sum(len(m.warm_keys()) for m in results[(label, n)])
            warm_mean = statistics.mean(m.compute_s[k] for m in results[(label, n)] for k in m.warm_keys())
            cold = [m.compute_s[keys[0]] for m in results[(label, n)] for keys in m.by_pid.values()]
            print(f"  {n} worker(s), {label}: mean compute of a warm case {warm_mean:.3f} s "
                  f"({warm_count} cases), of a process's first case "
                  f"{statistics.mean(cold):.3f} s ({len(cold)} cases)")
    if args.control:
        means = machine_control(counts)
        for n in counts:
            print(f"  machine control, {n} process(es): pure-CPU task {means[('cpu', n)]:.3f} s, memory-bound "
                  f"numpy task {means[('memory', n)]:.3f} s" + (
                      f"; efficiency the machine gives vs 1: CPU {means[('cpu', 1)] / means[('cpu', n)]:.3f}, "
                      f"memory {means[('memory', 1)] / means[('memory', n)]:.3f}" if n != 1 and 1 in counts else ""))
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
