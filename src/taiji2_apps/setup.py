"""ament_python package taiji2_apps; also installs with pip (see the workspace README)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "taiji2_apps"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Taiji-2 applications: the taiji2 command (experiment, calibrate, diagnose, simulate, plot, design, campaign and the ros2-style verbs), experiment runners, Monte Carlo campaigns on Dask and maneuver design.",
    license="Apache-2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    package_data={PACKAGE: ["py.typed"]},
    install_requires=['numpy', 'scipy', 'PyYAML', 'matplotlib', 'dask', 'distributed', 'pyarrow', 'taiji2_model', 'taiji2_runtime', 'taiji2_sim_pkg', 'taiji2_estimator_pkg', 'taiji2_ground_pkg'],
    python_requires=">=3.10",
    entry_points={'console_scripts': ['taiji2 = taiji2_apps.cli.main:main']},
)
