"""rclpy.timer.Timer: periodic callbacks on a node clock (wall, steady or simulated ROS time)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from taiji2_runtime.dds_rclpy.clock import Clock


class Timer:
    """Calls ``callback`` every ``timer_period_ns`` of ``clock`` time, skipping missed periods like rcl."""

    def __init__(self, callback: Callable[[], Any] | None, timer_period_ns: int, clock: Clock) -> None:
        if timer_period_ns < 0:
            raise ValueError(f"timer period must be >= 0 s, got {timer_period_ns * 1e-9} s")
        self.callback = callback
        self._period_ns = int(timer_period_ns)
        self._clock = clock
        self._canceled = False
        self._next_ns = clock.now().nanoseconds + self._period_ns

    @property
    def clock(self) -> Clock:
        return self._clock

    @property
    def timer_period_ns(self) -> int:
        return self._period_ns

    def is_canceled(self) -> bool:
        return self._canceled

    def cancel(self) -> None:
        self._canceled = True

    def reset(self) -> None:
        self._canceled = False
        self._next_ns = self._clock.now().nanoseconds + self._period_ns

    def destroy(self) -> None:
        self._canceled = True

    def time_until_next_call(self) -> int | None:
        """Nanoseconds until the timer is due (negative when late); None when canceled."""
        if self._canceled:
            return None
        return self._next_ns - self._clock.now().nanoseconds

    def is_ready(self) -> bool:
        if self._canceled:
            return False
        now = self._clock.now().nanoseconds
        if now + self._period_ns < self._next_ns:
            # time jumped backwards (e.g. a looped bag replay on /clock): restart from now
            self._next_ns = now + self._period_ns
        return now >= self._next_ns

    def _mark_called(self) -> None:
        now = self._clock.now().nanoseconds
        if self._period_ns == 0:
            self._next_ns = now
            return
        missed = (now - self._next_ns) // self._period_ns + 1
        self._next_ns += max(1, missed) * self._period_ns
