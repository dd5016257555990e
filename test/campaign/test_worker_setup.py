"""Campaign workers compute like plain processes: allocator thresholds, environment, clean close."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from taiji2_apps.campaign.engine import run_campaign
from taiji2_apps.campaign.spec import load_spec

# Page faults of 200 allocations of a 2.6 MB array (a 3-h (n, 3) series), each written and freed.
_CHURN = """
import resource, sys
import numpy as np
from taiji2_apps.campaign.worker import restore_allocator_thresholds
restored = restore_allocator_thresholds() if sys.argv[1] == "restore" else None
a = np.ones((108000, 3))
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(200):
    b = np.ones((108000, 3))
    del b
print(restored, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _churn(env: dict[str, str], mode: str) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", _CHURN, mode], env=env, capture_output=True, text=True, check=True)
    restored, faults = out.stdout.split()
    return restored, int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc allocator")
def test_dask_trim_threshold_makes_every_array_fresh_pages_and_the_setup_undoes_it():
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    _, plain = _churn(env, "plain")
    _, trimmed = _churn({**env, "MALLOC_TRIM_THRESHOLD_": "65536"}, "plain")
    restored, fixed = _churn({**env, "MALLOC_TRIM_THRESHOLD_": "65536"}, "restore")
    # Dask's default: each 2.6 MB array is a fresh mmap, ~640 page faults per allocation
    assert trimmed > 200 * 300 > 20 * max(plain, 1)
    assert restored == "True" and fixed < trimmed / 20
    assert _churn(env, "restore")[0] == "False"  # nothing to undo without the variable


def test_workers_have_no_trim_threshold_and_the_callers_environment_is_kept(tmp_path):
    spec = load_spec({"name": "env", "layouts": ["type1"], "durations_s": [60.0], "seeds": [1, 2], "chunk_size": 2})
    seen: list[dict] = []

    def inspect(_result: dict) -> None:
        if seen:
            return
        from dask.distributed import get_client

        def probe(dask_worker):
            return (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OPENBLAS_NUM_THREADS"),
                    getattr(dask_worker, "taiji2_allocator_restored", "missing"),
                    getattr(dask_worker, "taiji2_blas_threads", "missing"),
                    any(pc.is_running() for name, pc in dask_worker.periodic_callbacks.items()
                        if name.startswith("profile")),
                    dask_worker.periodic_callbacks["tick"].callback_time)

        seen.append(get_client().run(probe))

    before = dict(os.environ)
    run = run_campaign(spec, tmp_path, workers=2, progress=None, on_result=inspect)
    assert run.completed == 2
    # nothing left to restore; one BLAS thread; no sampling profiler; a 1-s health tick
    assert sorted(seen[0].values()) == [(None, "1", False, 1, False, 1000.0)] * 2
    assert dict(os.environ) == before


def test_cluster_starts_and_closes_without_tracebacks(tmp_path):
    """Start, run and close in a fresh process with 4 workers: stderr (workers included) is empty."""
    code = f"""
from taiji2_apps.campaign.engine import run_campaign
from taiji2_apps.campaign.spec import load_spec
if __name__ == "__main__":
    for r in range(2):
        spec = load_spec({{"name": "close", "layouts": ["type1"], "durations_s": [30.0],
                          "seeds": {{"start": 10 * r, "count": 4}}}})
        run_campaign(spec, {str(tmp_path)!r} + f"/{{r}}", workers=4, progress=None)
"""
    script = tmp_path / "close.py"
    script.write_text(code)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stderr.strip() == ""


def test_the_setup_quiets_the_event_loop_of_a_worker_started_with_dasks_defaults():
    # a worker of an existing cluster (`dask worker`) runs the sampling profiler and a 20-ms tick
    from tornado.ioloop import PeriodicCallback

    from taiji2_apps.campaign.worker import quiet_event_loop

    class Worker:
        def __init__(self) -> None:
            self.periodic_callbacks = {name: PeriodicCallback(lambda: None, 10)
                                       for name in ("profile", "profile-cycle", "heartbeat", "tick")}

    worker = Worker()
    for callback in worker.periodic_callbacks.values():
        callback.start()
    try:
        assert quiet_event_loop(worker) is True
        running = {name: pc.is_running() for name, pc in worker.periodic_callbacks.items()}
        assert running == {"profile": False, "profile-cycle": False, "heartbeat": True, "tick": True}
        assert worker.periodic_callbacks["tick"].callback_time == 1000.0
        assert worker.periodic_callbacks["heartbeat"].callback_time == 10
    finally:
        worker.periodic_callbacks["heartbeat"].stop()
        worker.periodic_callbacks["tick"].stop()
    assert quiet_event_loop(type("Bare", (), {"periodic_callbacks": {}})()) is False
