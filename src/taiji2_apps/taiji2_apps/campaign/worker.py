"""What each campaign worker process sets up before it runs cases (a Dask worker plugin).

The engine registers :class:`CampaignWorkerSetup` on every cluster it runs on, embedded or not, so
a worker started by ``dask worker``, ``dask-ssh`` or ``dask-jobqueue`` with Dask's default
configuration computes a case as fast as a plain process.

Dask's nannies start their workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (Dask's
``distributed.nanny.pre-spawn-environ``). Any ``MALLOC_*_THRESHOLD_`` setting turns off glibc's
dynamic thresholds, so the mmap threshold stays at 128 KiB: every array of more than 16,384
doubles (a 3-h case has hundreds, of 108,000 x 3 and more) is a fresh ``mmap`` whose pages are
faulted in and zeroed on first touch and unmapped again on ``free``. A 3-h case then takes 2.4-2.5x
its time in a plain process (3.2 M page faults instead of 0.1 M in six cases; docs/campaigns.md).
:func:`restore_allocator_thresholds` sets the ceilings that glibc's own dynamic thresholds reach
in a plain process (mmap above 32 MiB, trim above 64 MiB), which gives the plain process's speed.
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

#: The period of the event loop's health tick in a campaign worker [s] (Dask's default 20 ms,
#: ``distributed.admin.tick.interval``): 50 wake-ups a second, each taking the GIL from the case's
#: thread; with every core busy (2 workers on 2 cores) a warm case cost 1.09-1.16x the plain pool's
#: with it and 0.97x at 1 s (bench_campaign, 16 cases each, 2026-11-26). The tick only watches the
#: loop (a warning when a tick is more than ``distributed.admin.tick.limit``, 3 s, late).
TICK_INTERVAL_S = 1.0


#: glibc's mallopt parameters.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: glibc's ceiling of its dynamic mmap threshold on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX) and the
#: trim threshold it pairs with it (twice the mmap threshold).
MMAP_THRESHOLD_BYTES = 32 * 2**20
TRIM_THRESHOLD_BYTES = 2 * MMAP_THRESHOLD_BYTES
#: The environment variables that fix glibc's thresholds (and so turn off its dynamic ones).
ALLOCATOR_VARIABLES = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")


def restore_allocator_thresholds() -> bool:
    """Give this process glibc's plain-process thresholds if its environment fixed them.

    Returns
    -------
    bool
        True if the thresholds were set; False where nothing was to be done (no such variable in
        the environment) or cannot be (not Linux, no glibc ``mallopt``).
    """
    if not sys.platform.startswith("linux") or not any(name in os.environ for name in ALLOCATOR_VARIABLES):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


#: What a Dask worker logs (at ERROR, with a CommClosedError traceback) when its connection pool is
#: closed under a heartbeat still in flight: ``Worker.close`` stops the heartbeat's periodic
#: callback but does not wait for a running heartbeat before it closes its RPC pool, so a cluster
#: that closes while a heartbeat is on the wire prints that traceback (1 run in 3 with 8 workers
#: here; docs/campaigns.md).
HEARTBEAT_FAILURE = "Failed to communicate with scheduler during heartbeat"


class _HeartbeatRaceFilter(logging.Filter):
    """Drops the worker's "Failed to communicate with scheduler during heartbeat" record."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(HEARTBEAT_FAILURE)


#: The worker's periodic callbacks of Dask's sampling profiler: every 10 ms (``distributed.worker.
#: profile.interval``) the event-loop thread takes the GIL to walk the task thread's stack, and the
#: case's thread waits for it back; a warm 3-h case cost 1.14x wall and 1.17x CPU of the same case in
#: a plain process with it and 0.98x, 1.00x without (bench_campaign, profiler on and off, 18 cases,
#: 2026-11-26). Campaign workers do not run it; the dashboard's profile page stays empty.
PROFILER_CALLBACKS = ("profile", "profile-cycle")


def quiet_event_loop(worker: Any) -> bool:
    """Stop the worker's sampling profiler and slow its health tick to :data:`TICK_INTERVAL_S`.

    Returns
    -------
    bool
        True if the profiler was running (a worker of an existing cluster started with Dask's
        defaults); the embedded LocalCluster starts its workers without it.
    """
    callbacks = getattr(worker, "periodic_callbacks", {})
    running = [callbacks[name] for name in PROFILER_CALLBACKS if name in callbacks]
    for callback in running:
        callback.stop()
    if "tick" in callbacks:
        # tornado's PeriodicCallback reads callback_time [ms] when it schedules its next run
        callbacks["tick"].callback_time = max(callbacks["tick"].callback_time, TICK_INTERVAL_S * 1000)
    return bool(running)


class CampaignWorkerSetup(WorkerPlugin):
    """Worker plugin for campaign workers (also restarted ones).

    ``setup``: :func:`restore_allocator_thresholds` and :func:`quiet_event_loop` (a worker of an
    existing cluster started with Dask's defaults runs the profiler and a 20-ms tick). ``teardown``
    (the first step of the worker's ``close``, before it closes its RPC pool): no new heartbeat,
    and the one that may still be in flight fails without a traceback on stderr (see :data:`HEARTBEAT_FAILURE`).
    """

    name = "taiji2-campaign-worker-setup"
    idempotent = True

    def setup(self, worker: Any) -> None:
        """Called by Dask in each worker process before it runs a task."""
        from taiji2_runtime.threads import limit_blas_threads

        worker.taiji2_allocator_restored = restore_allocator_thresholds()
        worker.taiji2_profiler_stopped = quiet_event_loop(worker)
        # the project's BLAS policy (docs/threads.md), also on a cluster whose workers did not start
        # with one BLAS thread (Dask's LocalCluster defaults do; `dask worker` on a host does not)
        worker.taiji2_blas_threads = limit_blas_threads()

    def teardown(self, worker: Any) -> None:
        """Called by Dask when the worker starts to close."""
        heartbeat = getattr(worker, "periodic_callbacks", {}).get("heartbeat")
        if heartbeat is not None:
            heartbeat.stop()
        logger = logging.getLogger("distributed.worker")
        if not any(isinstance(f, _HeartbeatRaceFilter) for f in logger.filters):
            logger.addFilter(_HeartbeatRaceFilter())
