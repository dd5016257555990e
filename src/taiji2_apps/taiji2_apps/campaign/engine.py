"""Run a campaign on Dask: an embedded LocalCluster by default, or any existing cluster.

Cases go to the scheduler as independent tasks (``client.submit``); Dask reschedules a case whose
worker dies, and every case is deterministic for its seed, so a rerun gives the same rows. The
client writes completed cases to Parquet chunks as they arrive, so an interrupted campaign keeps
what it finished and a rerun with the same output directory skips it.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from taiji2_apps.campaign.case import run_case
from taiji2_apps.campaign.spec import expand_cases
from taiji2_apps.campaign.store import done_case_hashes, provenance, write_chunk
from taiji2_apps.campaign.worker import TICK_INTERVAL_S

#: Environment each nanny of the embedded cluster sets before it spawns its worker process (Dask's
#: ``distributed.nanny.pre-spawn-environ``; None removes a variable from Dask's defaults). One BLAS
#: thread per worker process: the parallelism is across cases. No ``MALLOC_TRIM_THRESHOLD_`` (Dask
#: sets 65536): it fixes glibc's allocator thresholds, every array above 128 KiB becomes a fresh
#: mmap, and a case costs 2.4-2.5x its time in a plain process (see :mod:`.worker`).
WORKER_PRE_SPAWN_ENV: dict[str, str | None] = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                                               "MKL_NUM_THREADS": "1", "MALLOC_TRIM_THRESHOLD_": None}
#: Dask configuration of the embedded cluster's workers: no sampling profiler and a slow health
#: tick, since each wake-up of a worker's event loop takes the GIL from its case (10-17 % and 9-16 %
#: of a case; :func:`.worker.quiet_event_loop`, which does the same on an existing cluster).
WORKER_CONFIG: dict[str, object] = {"distributed.worker.profile.enabled": False,
                                    "distributed.admin.tick.interval": f"{TICK_INTERVAL_S}s"}
#: Register :class:`.worker.CampaignWorkerSetup` on the cluster (restores glibc's thresholds in a
#: worker started with Dask's default environment, e.g. on an existing cluster).
WORKER_SETUP = True


@dataclass
class CampaignRun:
    """What a call of :func:`run_campaign` did."""

    total: int
    skipped: int
    completed: int
    failed: int
    wall_s: float
    compute_s: float
    workers: int
    files: list[Path]


def run_campaign(spec: Mapping[str, Any], out_dir: str | os.PathLike[str], *, scheduler: str | None = None,
                 workers: int | None = None, progress: TextIO | None = sys.stderr,
                 on_result: Callable[[dict[str, Any]], None] | None = None) -> CampaignRun:
    """Run every case of a validated spec not yet recorded in ``out_dir``.

    Parameters
    ----------
    spec : mapping
        Output of :func:`~.spec.load_spec`.
    out_dir : path
        Campaign directory (Parquet chunks); created if missing.
    scheduler : str, optional
        Address of an existing Dask scheduler, e.g. ``tcp://host:8786``; default: an embedded
        LocalCluster.
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    progress : text stream, optional
        Where progress lines go (None: silent).
    on_result : callable, optional
        Called with each completed case result (tests use it to interrupt).

    Raises
    ------
    ConnectionError
        The scheduler cannot be reached (the message names the address).
    """
    from dask.distributed import as_completed

    out = Path(out_dir)
    cases = expand_cases(spec)
    done = done_case_hashes(out) if out.exists() else set()
    todo = [c for c in cases if c["case_hash"] not in done]
    meta = provenance(spec)
    run = CampaignRun(total=len(cases), skipped=len(cases) - len(todo), completed=0, failed=0, wall_s=0.0,
                      compute_s=0.0, workers=0, files=[])
    _say(progress, f"campaign {spec['name']!r}: {len(cases)} cases, {run.skipped} already done, {len(todo)} to run")
    if not todo:
        return run
    with open_cluster(scheduler, workers) as client:
        run.workers = len(client.scheduler_info().get("workers", {}))
        _say(progress, f"dask: {run.workers} workers; dashboard: {_dashboard(client)}")
        started = time.perf_counter()  # wall time of the cases, cluster start-up excluded
        futures = [client.submit(run_case, case, key=f"taiji2-case-{case['case_hash']}", pure=False, retries=1)
                   for case in todo]
        by_hash = {case["case_hash"]: case for case in todo}
        buffer: list[dict[str, Any]] = []
        last = 0.0
        try:
            for future in as_completed(futures):
                result = future.result()
                case = by_hash[result["case_hash"]]
                result.update(group=case["group"], seed=case["seed"])
                buffer.append(result)
                run.completed += 1
                run.failed += result["status"] != "ok"
                run.compute_s += result["compute_s"]
                if len(buffer) >= spec["chunk_size"]:
                    run.files.append(write_chunk(out, buffer, meta))
                    buffer = []
                now = time.perf_counter()
                if now - last > 1.0 or run.completed == len(todo):
                    last = now
                    _progress(progress, run, len(todo), now - started)
                if on_result is not None:
                    on_result(result)
            run.wall_s = time.perf_counter() - started
        finally:
            # whatever finished is kept, also on Ctrl-C
            if buffer:
                run.files.append(write_chunk(out, buffer, meta))
            # an interrupted run cancels what is left, in one message (after a complete run
            # nothing is)
            pending = [future for future in futures if not future.done()]
            if pending:
                client.cancel(pending)
    return run


@contextmanager
def open_cluster(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A Dask client set up for campaign cases, of ``scheduler`` or of a new LocalCluster.

    The LocalCluster has one single-threaded, one-BLAS-thread worker process per core (or
    ``workers``) started with :data:`WORKER_PRE_SPAWN_ENV`; on any cluster each worker runs
    :class:`.worker.CampaignWorkerSetup`. On exit the client is closed before the cluster (no
    worker or client is left talking to a closed scheduler), and the caller's environment is what
    it was before (Dask's nannies write their pre-spawn environment into this process's).

    Raises
    ------
    ConnectionError
        The scheduler cannot be reached.
    """
    from dask.distributed import Client

    saved_environ = dict(os.environ)
    cluster = None
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise ConnectionError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        else:
            cluster = _local_cluster(workers or os.cpu_count() or 1)
            client = Client(cluster)
        try:
            if WORKER_SETUP:
                from taiji2_apps.campaign.worker import CampaignWorkerSetup

                client.register_plugin(CampaignWorkerSetup())
            yield client
        finally:
            client.close()
    finally:
        try:
            if cluster is not None:
                cluster.close()
        finally:
            os.environ.clear()
            os.environ.update(saved_environ)


def _local_cluster(workers: int) -> Any:
    import dask
    from dask.distributed import LocalCluster

    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **WORKER_PRE_SPAWN_ENV}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": pre_spawn, **WORKER_CONFIG}):
        # the HTTP server (dashboard with bokeh, /health and metrics without) on a free port: the
        # default 8787 warns when another cluster holds it
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                            silence_logs=40)


def _has_bokeh() -> bool:
    from importlib.util import find_spec

    return find_spec("bokeh") is not None


def _dashboard(client: Any) -> str:
    if not _has_bokeh():
        return "disabled (bokeh not installed; `pip install bokeh` enables it)"
    return str(client.dashboard_link)


def _progress(stream: TextIO | None, run: CampaignRun, todo: int, elapsed_s: float) -> None:
    rate = run.completed / elapsed_s if elapsed_s > 0 else 0.0
    eta = (todo - run.completed) / rate if rate > 0 else float("nan")
    _say(stream, f"{run.completed}/{todo} cases ({run.failed} failed), {rate:.2f} cases/s, "
                 f"elapsed {elapsed_s:.0f} s, ETA {eta:.0f} s")


def _say(stream: TextIO | None, line: str) -> None:
    if stream is not None:
        print(f"[campaign] {line}", file=stream, flush=True)
