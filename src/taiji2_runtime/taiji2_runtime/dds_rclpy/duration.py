"""rclpy.duration.Duration."""

from __future__ import annotations

from typing import Any

_NS = 1_000_000_000


class Duration:
    """A span of time in integer nanoseconds."""

    def __init__(self, *, seconds: float = 0, nanoseconds: int = 0) -> None:
        self._nanoseconds = round(seconds * _NS) + int(nanoseconds)

    @property
    def nanoseconds(self) -> int:
        return self._nanoseconds

    def to_msg(self) -> Any:
        from taiji2_runtime.interfaces import message_class

        msg = message_class("builtin_interfaces/msg/Duration")()
        msg.sec, msg.nanosec = divmod(self._nanoseconds, _NS)
        return msg

    @classmethod
    def from_msg(cls, msg: Any) -> Duration:
        return cls(seconds=msg.sec, nanoseconds=msg.nanosec)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Duration) and self._nanoseconds == other._nanoseconds

    def __lt__(self, other: Duration) -> bool:
        return self._nanoseconds < other._nanoseconds

    def __le__(self, other: Duration) -> bool:
        return self._nanoseconds <= other._nanoseconds

    def __gt__(self, other: Duration) -> bool:
        return self._nanoseconds > other._nanoseconds

    def __ge__(self, other: Duration) -> bool:
        return self._nanoseconds >= other._nanoseconds

    def __hash__(self) -> int:
        return hash(self._nanoseconds)

    def __repr__(self) -> str:
        return f"Duration(nanoseconds={self._nanoseconds})"
