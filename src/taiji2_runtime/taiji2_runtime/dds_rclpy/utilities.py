"""rclpy.utilities subset."""

from taiji2_runtime.dds_rclpy.arguments import remove_ros_args
from taiji2_runtime.dds_rclpy.context import get_default_context

__all__ = ["get_default_context", "remove_ros_args"]
