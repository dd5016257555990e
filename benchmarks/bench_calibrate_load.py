"""`taiji2 calibrate` of a 3-h bag on a busy machine: idle vs two CPU-bound processes beside it.

One 3-h Type-1 bag (seed 7; writer of ``bench_calibrate.py``, default the recorder's MCAP). Each
round, in one run:
  * idle: ``taiji2 calibrate BAG --layout type1 --json`` (whole process, as a user runs it) and the
    plain rosbags read of the same bag (``bench_calibrate.BASELINE_SCRIPT``), paired;
  * loaded: the same pair with two ``python -c 'while True: pass'`` processes running (started for
    the round, killed after it), and ``taiji2 calibrate`` once more with the BLAS policy turned off
    (``TAIJI2_BLAS_THREADS`` = the number of cores: OpenBLAS's own default, the behaviour before
    ``taiji2_runtime.threads``), for comparison.
After one untimed warm-up pair. Medians of the rounds; CPU time (user + sys) of each process from
``getrusage``. The BLAS thread counts are read inside a calibrate process (threadpoolctl) to show
the policy took effect.

Goals (docs/threads.md): loaded calibrate <= 2.5x idle calibrate; loaded calibrate >= 2x faster
than the loaded rosbags read.

    python benchmarks/bench_calibrate_load.py [--duration-s 10800] [--repeats 5] [--bag recorder] [--hogs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_calibrate import BAGS, BASELINE_SCRIPT, PROCESS_ENV, REPO, TAIJI2, timed_process, write_bags

HOG = "while True: pass"
THREADS_SCRIPT = """
import json, sys
from taiji2_apps.cli.main import main
import contextlib, io
with contextlib.redirect_stdout(io.StringIO()):
    status = main(["calibrate", sys.argv[1], "--layout", "type1", "--json"])
from taiji2_runtime.threads import blas_thread_counts
print(json.dumps({"status": status, "blas_threads": blas_thread_counts()}))
"""


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in PROCESS_ENV.items() if k not in ("TAIJI2_BLAS_THREADS", "OPENBLAS_NUM_THREADS")}
    env.update(extra)
    return env


def timed(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall s, CPU s = user + sys) of one process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = timed_process(argv, env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


class Hogs:
    """``n`` CPU-bound processes for the duration of a ``with`` block (killed by their own handles)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> Hogs:
        self.procs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(self.n)]
        time.sleep(0.3)
        return self

    def __exit__(self, *_: object) -> None:
        for proc in self.procs:
            proc.kill()
        for proc in self.procs:
            proc.wait()


def _line(label: str, runs: list[tuple[float, float]]) -> str:
    walls, cpu = [w for w, _ in runs], [c for _, c in runs]
    return (f"  {label:52s} wall median {statistics.median(walls):6.2f} s "
            f"(runs {' '.join(f'{w:.2f}' for w in walls)}); CPU median {statistics.median(cpu):5.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--bag", default="recorder", choices=BAGS, help="bag writer (default recorder)")
    parser.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside it (default 2)")
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    policy, unlimited = _env(), _env(TAIJI2_BLAS_THREADS=str(cores))
    with tempfile.TemporaryDirectory() as tmp:
        bag = write_bags(Path(tmp), args.duration_s, [args.bag])[args.bag]
        calibrate = [*TAIJI2, "calibrate", str(bag), "--layout", "type1", "--json"]
        baseline = [sys.executable, "-c", BASELINE_SCRIPT.format(test=str(REPO / "test")), str(bag)]
        check = subprocess.run([sys.executable, "-c", THREADS_SCRIPT, str(bag)], env=policy, capture_output=True,
                               text=True, timeout=600, check=True)
        print(f"bag: {args.bag}, {args.duration_s:g} s, Type-1; {cores} cores (affinity "
              f"{len(os.sched_getaffinity(0))}); {args.repeats} rounds; load: {args.hogs} x python -c '{HOG}'")
        print(f"BLAS threads inside taiji2 calibrate (threadpoolctl): {json.loads(check.stdout)['blas_threads']}")
        timed(calibrate, policy), timed(baseline, policy)  # warm-up, untimed: bytecode caches, page cache
        load_before = os.getloadavg()[0]
        runs: dict[str, list[tuple[float, float]]] = {k: [] for k in (
            "idle calibrate", "idle rosbags", "loaded calibrate", "loaded rosbags", "loaded calibrate, no policy")}
        for _ in range(args.repeats):
            runs["idle calibrate"].append(timed(calibrate, policy))
            runs["idle rosbags"].append(timed(baseline, policy))
            with Hogs(args.hogs):
                runs["loaded calibrate"].append(timed(calibrate, policy))
                runs["loaded rosbags"].append(timed(baseline, policy))
                runs["loaded calibrate, no policy"].append(timed(calibrate, unlimited))
    load_after = os.getloadavg()[0]
    for label, values in runs.items():
        print(_line(label + (f" (TAIJI2_BLAS_THREADS={cores})" if "no policy" in label else ""), values))
    med = {k: statistics.median(w for w, _ in v) for k, v in runs.items()}
    slowdown = med["loaded calibrate"] / med["idle calibrate"]
    speedup = med["loaded rosbags"] / med["loaded calibrate"]
    base_slowdown = med["loaded rosbags"] / med["idle rosbags"]
    print(f"loaded / idle calibrate: {slowdown:.2f}x (goal <= 2.5x); rosbags read / calibrate, both loaded: "
          f"{speedup:.2f}x (goal >= 2x); rosbags loaded / idle: {base_slowdown:.2f}x (the CPU share the load "
          f"leaves a process that uses no BLAS); calibrate's slowdown / rosbags': {slowdown / base_slowdown:.2f}; "
          f"without the policy, loaded / idle calibrate: "
          f"{med['loaded calibrate, no policy'] / med['idle calibrate']:.2f}x")
    print(f"1-min load average before the rounds {load_before:.1f}, after {load_after:.1f} (the {args.hogs} "
          f"CPU-bound processes of the loaded runs included; more means other jobs shared the machine)")


if __name__ == "__main__":
    main()
