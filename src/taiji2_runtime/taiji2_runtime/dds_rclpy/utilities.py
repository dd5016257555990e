"""rclpy.utilities subset."""

from .arguments import remove_ros_args
from .context import get_default_context

__all__ = ["get_default_context", "remove_ros_args"]
