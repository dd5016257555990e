"""taiji2_msgs for machines without ROS 2.

Only the ``.msg`` files are shipped (as package data of :mod:`taiji2_msgs.msg`); the
Python classes are derived from them at import time by :mod:`taiji2_runtime.interfaces`.
On a ROS 2 machine this package is built by colcon with rosidl instead and this file
is not used.
"""
