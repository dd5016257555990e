"""`taiji2 simulate`: a contract bag any ROS 2 tool reads, the requested conventions in it, bad input in one line."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from support import PYTHON, python_subprocess_env

CONTRACT = {"/taiji2/star_tracker", "/taiji2/grs1/voltages", "/taiji2/grs2/voltages", "/taiji2/maneuver/command"}


def _simulate(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "simulate", *args], env=python_subprocess_env(),
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_reference_bag_is_a_contract_bag(tmp_path, storage):
    out = tmp_path / "bag"
    proc = _simulate("--fidelity", "reference", "--duration-s", "60", "--seed", "3", "--storage", storage,
                     "--effect", "actuation_delay:delay_s=0.1", "--override", "timing.grs_stamp=midpoint",
                     "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["samples"] == 600 and summary["fidelity"] == "reference"
    with AnyReader([out]) as reader:  # plain rosbags, no project code
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert CONTRACT <= set(counts) and all(counts[t] == 600 for t in CONTRACT)
        grs = [c for c in reader.connections if c.topic == "/taiji2/grs1/voltages"]
        stamps = [reader.deserialize(raw, c.msgtype).header.stamp for c, _, raw in reader.messages(connections=grs)]
    t = np.array([s.sec + 1e-9 * s.nanosec for s in stamps])
    np.testing.assert_allclose(np.diff(t), 0.1, atol=1e-9)  # nanosecond stamps of a 10-Hz grid


@pytest.mark.parametrize(("args", "names"), [
    (["--effect", "no_such_effect:x=1"], "no_such_effect"),
    (["--effect", "thruster_response:time_constant_s=-0.1"], "time_constant_s"),
    (["--override", "timing.grs_stamp=sideways"], "timing.grs_stamp"),
    (["--duration-s", "-5"], "duration"),
])
def test_bad_input_is_one_line(tmp_path, args, names):
    proc = _simulate(*args, "--duration-s", "60", "--out", str(tmp_path / "bag")) if "--duration-s" not in args else \
        _simulate(*args, "--out", str(tmp_path / "bag"))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and names in lines[0], proc.stderr
    assert not (tmp_path / "bag").exists()


def test_existing_output_is_refused(tmp_path):
    (tmp_path / "bag").mkdir()
    proc = _simulate("--duration-s", "60", "--out", str(tmp_path / "bag"))
    assert proc.returncode == 2 and "already exists" in proc.stderr
