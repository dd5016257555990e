"""ament_python package taiji2_model; also installs with pip (see the workspace README)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "taiji2_model"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="The Taiji-2 nominal model: layouts and their schema, frames and the C_i rotations, timing conventions, the raw-data contract, maneuvers and shipped designs, and the effect definitions. numpy/scipy/PyYAML only, no middleware.",
    license="Apache-2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/maneuvers", glob("config/maneuvers/*.yaml")),
    ],
    package_data={PACKAGE: ["py.typed"]},
    install_requires=['numpy', 'scipy', 'PyYAML'],
    python_requires=">=3.10",
)
