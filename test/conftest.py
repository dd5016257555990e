"""Shared fixtures. Every runtime test gets its own context and executor (as rclpy's own tests do)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

# The embedded runtime is what these tests exercise, also on a machine where rclpy imports.
os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")
# The project's BLAS policy (docs/threads.md) for the test processes and the graphs they start, as
# every entry point applies it: BLAS threads spinning on small matrices slow a busy machine tenfold.
from taiji2_runtime.threads import limit_blas_threads

limit_blas_threads()
# A private DDS domain per test session keeps parallel sessions on one host apart; the xdist workers
# of one session (gw0, gw1, ...) inherit it and each moves to a domain of its own.
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
if os.environ.get("PYTEST_XDIST_WORKER", "").startswith("gw"):
    os.environ["ROS_DOMAIN_ID"] = str(int(os.environ["ROS_DOMAIN_ID"]) + 1 + int(os.environ["PYTEST_XDIST_WORKER"][2:]))


#: test folders whose tests run node graphs in subprocesses: two xdist groups, the fault graphs and the
#: rest, each on one worker, so at most two graphs run at once (CI time: in one group, on one worker, the
#: nine slowest graph tests alone took 422 s of the suite's 910 s). Their waits are bounded by simulated
#: progress, so a graph beside another is only slower (the suite passes beside two CPU-bound processes, and the
#: kill test runs beside two)
GRAPH_FOLDERS = {"faults": "graph-faults", "nodes": "graph", "bag": "graph", "runtime": "graph", "rclpy": "graph"}


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads xdist_group into the node ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """xdist groups (the graph tests together, every other module on one worker, so module fixtures are
    made once); under real rclpy, tests of the embedded runtime's own internals skip with their reason."""
    from taiji2_runtime.ros import RUNTIME

    root = Path(__file__).parent
    for item in items:
        parts = item.path.relative_to(root).parts if item.path.is_relative_to(root) else (item.path.name,)
        group = GRAPH_FOLDERS.get(parts[0], "/".join(parts))
        item.add_marker(pytest.mark.xdist_group(group))
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
