"""Shared fixtures. Every runtime test gets its own context and executor (as rclpy's own tests do)."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"

# The embedded runtime is what these tests exercise, also on a machine where rclpy imports.
os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")
# A private DDS domain per test session keeps parallel sessions on one host apart.
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))


@pytest.fixture
def context() -> Iterator[object]:
    from taiji2_runtime.ros import rclpy

    ctx = rclpy.context.Context()
    rclpy.init(args=["test"], context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(context: object) -> Iterator[object]:
    from taiji2_runtime.ros import rclpy

    ex = rclpy.executors.SingleThreadedExecutor(context=context)
    yield ex
    ex.shutdown()


def spin_until(executor: object, predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Spin ``executor`` until ``predicate()`` holds or ``timeout_s`` passes; returns the predicate."""
    import time

    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def python_subprocess_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    return env


PYTHON = sys.executable
