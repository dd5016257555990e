"""Shared fixtures. Every runtime test gets its own context and executor (as rclpy's own tests do)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

# The embedded runtime is what these tests exercise, also on a machine where rclpy imports.
os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")
# A private DDS domain per test session keeps parallel sessions on one host apart.
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under real rclpy, tests of the embedded runtime's own internals are skipped with their reason."""
    from taiji2_runtime.ros import RUNTIME

    if RUNTIME != "rclpy":
        return
    for item in items:
        marker = item.get_closest_marker("embedded_runtime")
        if marker is not None:
            reason = marker.kwargs.get("reason") or (marker.args[0] if marker.args else "embedded runtime only")
            item.add_marker(pytest.mark.skip(reason=f"embedded runtime itself: {reason}"))


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
