"""rclpy.time.Time."""

from __future__ import annotations

from typing import Any

from taiji2_runtime.dds_rclpy.clock_type import ClockType
from taiji2_runtime.dds_rclpy.duration import Duration

_NS = 1_000_000_000


class Time:
    """A point in time of a given clock type, in integer nanoseconds."""

    def __init__(
        self, *, seconds: float = 0, nanoseconds: int = 0, clock_type: ClockType = ClockType.SYSTEM_TIME
    ) -> None:
        total = round(seconds * _NS) + int(nanoseconds)
        if total < 0:
            raise ValueError("Time: negative times are not allowed")
        self._nanoseconds = total
        self._clock_type = ClockType(clock_type)

    @property
    def nanoseconds(self) -> int:
        return self._nanoseconds

    @property
    def clock_type(self) -> ClockType:
        return self._clock_type

    def seconds_nanoseconds(self) -> tuple[int, int]:
        return divmod(self._nanoseconds, _NS)

    def to_msg(self) -> Any:
        from taiji2_runtime.interfaces import message_class

        msg = message_class("builtin_interfaces/msg/Time")()
        msg.sec, msg.nanosec = self.seconds_nanoseconds()
        return msg

    @classmethod
    def from_msg(cls, msg: Any, clock_type: ClockType = ClockType.ROS_TIME) -> Time:
        return cls(seconds=msg.sec, nanoseconds=msg.nanosec, clock_type=clock_type)

    def __add__(self, other: Duration) -> Time:
        if not isinstance(other, Duration):
            return NotImplemented
        return Time(nanoseconds=self._nanoseconds + other.nanoseconds, clock_type=self._clock_type)

    __radd__ = __add__

    def __sub__(self, other: Time | Duration) -> Any:
        if isinstance(other, Time):
            if other.clock_type != self._clock_type:
                raise TypeError("Can't subtract times with different clock types")
            return Duration(nanoseconds=self._nanoseconds - other.nanoseconds)
        if isinstance(other, Duration):
            return Time(nanoseconds=self._nanoseconds - other.nanoseconds, clock_type=self._clock_type)
        return NotImplemented

    def _check(self, other: Time) -> None:
        if not isinstance(other, Time):
            raise TypeError("Can't compare times with non-times")
        if other.clock_type != self._clock_type:
            raise TypeError("Can't compare times with different clock types")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Time):
            return False
        self._check(other)
        return self._nanoseconds == other._nanoseconds

    def __lt__(self, other: Time) -> bool:
        self._check(other)
        return self._nanoseconds < other._nanoseconds

    def __le__(self, other: Time) -> bool:
        self._check(other)
        return self._nanoseconds <= other._nanoseconds

    def __gt__(self, other: Time) -> bool:
        self._check(other)
        return self._nanoseconds > other._nanoseconds

    def __ge__(self, other: Time) -> bool:
        self._check(other)
        return self._nanoseconds >= other._nanoseconds

    def __hash__(self) -> int:
        return hash((self._nanoseconds, self._clock_type))

    def __repr__(self) -> str:
        return f"Time(nanoseconds={self._nanoseconds}, clock_type={self._clock_type.name})"
