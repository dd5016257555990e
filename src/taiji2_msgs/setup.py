"""pip build of taiji2_msgs for machines without ROS 2 (colcon uses CMakeLists.txt instead).

Ships the same ``msg/*.msg`` files that rosidl compiles; Python classes are derived from
them at import time by taiji2_runtime.
"""

from setuptools import setup

setup(
    name="taiji2_msgs",
    version="0.1.0",
    description="Taiji-2 GRS calibration messages (.msg definitions) for use without ROS 2",
    license="Apache-2.0",
    packages=["taiji2_msgs", "taiji2_msgs.msg"],
    package_dir={"taiji2_msgs": "pip", "taiji2_msgs.msg": "msg"},
    package_data={"taiji2_msgs.msg": ["*.msg"]},
    python_requires=">=3.10",
)
