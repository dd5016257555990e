"""Message classes of taiji2_msgs, derived at import time from the ``.msg`` files beside this file.

Used only when the package is installed with pip (no ROS 2); colcon builds the rosidl
package instead. ``from taiji2_msgs.msg import StarTracker`` works in both worlds.
"""

from typing import Any


def __getattr__(name: str) -> Any:
    from taiji2_runtime.interfaces import message_class

    try:
        return message_class(f"taiji2_msgs/msg/{name}")
    except KeyError as exc:
        raise AttributeError(f"taiji2_msgs.msg has no message {name!r}") from exc
