"""rclpy.logging subset: named loggers printing in the rcutils console format to stderr."""

from __future__ import annotations

import sys
import time
from enum import IntEnum
from typing import Any


class LoggingSeverity(IntEnum):
    """rclpy.logging.LoggingSeverity."""

    UNSET = 0
    DEBUG = 10
    INFO = 20
    WARN = 30
    ERROR = 40
    FATAL = 50


_default_level = LoggingSeverity.INFO
_levels: dict[str, LoggingSeverity] = {}
_last_logged: dict[tuple[str, int], int] = {}


def set_default_level(level: str | LoggingSeverity) -> None:
    """Default severity threshold (from ``--log-level``)."""
    global _default_level
    _default_level = level if isinstance(level, LoggingSeverity) else LoggingSeverity[str(level).upper()]


class RcutilsLogger:
    """A named logger: ``[LEVEL] [seconds.nanoseconds] [name]: message`` on stderr."""

    def __init__(self, name: str = "") -> None:
        self.name = name

    def get_child(self, name: str) -> RcutilsLogger:
        return RcutilsLogger(f"{self.name}.{name}" if self.name else name)

    def set_level(self, level: LoggingSeverity) -> None:
        _levels[self.name] = LoggingSeverity(level)

    def get_effective_level(self) -> LoggingSeverity:
        return _levels.get(self.name, _default_level)

    def is_enabled_for(self, severity: LoggingSeverity) -> bool:
        return severity >= self.get_effective_level()

    def log(self, message: Any, severity: LoggingSeverity, *, throttle_duration_sec: float | None = None,
            once: bool = False, **_kwargs: Any) -> bool:
        if not self.is_enabled_for(severity):
            return False
        ns = time.time_ns()
        caller = sys._getframe(2)
        if throttle_duration_sec or once:
            site = (caller.f_code.co_filename, caller.f_lineno)
            last = _last_logged.get(site)
            if last is not None and (once or ns - last < throttle_duration_sec * 1e9):
                return False
            _last_logged[site] = ns
        print(
            f"[{severity.name}] [{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}] [{self.name}]: {message}",
            file=sys.stderr,
            flush=True,
        )
        from taiji2_runtime.dds_rclpy.rosout import forward

        forward(int(severity), self.name, str(message), ns, caller.f_code.co_filename, caller.f_code.co_name,
                caller.f_lineno)
        return True

    def debug(self, message: Any, **kwargs: Any) -> bool:
        return self.log(message, LoggingSeverity.DEBUG, **kwargs)

    def info(self, message: Any, **kwargs: Any) -> bool:
        return self.log(message, LoggingSeverity.INFO, **kwargs)

    def warning(self, message: Any, **kwargs: Any) -> bool:
        return self.log(message, LoggingSeverity.WARN, **kwargs)

    warn = warning

    def error(self, message: Any, **kwargs: Any) -> bool:
        return self.log(message, LoggingSeverity.ERROR, **kwargs)

    def fatal(self, message: Any, **kwargs: Any) -> bool:
        return self.log(message, LoggingSeverity.FATAL, **kwargs)


def get_logger(name: str) -> RcutilsLogger:
    """rclpy.logging.get_logger."""
    return RcutilsLogger(name)
