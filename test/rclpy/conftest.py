"""The real-ROS 2 tier: colcon-built packages, `ros2 run`, `ros2 topic`, a mixed graph.

Runs only when asked (``TAIJI2_RCLPY_TIER=1``, as ``.ci/run`` does where ROS 2 is installed); the
README test command leaves it to ``.ci/run``. The workspace is built once per session with colcon
into a temporary directory; every ROS command runs in a bash that sourced ROS 2 and that workspace,
with this interpreter's site-packages appended so scipy/PyYAML/cyclonedds resolve.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ENABLED = os.environ.get("TAIJI2_RCLPY_TIER") == "1"
if not ENABLED:
    collect_ignore_glob = ["test_*.py"]

#: ROS 2 environment script (this project's shared build sets RMW_IMPLEMENTATION=rmw_cyclonedds_cpp).
ROS_ENV = os.environ.get("TAIJI2_ROS_ENV", str(REPO.parent / "shared" / "ros2" / "env.sh"))


def _domain_without_daemon() -> int:
    """A domain in 150..199 that no running ros2 daemon serves.

    ros2 commands ask the domain's daemon, which outlives the run that started it; a daemon left by
    another run on this host (perhaps with another Cyclone configuration) would answer for a graph it
    cannot see.
    """
    taken = set()
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().split(b"\0")
        except OSError:
            continue
        if b"ros2-daemon" in args and b"--ros-domain-id" in args:
            index = args.index(b"--ros-domain-id") + 1
            if index < len(args) and args[index].isdigit():
                taken.add(int(args[index]))
    start = os.getpid() % 50
    for step in range(50):
        domain = 150 + (start + step) % 50
        if domain not in taken:
            return domain
    return 150 + start


@pytest.fixture(scope="session")
def ros(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., subprocess.CompletedProcess]:
    """``ros("ros2 ...", timeout=s)`` runs a bash command line in the sourced ROS 2 + workspace."""
    if not Path(ROS_ENV).is_file():
        pytest.skip(f"no ROS 2 environment script at {ROS_ENV}")
    ws = tmp_path_factory.mktemp("ws")
    # TAIJI2_RCLPY_DOMAIN: a domain of the caller's choosing (several sessions sharing a host)
    domain = os.environ.get("TAIJI2_RCLPY_DOMAIN") or str(_domain_without_daemon())
    # every site directory of this interpreter, including those a .pth file adds (.ci/run's .venv-ros
    # reaches the README's .venv that way), since PYTHONPATH entries do not process .pth files
    packages = ":".join(p for p in sys.path if p.endswith("-packages"))  # in this interpreter's order
    # Debian's python3 first: ROS 2 and rosidl's code generators run on it
    prefix = (f"export PATH=/usr/bin:$PATH ROS_DOMAIN_ID={domain} && source {ROS_ENV} >/dev/null && "
              f"export PYTHONPATH=${{PYTHONPATH:+$PYTHONPATH:}}{packages}")
    build = subprocess.run(["bash", "-c", f"{prefix} && cd {ws} && colcon build --base-paths {REPO}/src "
                                          "--event-handlers console_direct- 2>&1"],
                           capture_output=True, text=True, timeout=900)
    assert build.returncode == 0, build.stdout[-3000:]
    prefix += f" && source {ws}/install/setup.bash"
    printed = subprocess.run(["bash", "-c", f"{prefix} && env -u CYCLONEDDS_URI ros2 run taiji2_apps taiji2 "
                              "--print-cyclonedds-config"], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0 and printed.stdout.startswith("<CycloneDDS>"), printed.stderr
    cyclonedds_uri = printed.stdout.strip()

    def run(command: str, timeout: float = 120.0, env: dict[str, str] | None = None,
            background: bool = False) -> subprocess.CompletedProcess | subprocess.Popen:
        full_env = {**os.environ, **(env or {})}
        full_env.pop("TAIJI2_RUNTIME", None)
        # one Cyclone configuration for rclpy (rmw_cyclonedds) and embedded nodes, taken as the README says:
        # export CYCLONEDDS_URI="$(taiji2 --print-cyclonedds-config)" (the embedded runtime's loopback default)
        full_env["CYCLONEDDS_URI"] = cyclonedds_uri
        full_env.update(env or {})
        args = ["bash", "-c", f"{prefix} && {command}"]
        if background:
            return subprocess.Popen(args, env=full_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    start_new_session=True)
        return subprocess.run(args, env=full_env, capture_output=True, text=True, timeout=timeout)

    return run
