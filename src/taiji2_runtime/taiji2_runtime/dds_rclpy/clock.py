"""rclpy.clock: Clock and ROSClock (simulated time from /clock when use_sim_time is set)."""

from __future__ import annotations

import time as _time

from taiji2_runtime.dds_rclpy.clock_type import ClockType
from taiji2_runtime.dds_rclpy.time import Time


class Clock:
    """A clock of a given type; ``now()`` returns a :class:`Time`."""

    def __init__(self, *, clock_type: ClockType = ClockType.SYSTEM_TIME) -> None:
        self._clock_type = ClockType(clock_type)

    @property
    def clock_type(self) -> ClockType:
        return self._clock_type

    def now(self) -> Time:
        if self._clock_type == ClockType.STEADY_TIME:
            ns = _time.monotonic_ns()
        else:
            ns = _time.time_ns()
        return Time(nanoseconds=ns, clock_type=self._clock_type)

    def __repr__(self) -> str:
        return f"Clock(clock_type={self._clock_type.name})"


class ROSClock(Clock):
    """ROS time: system time, or the last /clock value while ROS time override is active."""

    def __init__(self) -> None:
        super().__init__(clock_type=ClockType.ROS_TIME)
        self._ros_time_active = False
        self._override_ns = 0

    @property
    def ros_time_is_active(self) -> bool:
        return self._ros_time_active

    def _set_ros_time_is_active(self, enabled: bool) -> None:
        self._ros_time_active = bool(enabled)

    def set_ros_time_override(self, time: Time) -> None:
        self._override_ns = time.nanoseconds

    def now(self) -> Time:
        if self._ros_time_active:
            return Time(nanoseconds=self._override_ns, clock_type=ClockType.ROS_TIME)
        return Time(nanoseconds=_time.time_ns(), clock_type=ClockType.ROS_TIME)
