"""ament_python package taiji2_sim_pkg; also installs with pip (see the workspace README)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "taiji2_sim_pkg"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Taiji-2 spacecraft simulator (attitude dynamics, star tracker, two GRS) and maneuver commander nodes, with a middleware-free numerical core.",
    license="Apache-2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    package_data={PACKAGE: ["py.typed"]},
    install_requires=["numpy", "scipy", "PyYAML", "taiji2_model", "taiji2_runtime"],
    python_requires=">=3.10",
    entry_points={"console_scripts": ["maneuver_commander = taiji2_sim_pkg.nodes.maneuver_commander:main", "spacecraft_sim = taiji2_sim_pkg.nodes.spacecraft_sim:main", "telemetry_packetizer = taiji2_sim_pkg.nodes.telemetry_packetizer:main", "space_link = taiji2_sim_pkg.nodes.space_link:main", "onboard_executor = taiji2_sim_pkg.nodes.onboard_executor:main", "uplink_intruder = taiji2_sim_pkg.nodes.uplink_intruder:main"]},
)
