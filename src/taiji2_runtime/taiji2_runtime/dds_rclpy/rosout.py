"""``/rosout``: each node publishes its log lines as rcl_interfaces/msg/Log, as rcl does for rclpy.

QoS as rcl's ``rcl_qos_profile_rosout_default`` (reliable, transient-local, keep-last 1000), so
``ros2 topic echo /rosout`` and rqt_console see an embedded node's log like any other; rcl's 10-s
lifespan is not set (lifespan does not affect matching). A log line reaches the /rosout of the
node whose logger name it carries, or of the nearest parent logger (``node.child`` -> ``node``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from taiji2_runtime.dds_rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from taiji2_runtime.interfaces import message_class

ROSOUT_TOPIC = "/rosout"
qos_profile_rosout_default = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: logger name -> function publishing one line (severity, logger name, message, ns, file, function, line)
_sinks: dict[str, Callable[..., None]] = {}
_publishing = threading.local()


def attach(logger_name: str, publisher: Any) -> None:
    """Send the log lines of ``logger_name`` (and its children) to ``publisher``."""
    log_class = message_class("rcl_interfaces/msg/Log")
    time_class = message_class("builtin_interfaces/msg/Time")

    def sink(severity: int, name: str, text: str, ns: int, file: str, function: str, line: int) -> None:
        publisher.publish(log_class(stamp=time_class(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                                    level=severity, name=name, msg=text, file=file, function=function, line=line))

    _sinks[logger_name] = sink


def detach(logger_name: str) -> None:
    _sinks.pop(logger_name, None)


def forward(severity: int, name: str, text: str, ns: int, file: str, function: str, line: int) -> None:
    """Publish a log line on the /rosout of the node owning logger ``name`` (if any)."""
    if getattr(_publishing, "active", False):
        return  # a line logged while publishing a line (a blocked writer's warning) stays on stderr
    owner = name
    while owner not in _sinks and "." in owner:
        owner = owner.rsplit(".", 1)[0]
    sink = _sinks.get(owner)
    if sink is None:
        return
    _publishing.active = True
    try:
        sink(severity, name, text, ns, file, function, line)
    except Exception:  # a log line that cannot be published must not end the node
        pass
    finally:
        _publishing.active = False
