"""Taiji-2 spacecraft simulator: middleware-free numerical core (``core``) and ROS 2 nodes."""

__version__ = "0.1.0"
