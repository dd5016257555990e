"""BLAS thread policy (docs/threads.md): one BLAS thread per process, applied by every entry point
before its first BLAS call, reaching the BLAS libraries loaded before and after the call."""

from __future__ import annotations

import json
import subprocess

import pytest

from support import PYTHON, python_subprocess_env

CHECK = """
import json, sys
from taiji2_runtime.threads import blas_thread_counts, limit_blas_threads
applied = limit_blas_threads()
before_scipy = blas_thread_counts()
import scipy.linalg  # scipy's own OpenBLAS loads after the call
import taiji2_estimator_pkg.calibration  # the estimator core and what it loads
print(json.dumps({"applied": applied, "before_scipy": before_scipy, "after": blas_thread_counts()}))
"""


def _check(env_extra: dict[str, str]) -> dict:
    env = {k: v for k, v in python_subprocess_env().items()
           if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS", "TAIJI2_BLAS_THREADS")}
    env.update(env_extra)
    proc = subprocess.run([PYTHON, "-c", CHECK], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_one_blas_thread_for_libraries_loaded_before_and_after_the_call():
    result = _check({})
    assert result["applied"] == 1
    assert result["before_scipy"] and set(result["before_scipy"].values()) == {1}, result
    # numpy's and scipy's OpenBLAS (two libraries in the wheels), each at one thread
    assert len(result["after"]) >= len(result["before_scipy"])
    assert set(result["after"].values()) == {1}, result


def test_environment_overrides_the_policy():
    result = _check({"TAIJI2_BLAS_THREADS": "2"})
    assert result["applied"] == 2 and set(result["after"].values()) == {2}, result


class _Applied(Exception):
    """Raised by the stand-in policy: the entry point reached it before any work."""


VERBS = {
    "calibrate": ["calibrate", "/nonexistent-bag"],
    "diagnose": ["diagnose", "/nonexistent-bag"],
    "simulate": ["simulate", "--out", "/nonexistent-dir/bag"],
    "design": ["design", "--duration-s", "1"],
    "experiment": ["experiment", "--duration-s", "1"],
    "plot": ["plot"],
}


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_every_verb_applies_the_policy_first(monkeypatch, verb):
    import taiji2_runtime.threads
    from taiji2_apps.cli.main import main as taiji2

    def applied(threads: int | None = None) -> int:
        raise _Applied

    monkeypatch.setattr(taiji2_runtime.threads, "limit_blas_threads", applied)
    with pytest.raises(_Applied):
        taiji2(VERBS[verb])


@pytest.mark.parametrize("node", ["scale_factor_estimator", "com_offset_estimator"])
def test_estimator_nodes_apply_the_policy_before_spinning(monkeypatch, node):
    import importlib

    module = importlib.import_module(f"taiji2_estimator_pkg.nodes.{node}")

    def applied(threads: int | None = None) -> int:
        raise _Applied

    monkeypatch.setattr(module, "limit_blas_threads", applied)
    monkeypatch.setattr(module, "run_node", lambda *a, **k: pytest.fail("run_node before the BLAS policy"))
    with pytest.raises(_Applied):
        module.main([node])
