"""`taiji2 experiment` through the node graph as a new user runs it (issue 27 rows 1 and 8): it ends with
a verdict, picks a private DDS domain of its own, and leaves no temporary directory behind."""

from __future__ import annotations

import os
import subprocess

from support import PYTHON, python_subprocess_env


def test_experiment_ends_with_a_verdict_on_a_private_domain_and_cleans_up(tmp_path):
    env = python_subprocess_env()
    env.pop("ROS_DOMAIN_ID", None)  # as a user runs it: the command picks a private domain
    env["TMPDIR"] = str(tmp_path)
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "experiment", "--layout", "type1",
                           "--maneuver", "paper", "--duration-s", "200"], env=env, capture_output=True, text=True,
                          timeout=300)
    # 200 s of the paper's preset cannot meet the d requirements: exit 3, and the verdict says why and what to do
    assert proc.returncode == 3, proc.stderr[-3000:]
    lines = proc.stdout.rstrip().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("verdict: "))
    assert all(line.startswith("  ") for line in lines[start + 1:]), "the output ends with the verdict"
    verdict = "\n".join(lines[start:])
    assert "of 13 requirements met" in verdict and "with the paper's type1 preset in 0.06 h" in verdict
    assert "cannot be met with this maneuver in 0.06 h" in verdict and "Cramer-Rao bound" in verdict
    assert "what to do: a designed maneuver: taiji2 design --layout type1" in verdict
    # the range is a requirement: the paper's preset with the noise leaves it in ~15 % of the samples
    assert "GRS linear range not met" in verdict and "the GRS linear readout was beyond" in verdict
    assert "(private; set ROS_DOMAIN_ID to choose one)" in proc.stderr
    domain = int(proc.stderr.split("DDS domain ")[1].split()[0])
    assert 202 <= domain <= 232
    assert not [p for p in os.listdir(tmp_path) if p.startswith("taiji2-experiment-")], "temporary logs left"
