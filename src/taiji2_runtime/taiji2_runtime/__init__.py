"""taiji2_runtime: runs the Taiji-2 nodes on rclpy, or on Cyclone DDS where ROS 2 is absent."""

__version__ = "0.1.0"
