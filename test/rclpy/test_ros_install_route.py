"""The README's ROS 2 route leaves the tools working (issue 26 row 6): after rosdep (package.xml's keys) and the
README's one pip command (requirements-ros.txt), ``ros2 run taiji2_apps taiji2 calibrate BAG`` runs.

This ROS 2 image is minimal and has no rosdep database: the distribution packages rosdep would install for
package.xml's keys (python3-scipy, python3-matplotlib) are stood in for by the same pins with pip, into the same
user site; everything else comes from the README's pip line, run verbatim (its ``src/taiji2`` is this checkout).
The tools then run with no PYTHONPATH but ROS 2's and the workspace's: nothing of the test's own environment.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
#: stand-ins for the Debian packages of package.xml's rosdep keys, pinned as in requirements.txt
ROSDEP_STAND_INS = ("numpy==2.4.6", "scipy==1.17.1", "PyYAML==6.0.3", "matplotlib==3.11.2")


def _readme_pip_line() -> str:
    start = "PIP_BREAK_SYSTEM_PACKAGES=1 python3 -m pip install"
    lines = [line.strip() for line in (REPO / "README.md").read_text().splitlines()
             if "requirements-ros.txt" in line and line.strip().startswith(start)]
    assert len(lines) == 1, lines
    return lines[0].replace("src/taiji2/", f"{REPO}/")


def test_readme_pip_command_completes_the_tools_under_ros2_run(ros, tmp_path):
    bag = tmp_path / "bag"
    made = subprocess.run([sys.executable, "-m", "taiji2_apps.cli.main", "simulate", "--duration-s", "600",
                           "--seed", "6", "--out", str(bag)], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr[-2000:]
    userbase = tmp_path / "userbase"
    pip = "PIP_BREAK_SYSTEM_PACKAGES=1 python3 -m pip install -q --user --disable-pip-version-check --no-compile"
    # ROS 2 and the workspace only: the ros fixture's PYTHONPATH (the test venv's packages) is dropped
    out = ros(f"export PYTHONPATH=$(echo $PYTHONPATH | tr ':' '\\n' | grep -e /opt/ros -e /install/ | paste -sd:) && "
              f"{pip} {' '.join(ROSDEP_STAND_INS)} && {_readme_pip_line()} && "
              f"python3 -c 'import rosbags.rosbag2, threadpoolctl, spacepackets; print(rosbags.rosbag2.__file__)' && "
              f"ros2 run taiji2_apps taiji2 calibrate {bag} --json",
              env={"PYTHONUSERBASE": str(userbase), "PYTHONNOUSERSITE": ""}, timeout=600)
    if out.returncode != 0 and "No matching distribution" in out.stderr + out.stdout:
        pytest.skip(f"no package index reachable: {out.stderr[-300:]}")
    assert out.returncode in (0, 3), out.stdout[-2000:] + out.stderr[-3000:]  # 3: calibrated, not every requirement met
    lines = out.stdout.splitlines()
    assert any(line.startswith(str(userbase)) for line in lines), lines[-2:-1]  # README route
    # the one JSON line (ros2 run adds "[ros2run]: Process exited with failure 3" after it for exit status 3)
    result = json.loads(next(line for line in lines if line.startswith("{")))
    assert set(result) >= {"grs1", "grs2"} and "scale_factors" in result["grs1"], sorted(result)
    assert os.environ.get("PYTHONUSERBASE") != str(userbase)
