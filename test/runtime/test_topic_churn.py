"""Topics of a new context while Cyclone still frees the previous context's endpoints (dds_rclpy.topics).

cyclonedds-python 11.0.1's ``Topic()`` walks the domain's type library without its lock, while
Cyclone's garbage-collector thread frees the types of a participant deleted a moment before: the
process died with a segmentation fault in ``Topic()`` (or ``Topic()`` raised BAD_PARAMETER). The
runtime anchors every topic type for the life of the process, so no type is freed.
"""

from __future__ import annotations

import subprocess

import pytest

from support import PYTHON, python_subprocess_env

pytestmark = pytest.mark.embedded_runtime(reason=(
    "a race inside cyclonedds-python, which the embedded runtime works around; rclpy does not use it"
))

#: contexts each churn process creates and shuts down back to back, and churn processes run at once
#: (competing for the CPUs, they delay each other's Cyclone garbage collector into the next
#: context's Topic() calls). Before the fix, 4 of 6 such runs had a process die (3 by SIGSEGV, 1 by
#: BAD_PARAMETER) on an otherwise idle 2-core machine, 0 of 6 after; a run takes about 9 s there
CHURN_CONTEXTS = 600
CHURN_PROCESSES = 2

CHURN = f"""
import faulthandler
faulthandler.enable()
from taiji2_runtime.ros import rclpy
for _ in range({CHURN_CONTEXTS}):
    ctx = rclpy.context.Context()
    rclpy.init(args=["churn"], context=ctx)
    rclpy.node.Node("churn", context=ctx)  # ros_discovery_info, 12 parameter-service topics, /rosout
    rclpy.try_shutdown(context=ctx)
print("churned")
"""


def test_contexts_created_and_shut_down_back_to_back_never_crash_topic_creation():
    procs = [subprocess.Popen([PYTHON, "-c", CHURN], env=python_subprocess_env(), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(CHURN_PROCESSES)]
    try:
        for proc in procs:
            out, err = proc.communicate(timeout=300)
            assert proc.returncode == 0, f"exit {proc.returncode}:\n{err[-3000:]}"
            assert out.strip() == "churned"
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()


def test_topic_types_stay_anchored_after_their_context_shuts_down():
    from taiji2_runtime.dds_rclpy.service_types import wire_class
    from taiji2_runtime.dds_rclpy.topics import anchored_types
    from taiji2_runtime.ros import rclpy

    ctx = rclpy.context.Context()
    rclpy.init(args=["anchor"], context=ctx)
    rclpy.node.Node("anchored", context=ctx)
    domain_id = ctx.domain_id
    rclpy.try_shutdown(context=ctx)
    anchored = anchored_types(domain_id)
    for srv in ("rcl_interfaces/srv/GetParameters", "rcl_interfaces/srv/SetParameters"):
        for suffix in ("Request", "Response"):
            assert wire_class(srv, suffix) in anchored
