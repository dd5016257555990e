"""``taiji2 --print-cyclonedds-config``: the configuration a mixed rclpy/embedded graph shares (issue 26 row 7).
The rclpy tier exports what it prints to every ROS 2 command and node it runs (test/rclpy/conftest.py)."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET

from taiji2_runtime.cyclonedds_config import DEFAULT_CYCLONEDDS_CONFIG

from support import PYTHON, python_subprocess_env

PROBE = ("import sys; from taiji2_apps.cli.main import main; status = main(['--print-cyclonedds-config']); "
         "assert 'cyclonedds' not in sys.modules, 'imported cyclonedds'; sys.exit(status)")


def _print_config(**env: str) -> subprocess.CompletedProcess:
    full = python_subprocess_env()
    full.pop("CYCLONEDDS_URI", None)
    full.update(env)
    return subprocess.run([PYTHON, "-c", PROBE], env=full, capture_output=True, text=True, timeout=60)


def test_prints_the_default_on_one_line_without_the_dds_library():
    out = _print_config()
    assert out.returncode == 0, out.stderr
    printed = out.stdout.strip()
    assert "\n" not in printed  # a value for export CYCLONEDDS_URI="$(...)"
    # the same document as the runtime's default (whitespace between elements aside)
    canonical = [(e.tag, dict(e.attrib), (e.text or "").strip()) for e in ET.fromstring(printed).iter()]
    assert canonical == [(e.tag, dict(e.attrib), (e.text or "").strip())
                         for e in ET.fromstring(DEFAULT_CYCLONEDDS_CONFIG).iter()]


def test_prints_cyclonedds_uri_when_set():
    out = _print_config(CYCLONEDDS_URI="file:///etc/cyclonedds.xml")
    assert out.returncode == 0 and out.stdout.strip() == "file:///etc/cyclonedds.xml", out.stderr
