"""rclpy.task.Future."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class Future:
    """The result of an asynchronous operation, completed by a callback on the executor."""

    def __init__(self, *, executor: Any = None) -> None:
        self._lock = threading.Lock()
        self._done = False
        self._cancelled = False
        self._result: Any = None
        self._exception: BaseException | None = None
        self._callbacks: list[Callable[[Future], None]] = []
        self._executor = executor

    def cancel(self) -> None:
        with self._lock:
            if not self._done:
                self._cancelled = True
        self._schedule_callbacks()

    def cancelled(self) -> bool:
        return self._cancelled

    def done(self) -> bool:
        return self._done or self._cancelled

    def result(self) -> Any:
        if self._exception is not None:
            raise self._exception
        return self._result

    def exception(self) -> BaseException | None:
        return self._exception

    def set_result(self, result: Any) -> None:
        with self._lock:
            self._result = result
            self._done = True
            self._cancelled = False
        self._schedule_callbacks()

    def set_exception(self, exception: BaseException) -> None:
        with self._lock:
            self._exception = exception
            self._done = True
            self._cancelled = False
        self._schedule_callbacks()

    def add_done_callback(self, callback: Callable[[Future], None]) -> None:
        invoke = False
        with self._lock:
            if self.done():
                invoke = True
            else:
                self._callbacks.append(callback)
        if invoke:
            callback(self)

    def _schedule_callbacks(self) -> None:
        callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            callback(self)
        if self._executor is not None:
            self._executor.wake()
