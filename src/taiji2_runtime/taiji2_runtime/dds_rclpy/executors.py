"""rclpy.executors: a single-threaded executor waiting on one Cyclone DDS WaitSet.

Work items are subscription samples and due timers. ``spin_once`` runs at most one callback, as
in rclpy. Readers are drained in bounded batches, round-robin, so no topic starves another and
the DDS reader history (reliable, keep-all where asked) holds whatever is not yet processed.
The wait is cut into short slices so that SIGINT/SIGTERM are handled within ~0.1 s.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException, GuardCondition, WaitSet

from taiji2_runtime.dds_rclpy.context import DUPLICATE_NODE_NAME, Context, get_default_context
from taiji2_runtime.dds_rclpy.exceptions import NodeNameNonUniqueError, NotInitializedException
from taiji2_runtime.dds_rclpy.task import Future

_TAKE_BATCH = 64
_WAIT_SLICE_NS = 100_000_000
_NAME_CHECK_PERIOD_S = 0.25


class ExternalShutdownException(Exception):
    """The context was shut down from outside the executor (signal, or another thread)."""


class ShutdownException(Exception):
    """The executor was shut down."""


class TimeoutException(Exception):
    """An operation timed out."""


class Executor:
    """Runs the callbacks of the nodes added to it, one at a time, in the calling thread."""

    def __init__(self, *, context: Context | None = None) -> None:
        self._context = context or get_default_context()
        self._nodes: list[Any] = []
        self._pending: deque[tuple[Callable[..., Any], tuple[Any, ...]]] = deque()
        self._waitset: WaitSet | None = None
        self._guard: GuardCondition | None = None
        self._waitset_version = -1
        self._is_shutdown = False
        self._next_name_check = 0.0
        self._context.add_executor(self)

    @property
    def context(self) -> Context:
        return self._context

    def add_node(self, node: Any) -> bool:
        if node in self._nodes:
            return False
        self._nodes.append(node)
        node.executor = self
        self.wake()
        return True

    def remove_node(self, node: Any) -> None:
        if node in self._nodes:
            self._nodes.remove(node)
            node.executor = None
            self._pending = deque(item for item in self._pending if getattr(item[0], "__self__", None) is not node)

    def get_nodes(self) -> list[Any]:
        return list(self._nodes)

    def wake(self) -> None:
        """Interrupt a wait (new timer, completed future, shutdown)."""
        if self._guard is not None:
            try:
                self._guard.set(True)
            except Exception:
                pass

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        self._is_shutdown = True
        for node in list(self._nodes):
            self.remove_node(node)
        self._context.remove_executor(self)
        self.wake()
        return True

    def create_task(self, callback: Callable[..., Any], *args: Any) -> Future:
        """Run ``callback(*args)`` on the executor; the returned future holds its result."""
        future = Future(executor=self)

        def run() -> None:
            try:
                future.set_result(callback(*args))
            except Exception as exc:
                future.set_exception(exc)

        self._pending.append((run, ()))
        self.wake()
        return future

    # -- spinning ------------------------------------------------------------------------------
    def spin(self) -> None:
        """Run callbacks until the context is shut down.

        Raises
        ------
        ExternalShutdownException
            When the context was shut down by a signal or from elsewhere.
        """
        while self._context.ok() and not self._is_shutdown:
            self.spin_once()
        if not self._context.ok():
            reason = self._context.shutdown_reason or ""
            if reason.startswith(DUPLICATE_NODE_NAME):
                raise NodeNameNonUniqueError(reason[len(DUPLICATE_NODE_NAME) + 2:])
            raise ExternalShutdownException(reason)

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Run at most one ready callback, waiting up to ``timeout_sec`` (None: forever) for one."""
        deadline = None if timeout_sec is None or timeout_sec < 0 else time.monotonic() + timeout_sec
        while self._context.ok() and not self._is_shutdown:
            if self._pending or self._collect():
                callback, args = self._pending.popleft()
                callback(*args)
                return
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return
            self._wait(remaining)

    def spin_until_future_complete(self, future: Future, timeout_sec: float | None = None) -> None:
        """Spin until ``future`` is done, the context shuts down, or ``timeout_sec`` passes."""
        deadline = None if timeout_sec is None or timeout_sec < 0 else time.monotonic() + timeout_sec
        future._executor = self
        while self._context.ok() and not future.done():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return
            self.spin_once(timeout_sec=remaining)

    def spin_once_until_future_complete(self, future: Future, timeout_sec: float | None = None) -> None:
        future._executor = self
        self.spin_once(timeout_sec)

    # -- internals -----------------------------------------------------------------------------
    def _ensure_waitset(self) -> WaitSet:
        version = self._context.entities_version
        if self._waitset is None or version != self._waitset_version:
            participant = self._context.participant()
            waitset = WaitSet(participant)
            if self._guard is None:
                self._guard = GuardCondition(participant)
            waitset.attach(self._guard)
            for node in self._nodes:
                for subscription in node.subscriptions:
                    waitset.attach(subscription.read_condition)
                for service in node.services:
                    waitset.attach(service.read_condition)
            self._waitset, self._waitset_version = waitset, version
        return self._waitset

    def _collect(self) -> bool:
        if not self._context.ok():
            return False
        now = time.monotonic()
        if now >= self._next_name_check:
            self._next_name_check = now + _NAME_CHECK_PERIOD_S
            self._context.check_node_names()
            if not self._context.ok():
                return False
        for node in list(self._nodes):
            for subscription in list(node.subscriptions):
                for msg in subscription.take(_TAKE_BATCH):
                    self._pending.append((subscription.callback, (msg,)))
            for service in list(node.services):
                service.send_held()  # replies waiting for their client's reply reader (service.py)
                for request in service.take(_TAKE_BATCH):
                    self._pending.append((service.answer, (request,)))
            for timer in list(node.timers):
                if timer.is_ready():
                    timer._mark_called()
                    if timer.callback is not None:
                        self._pending.append((timer.callback, ()))
        return bool(self._pending)

    def _next_timer_wait_ns(self) -> int | None:
        waits = []
        for node in self._nodes:
            for timer in node.timers:
                if timer.is_canceled():
                    continue
                clock = timer.clock
                if getattr(clock, "ros_time_is_active", False):
                    continue  # simulated time advances only when /clock arrives, which wakes us
                waits.append(max(0, timer.time_until_next_call() or 0))
        return min(waits) if waits else None

    def _wait(self, remaining_s: float | None) -> None:
        try:
            waitset = self._ensure_waitset()
        except NotInitializedException:
            return
        wait_ns = _WAIT_SLICE_NS
        timer_ns = self._next_timer_wait_ns()
        if timer_ns is not None:
            wait_ns = min(wait_ns, timer_ns)
        if remaining_s is not None:
            wait_ns = min(wait_ns, max(0, int(remaining_s * 1e9)))
        try:
            if wait_ns > 0:
                waitset.wait(wait_ns)
            if self._guard is not None and self._context.ok():
                self._guard.take()
        except DDSException:
            # the participant went away under us: a signal shut the context down mid-wait
            if self._context.ok():
                raise


class SingleThreadedExecutor(Executor):
    """rclpy.executors.SingleThreadedExecutor."""


class MultiThreadedExecutor(Executor):
    """Accepted for API compatibility; runs callbacks in the calling thread like SingleThreadedExecutor."""

    def __init__(self, num_threads: int | None = None, *, context: Context | None = None) -> None:
        super().__init__(context=context)
