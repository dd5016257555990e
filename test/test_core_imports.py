"""The numerical core imports with no middleware loaded (no rclpy, no Cyclone DDS, no runtime)."""

from __future__ import annotations

import subprocess

from support import PYTHON, python_subprocess_env

CHECK = """
import importlib, pkgutil, sys
import taiji2_sim_pkg.core as sim_core, taiji2_estimator_pkg.core as est_core
for pkg in (sim_core, est_core):
    for mod in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):
        importlib.import_module(mod.name)
bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'cyclonedds', 'taiji2_runtime', 'rosbags'))
print(len([m for m in sys.modules if '.core.' in m]), bad)
sys.exit(1 if bad else 0)
"""


def test_numerical_core_imports_without_middleware():
    proc = subprocess.run([PYTHON, "-c", CHECK], env=python_subprocess_env(), capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    modules_loaded = int(proc.stdout.split()[0])
    assert modules_loaded >= 4  # the check really walked the core modules
