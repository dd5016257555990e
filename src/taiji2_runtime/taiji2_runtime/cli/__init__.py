"""The ``taiji2`` command: ros2-style verbs that work with or without ROS 2."""
