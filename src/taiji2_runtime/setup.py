"""ament_python package taiji2_runtime; also installs with pip (see the workspace README)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "taiji2_runtime"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Runs the Taiji-2 nodes on rclpy where ROS 2 is installed, or on a thin rclpy-compatible runtime over Eclipse Cyclone DDS elsewhere; the taiji2 command (run, topic, bag, calibrate, diagnose).",
    license="Apache-2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    package_data={PACKAGE: ["py.typed"]},
    install_requires=["numpy", "PyYAML", "taiji2_model", "rosbags", "cyclonedds", "threadpoolctl", "spacepackets", "cryptography"],
    python_requires=">=3.10",
)
