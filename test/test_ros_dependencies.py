"""package.xml declares only dependencies rosdep resolves, and with requirements-ros.txt they cover every
third-party import of the packages (issue 26 row 6). The route itself (rosdep's packages + the README's pip
command, then ``ros2 run taiji2_apps taiji2 calibrate``) runs in test/rclpy/test_ros_install_route.py."""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from importlib.metadata import PackageNotFoundError, packages_distributions, requires
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("taiji2_msgs", "taiji2_model", "taiji2_runtime", "taiji2_sim_pkg", "taiji2_estimator_pkg",
            "taiji2_ground_pkg", "taiji2_apps")
#: the python3-* rosdep keys package.xml may use, each with the PyPI distribution it installs; checked in
#: ros/rosdistro rosdep/python.yaml (commit 8468e88, 2026-08-22): no key exists for threadpoolctl,
#: spacepackets, fastcrc, cyclonedds, dask, distributed or pyarrow (requirements-ros.txt has those)
ROSDEP_PYTHON_KEYS = {"python3-numpy": "numpy", "python3-scipy": "scipy", "python3-yaml": "PyYAML",
                      "python3-matplotlib": "matplotlib", "python3-rosbags-pip": "rosbags", "python3-pytest": "pytest"}
#: ROS 2 packages the manifests may name (rosdep resolves them to ros-<distro>-* packages)
ROS_PACKAGES = {"rclpy", "std_msgs", "geometry_msgs", "diagnostic_msgs", "rosgraph_msgs", "ament_cmake",
                "rosidl_default_generators", "rosidl_default_runtime", "builtin_interfaces"}


def _keys(package: str) -> set[str]:
    root = ET.parse(REPO / "src" / package / "package.xml").getroot()
    return {e.text.strip() for e in root if e.tag.endswith("depend") and e.text}


def _pins(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.\-\[\]]+)==(\S+)", line.strip())
        if m:
            out[m.group(1).split("[")[0].lower()] = m.group(2)
    return out


def _closure(names: set[str]) -> set[str]:
    """``names`` and everything they require (installed metadata), lower case."""
    seen: set[str] = set()
    todo = list(names)
    while todo:
        name = todo.pop().lower()
        if name in seen:
            continue
        seen.add(name)
        try:
            reqs = requires(name) or []
        except PackageNotFoundError:
            continue
        todo += [re.split(r"[ ;<>=!~\[(]", r, maxsplit=1)[0] for r in reqs if "extra ==" not in r]
    return seen


def _third_party_imports(package: str) -> set[str]:
    found = set()
    for path in (REPO / "src" / package / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module else [])
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and not top.startswith("taiji2") and top not in (
                        "rclpy", "compression"):  # compression: the standard library's from Python 3.14
                    found.add(top)
    return found


def test_every_manifest_key_resolves_in_rosdep():
    for package in PACKAGES:
        unknown = {k for k in _keys(package) if k not in ROSDEP_PYTHON_KEYS and k not in ROS_PACKAGES
                   and k not in PACKAGES}
        assert unknown == set(), (package, unknown)


def test_rosdep_keys_and_requirements_ros_cover_every_import():
    ros_pins = _pins(REPO / "requirements-ros.txt")
    assert all(_pins(REPO / "requirements.txt")[name] == pin for name, pin in ros_pins.items()), ros_pins
    distributions = packages_distributions()
    for package in PACKAGES:
        provided = {ROSDEP_PYTHON_KEYS[k].lower() for k in _keys(package) if k in ROSDEP_PYTHON_KEYS}
        covered = _closure(provided | set(ros_pins))
        missing = {top for top in _third_party_imports(package)
                   if not {d.lower() for d in distributions.get(top, [top])} & covered}
        assert missing == set(), (package, missing)


def test_readme_gives_the_pip_command_of_requirements_ros():
    command = "PIP_BREAK_SYSTEM_PACKAGES=1 python3 -m pip install --user -r src/taiji2/requirements-ros.txt"
    assert command in (REPO / "README.md").read_text()
    assert command in (REPO / "requirements-ros.txt").read_text()
