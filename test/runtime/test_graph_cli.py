"""``taiji2 node list`` and ``taiji2 param list|get|set`` against a running embedded node (no ROS 2)."""

from __future__ import annotations

import signal
import subprocess
import time

from support import PYTHON, python_subprocess_env, run_taiji2

NODE = "/graph_cli_probe"


def _taiji2(*args: str) -> subprocess.CompletedProcess:
    return run_taiji2(*args, timeout=60)


def test_node_list_and_param_get_set_reach_an_embedded_node():
    node = subprocess.Popen([PYTHON, "-m", "taiji2_apps.cli.main", "run", "taiji2_sim_pkg", "maneuver_commander",
                             "--ros-args", "-r", f"__node:={NODE[1:]}", "-p", "publish_rate_hz:=20.0"],
                            env=python_subprocess_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        listed = _taiji2("node", "list")
        while NODE not in listed.stdout.splitlines() and time.monotonic() < deadline:
            listed = _taiji2("node", "list")  # each call listens for discovery itself
        assert NODE in listed.stdout.splitlines(), (listed.stdout, listed.stderr)

        names = _taiji2("param", "list", NODE)
        assert {"  publish_rate_hz", "  period_s", "  use_sim_time"} <= set(names.stdout.splitlines()), names.stderr
        got = _taiji2("param", "get", NODE, "publish_rate_hz")
        assert got.stdout.strip() == "Double value is: 20.0", got.stderr

        # lookahead_s can change at run time (checked, applied); period_s is read at start: read-only
        assert _taiji2("param", "set", NODE, "lookahead_s", "2.5").stdout.strip() == "Set parameter successful"
        assert _taiji2("param", "get", NODE, "lookahead_s").stdout.strip() == "Double value is: 2.5"
        for name, value, why in (("lookahead_s", "fast", "lookahead_s"), ("lookahead_s", "-1.0", "outside"),
                                 ("period_s", "100.0", "Trying to set a read-only parameter: period_s.")):
            refused = _taiji2("param", "set", NODE, name, value)
            errors = [line for line in refused.stderr.splitlines() if line.startswith("error:")]
            assert refused.returncode == 1 and len(errors) == 1 and why in errors[0], refused.stderr
        assert _taiji2("param", "get", NODE, "lookahead_s").stdout.strip() == "Double value is: 2.5"
        assert _taiji2("param", "get", NODE, "period_s").stdout.strip() != "Double value is: 100.0"

        absent = _taiji2("param", "get", "/no_such_node", "x", "--timeout", "0.5")
        assert absent.returncode == 2 and "/no_such_node" in absent.stderr
        assert node.poll() is None  # the node kept running through all of it
    finally:
        node.send_signal(signal.SIGTERM)
        node.wait(timeout=10)


def test_node_list_hides_hidden_nodes_as_ros2_node_list_does(context):
    # a name starting with "_" (ros2cli's daemon is /_ros2cli_daemon_...): listed only with -a (issue 26 row 10)
    from taiji2_runtime.ros import rclpy

    nodes = [rclpy.node.Node(name, context=context) for name in ("visible_probe", "_hidden_probe")]
    deadline = time.monotonic() + 30
    listed = _taiji2("node", "list", "-a")
    while "/_hidden_probe" not in listed.stdout.splitlines() and time.monotonic() < deadline:
        listed = _taiji2("node", "list", "-a")
    assert {"/visible_probe", "/_hidden_probe"} <= set(listed.stdout.splitlines()), listed.stderr
    plain = _taiji2("node", "list").stdout.splitlines()
    assert "/visible_probe" in plain and not any(n.rsplit("/", 1)[-1].startswith("_") for n in plain), plain
    for node in nodes:
        node.destroy_node()
