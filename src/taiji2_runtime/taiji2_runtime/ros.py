"""The one place that decides which ROS 2 client library runs the nodes.

Node code imports ``rclpy`` and message modules from here and nowhere else::

    from taiji2_runtime.ros import rclpy, messages
    WrenchStamped = messages.geometry_msgs.WrenchStamped

* Where ``rclpy`` imports (a sourced ROS 2 Humble/Jazzy workspace), it is used unchanged and
  messages are the rosidl-generated classes.
* Elsewhere the same API is provided by :mod:`taiji2_runtime.dds_rclpy` over Eclipse Cyclone DDS
  with ROS 2 wire conventions, and messages are derived from the ``.msg`` definitions.

``TAIJI2_RUNTIME=cyclonedds`` forces the embedded runtime even where rclpy imports (for tests of
the embedded runtime on a ROS machine); ``TAIJI2_RUNTIME=rclpy`` makes a missing rclpy an error.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType
from typing import Any

_choice = os.environ.get("TAIJI2_RUNTIME", "auto").strip().lower()
if _choice not in ("auto", "rclpy", "cyclonedds"):
    raise ImportError(f"TAIJI2_RUNTIME={_choice!r}: expected 'auto', 'rclpy' or 'cyclonedds'")

rclpy: ModuleType
if _choice == "cyclonedds":
    RUNTIME = "cyclonedds"
else:
    try:
        import rclpy  # type: ignore[no-redef]

        for _sub in ("node", "qos", "executors", "task", "time", "duration", "clock", "parameter", "exceptions",
                     "logging", "utilities"):
            importlib.import_module(f"rclpy.{_sub}")
        RUNTIME = "rclpy"
    except ImportError:
        if _choice == "rclpy":
            raise
        RUNTIME = "cyclonedds"

if RUNTIME == "cyclonedds":
    from taiji2_runtime import dds_rclpy as rclpy

    RCLError: type[Exception] = rclpy.exceptions.RCLError
else:
    # rcl's error type lives in the C extension, not in rclpy.exceptions (Humble and Jazzy alike)
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl

    RCLError = _rclpy_impl.RCLError


class _Messages:
    """``messages.<package>`` is the ``<package>.msg`` module of the chosen runtime."""

    def __getattr__(self, package: str) -> Any:
        if package.startswith("_"):
            raise AttributeError(package)
        if RUNTIME == "rclpy":
            return importlib.import_module(f"{package}.msg")
        from taiji2_runtime.interfaces import message_module

        return message_module(package)


messages = _Messages()

__all__ = ["RUNTIME", "RCLError", "messages", "rclpy"]
