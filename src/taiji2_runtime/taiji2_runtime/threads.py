"""BLAS thread policy of the taiji2 entry points: one BLAS thread per process (docs/threads.md).

Every entry point (``taiji2 calibrate``, ``diagnose``, ``simulate``, ``design``, ``experiment``,
the estimator nodes, campaign workers) does small-matrix work: 3x3 to a few tens of rows, many
times. OpenBLAS's worker threads gain nothing there on an idle machine (measured: same wall time
with 1 and with 2 threads) and, when every core is taken, they spin waiting for work and for
each other: `taiji2 calibrate` of a 3-h bag went from 0.7 s to 9-15 s beside two CPU-bound jobs
on two cores. With one BLAS thread the tools slow in proportion to the CPU they get; parallelism
comes from processes (campaign workers, the node graph), not from BLAS.

Call :func:`limit_blas_threads` first thing in an entry point, before any BLAS-heavy call: it
limits the BLAS libraries already loaded (threadpoolctl) and sets ``OPENBLAS_NUM_THREADS`` (and
the MKL/BLIS equivalents) for the ones loaded later (scipy brings its own OpenBLAS) and for child
processes. ``TAIJI2_BLAS_THREADS=N`` overrides the policy. Only the standard library is imported
at module level (the CLI import rule); numpy and threadpoolctl are imported by the call.
"""

from __future__ import annotations

import os
import sys

__all__ = ["DEFAULT_BLAS_THREADS", "ENV_OVERRIDE", "blas_thread_counts", "blas_threads", "limit_blas_threads"]

#: BLAS threads of a taiji2 process unless ``TAIJI2_BLAS_THREADS`` says otherwise (measured: docs/threads.md)
DEFAULT_BLAS_THREADS = 1
#: environment variable that overrides the policy (a positive integer)
ENV_OVERRIDE = "TAIJI2_BLAS_THREADS"
# read by the BLAS libraries when they load (a library loaded after the call, and child processes)
_LIBRARY_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def blas_threads() -> int:
    """BLAS threads per process under the policy: ``TAIJI2_BLAS_THREADS`` if set, else 1."""
    value = os.environ.get(ENV_OVERRIDE, "").strip()
    if not value:
        return DEFAULT_BLAS_THREADS
    try:
        threads = int(value)
    except ValueError:
        threads = 0
    if threads < 1:
        print(f"warning: {ENV_OVERRIDE}={value!r} is not a positive integer; using {DEFAULT_BLAS_THREADS}",
              file=sys.stderr)
        return DEFAULT_BLAS_THREADS
    return threads


def limit_blas_threads(threads: int | None = None) -> int:
    """Apply the BLAS thread policy to this process (and its future children); returns the count.

    ``threads`` (default :func:`blas_threads`) is applied to every BLAS library loaded now
    (numpy's is loaded by the call) and, through the environment, to those loaded later. Cheap
    (about 3 ms beyond importing numpy) and idempotent.
    """
    n = blas_threads() if threads is None else int(threads)
    if n < 1:
        raise ValueError(f"BLAS threads must be >= 1, got {n}")
    for name in _LIBRARY_ENV:
        os.environ[name] = str(n)
    import numpy  # noqa: F401  # loads numpy's BLAS so that the limit reaches it
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=n, user_api="blas")
    return n


def blas_thread_counts() -> dict[str, int]:
    """Threads of each BLAS library loaded in this process (file name -> threads), from threadpoolctl."""
    from threadpoolctl import threadpool_info

    return {os.path.basename(info["filepath"]): int(info["num_threads"])
            for info in threadpool_info() if info.get("user_api") == "blas"}
