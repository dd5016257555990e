"""ament_python package taiji2_estimator_pkg; also installs with pip (see the workspace README)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "taiji2_estimator_pkg"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Taiji-2 GRS scale-factor and c.m.-offset estimator nodes, offline calibration and sim-to-real gap diagnosis, with a middleware-free numerical core.",
    license="Apache-2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    package_data={PACKAGE: ["py.typed"]},
    install_requires=["numpy", "scipy", "PyYAML", "matplotlib", "taiji2_model", "taiji2_runtime"],
    python_requires=">=3.10",
    entry_points={
        "console_scripts": ["scale_factor_estimator = taiji2_estimator_pkg.nodes.scale_factor_estimator:main", "com_offset_estimator = taiji2_estimator_pkg.nodes.com_offset_estimator:main"],
    },
)
