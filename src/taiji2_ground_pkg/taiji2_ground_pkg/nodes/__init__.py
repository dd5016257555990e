"""ROS 2 nodes of the ground segment (thin wrappers: the logic is in the modules beside them)."""
