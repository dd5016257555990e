"""Under real rclpy (colcon build, `ros2 run`): the README's ROS 2 section, clean ends, bad input, a mixed graph."""

from __future__ import annotations

import json
import os
import signal
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ALL_EXECUTABLES = {"taiji2_sim_pkg spacecraft_sim", "taiji2_sim_pkg maneuver_commander",
                   "taiji2_sim_pkg telemetry_packetizer", "taiji2_sim_pkg space_link",
                   "taiji2_sim_pkg onboard_executor", "taiji2_sim_pkg uplink_intruder",
                   "taiji2_ground_pkg ground_receiver", "taiji2_ground_pkg command_planner",
                   "taiji2_ground_pkg yamcs_station",
                   "taiji2_estimator_pkg scale_factor_estimator", "taiji2_estimator_pkg com_offset_estimator"}


def _stop(proc) -> tuple[int, str]:
    """SIGINT to the process group; a process still running 60 s later is killed and reported as hung
    (status -9, its stderr so far), so that the test's assertion names it instead of a TimeoutExpired."""
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
        return -9, f"did not end within 60 s of SIGINT (killed); stderr: {err}"
    return proc.returncode, err


def test_colcon_build_installs_every_node(ros):
    out = ros(" && ".join(f"ros2 pkg executables {package}" for package in
                   ("taiji2_sim_pkg", "taiji2_estimator_pkg", "taiji2_ground_pkg")))
    assert out.returncode == 0, out.stderr
    assert set(out.stdout.strip().splitlines()) == ALL_EXECUTABLES


def test_readme_ros2_section_verbatim_with_the_estimators_all_stop_with_exit_0(ros):
    # the README's two commands (the simulator in the background, the commander on simulated time), plus
    # the two estimators, all under `ros2 run`: estimates flow, and every node stops on SIGINT with exit 0
    nodes = {"spacecraft_sim": "ros2 run taiji2_sim_pkg spacecraft_sim",
             "scale_factor_estimator": "ros2 run taiji2_estimator_pkg scale_factor_estimator",
             "com_offset_estimator": "ros2 run taiji2_estimator_pkg com_offset_estimator",
             "maneuver_commander": "ros2 run taiji2_sim_pkg maneuver_commander --ros-args -p use_sim_time:=true "
                                   "-p lookahead_s:=2.0"}
    procs = {name: ros(f"exec {command}", background=True) for name, command in nodes.items()}
    try:  # with the type given, `ros2 topic echo` waits for the topic instead of failing while nodes start
        command = ros("ros2 topic echo --once /taiji2/maneuver/command geometry_msgs/msg/WrenchStamped", timeout=120)
        scale = ros("ros2 topic echo --once /taiji2/estimates/grs1/scale_factors taiji2_msgs/msg/ScaleFactorEstimate",
                    timeout=180)
        offset = ros("ros2 topic echo --once /taiji2/estimates/grs2/com_offset taiji2_msgs/msg/ComOffsetEstimate",
                     timeout=180)
    finally:
        stopped = {name: _stop(proc) for name, proc in procs.items()}
    assert command.returncode == 0 and "torque:" in command.stdout and "frame_id: crf" in command.stdout, command.stderr
    assert scale.returncode == 0 and "scale_factors:" in scale.stdout, scale.stderr
    assert offset.returncode == 0 and "offset:" in offset.stdout, offset.stderr
    for name, (status, err) in stopped.items():
        errors = [line for line in err.splitlines() if line.startswith("error") or "Traceback" in line]
        assert status == 0 and errors == [], (name, status, err[-2000:])


def test_spacecraft_sim_runs_to_its_end_with_exit_0(ros):
    out = ros("ros2 run taiji2_sim_pkg spacecraft_sim --ros-args -p duration_s:=30.0 -p sync_with_command:=false "
              "-p seed:=4", timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "done: 300 steps" in out.stderr and "Traceback" not in out.stderr


def test_bad_input_is_one_error_line_and_exit_2(ros):
    for args in ("-p clock_mode:=warp", "-p seed:=abc", "-r ::bad"):
        out = ros(f"ros2 run taiji2_sim_pkg spacecraft_sim --ros-args {args}", timeout=120)
        errors = [line for line in out.stderr.splitlines() if line.startswith("error:")]
        assert out.returncode == 2 and len(errors) == 1 and "Traceback" not in out.stderr, (args, out.stderr)


def test_embedded_runtime_node_reaches_ros2_cli_and_back(ros):
    # embedded-runtime commander (Cyclone DDS directly) -> the real ROS 2 CLI
    embedded = ros("exec python3 -m taiji2_apps.cli.main run taiji2_sim_pkg maneuver_commander",
                   env={"TAIJI2_RUNTIME": "cyclonedds"}, background=True)
    try:
        # the type is given: the embedded node may still be starting when the echo looks for the topic
        echo = ros("ros2 topic echo --once /taiji2/maneuver/command geometry_msgs/msg/WrenchStamped", timeout=120)
    finally:
        status, err = _stop(embedded)
    assert echo.returncode == 0 and "torque:" in echo.stdout, echo.stderr
    assert status == 0, err
    # rclpy commander -> the embedded runtime's `taiji2 topic echo`
    real = ros("exec ros2 run taiji2_sim_pkg maneuver_commander", background=True)
    try:
        echo = ros("python3 -m taiji2_apps.cli.main topic echo /taiji2/maneuver/command --once", timeout=120,
                   env={"TAIJI2_RUNTIME": "cyclonedds"})
    finally:
        status, err = _stop(real)
    assert echo.returncode == 0 and "torque" in echo.stdout, echo.stderr
    assert status == 0, err


def test_embedded_endpoints_carry_rosidls_type_hash(ros):

    from taiji2_runtime.interfaces import type_hash_of

    # our message types: the hash rosidl generates in a colcon build of this workspace
    for name in ("GrsVoltages", "StarTracker", "ScaleFactorEstimate", "ComOffsetEstimate", "SpacePackets"):
        out = ros(f"cat $(ros2 pkg prefix taiji2_msgs)/share/taiji2_msgs/msg/{name}.json")
        assert out.returncode == 0, out.stderr
        generated = json.loads(out.stdout)["type_hashes"][0]
        assert generated["hash_string"] == type_hash_of(f"taiji2_msgs/msg/{name}"), name
    # an embedded endpoint as the ROS 2 CLI sees it: the hash parsed from USER_DATA, no rmw warning
    embedded = ros("exec python3 -m taiji2_apps.cli.main run taiji2_sim_pkg maneuver_commander",
                   env={"TAIJI2_RUNTIME": "cyclonedds"}, background=True)
    try:
        info = ros("ros2 topic echo --once /taiji2/maneuver/command geometry_msgs/msg/WrenchStamped >/dev/null && "
                   "ros2 topic info -v /taiji2/maneuver/command", timeout=120)
    finally:
        _stop(embedded)
    assert info.returncode == 0, info.stderr
    assert f"Topic type hash: {type_hash_of('geometry_msgs/msg/WrenchStamped')}" in info.stdout, info.stdout
    assert "Failed to parse type hash for topic '/taiji2/maneuver/command'" not in info.stderr, info.stderr


def _rmw_warnings(text: str) -> list[str]:
    """Lines in which rmw or rcl complain (a mixed graph must produce none, in either direction)."""
    return [line for line in text.splitlines() if "WARN" in line or "Failed to parse" in line]


def test_ros2_cli_sees_embedded_node_its_parameters_and_topics(ros):
    embedded = ros("exec python3 -m taiji2_apps.cli.main run taiji2_sim_pkg maneuver_commander "
                   "--ros-args -p period_s:=250.0", env={"TAIJI2_RUNTIME": "cyclonedds"}, background=True)
    try:
        # discovery is asynchronous: ask until the node is listed (bounded: 30 tries of a 1-s listing)
        listed = ros("for i in $(seq 30); do ros2 node list --no-daemon | grep -qx /maneuver_commander && break; done;"
                     " ros2 node list --no-daemon", timeout=180)
        info = ros("ros2 node info --no-daemon /maneuver_commander && "
                   "ros2 topic info -v --no-daemon /taiji2/maneuver/command && "
                   "ros2 param get --no-daemon /maneuver_commander period_s && "
                   "ros2 param set --no-daemon /maneuver_commander lookahead_s 2.5 && "
                   "ros2 param get --no-daemon /maneuver_commander lookahead_s && "
                   "ros2 param set --no-daemon /maneuver_commander period_s 100.0; "
                   "ros2 param set --no-daemon /maneuver_commander lookahead_s -1.0; "
                   "ros2 param dump --no-daemon /maneuver_commander", timeout=180)
    finally:
        status, err = _stop(embedded)
    assert "/maneuver_commander" in listed.stdout.splitlines(), listed.stderr
    assert info.returncode == 0, info.stderr
    out = info.stdout
    assert "/taiji2/maneuver/command: geometry_msgs/msg/WrenchStamped" in out  # node info: its publisher
    assert "/maneuver_commander/get_parameters: rcl_interfaces/srv/GetParameters" in out
    assert "Node name: maneuver_commander" in out  # topic info -v: the endpoint belongs to the node
    assert "Double value is: 250.0" in out and "Set parameter successful" in out and "Double value is: 2.5" in out
    # read-only (read at start) and a refused value: ros2 param set says why (issue 26 row 2)
    assert "Setting parameter failed: Trying to set a read-only parameter: period_s." in info.stderr, info.stderr
    assert "Setting parameter failed: lookahead_s: -1.0 is outside [0.0, 3600.0] [s]" in info.stderr, info.stderr
    assert "period_s: 250.0" in out and "lookahead_s: 2.5" in out  # dump
    assert _rmw_warnings(listed.stderr + info.stderr) == []
    assert status == 0, err


def test_embedded_tools_see_rclpy_node_and_its_parameters(ros):
    real = ros("exec ros2 run taiji2_sim_pkg maneuver_commander --ros-args -p period_s:=250.0", background=True)
    taiji2 = "python3 -m taiji2_apps.cli.main"
    try:
        # with ros2cli's daemon (a hidden node, /_ros2cli_daemon_...) in the graph, as on a ROS 2 machine
        listed = ros(f"ros2 daemon start >/dev/null; "
                     f"for i in $(seq 30); do {taiji2} node list -a | grep -q '^/_ros2cli_daemon' && "
                     f"{taiji2} node list | grep -qx /maneuver_commander && break; done; "
                     f"{taiji2} node list; echo ---; {taiji2} node list -a; ros2 daemon stop >/dev/null",
                     env={"TAIJI2_RUNTIME": "cyclonedds"}, timeout=180)
        params = ros(f"{taiji2} param get /maneuver_commander period_s && "
                     f"{taiji2} param set /maneuver_commander lookahead_s 2.5 && "
                     f"{taiji2} param get /maneuver_commander lookahead_s && "
                     f"({taiji2} param set /maneuver_commander period_s 100.0 || "
                     f"{taiji2} param set /maneuver_commander lookahead_s -1.0 || true)",
                     env={"TAIJI2_RUNTIME": "cyclonedds"}, timeout=120)
    finally:
        status, err = _stop(real)
    plain, everything = listed.stdout.split("---\n")
    assert "/maneuver_commander" in plain.splitlines(), listed.stderr
    # hidden nodes as ros2 node list hides them (issue 26 row 10); -a shows them
    assert not any(n.startswith("/_") for n in plain.splitlines()), plain
    assert any(n.startswith("/_ros2cli_daemon") for n in everything.splitlines()), everything
    assert params.returncode == 0, params.stderr
    assert params.stdout.splitlines() == ["Double value is: 250.0", "Set parameter successful",
                                          "Double value is: 2.5"]
    # rclpy's own refusal of a read-only parameter, then the node's check with its start-up message
    assert "Trying to set a read-only parameter: period_s." in params.stderr, params.stderr
    assert "lookahead_s: -1.0 is outside [0.0, 3600.0] [s]" in params.stderr, params.stderr
    assert status == 0, err
    assert _rmw_warnings(err) == [], err  # the rclpy node had nothing to say about our endpoints


def test_type_hashes_equal_rosidls_for_every_installed_message_and_parameter_service(ros):
    import glob

    from taiji2_runtime.dds_rclpy.service_types import SERVICE_DEFINITIONS, service_type_hash
    from taiji2_runtime.typestore import rihs01

    prefix = ros("echo $AMENT_PREFIX_PATH").stdout.strip().split(":")
    generated: dict[str, str] = {}
    for root in prefix:
        for path in glob.glob(f"{root}/share/*/msg/*.json") + glob.glob(f"{root}/share/rcl_interfaces/srv/*.json"):
            with open(path, encoding="utf-8") as f:
                for entry in json.load(f)["type_hashes"]:
                    generated.setdefault(entry["type_name"], entry["hash_string"])
    ours: dict[str, str] = {}
    for name in generated:
        if name.split("/")[1] == "msg":
            try:
                ours[name] = rihs01(name)
            except KeyError:
                continue  # a type rosbags does not know (nothing of ours sends it)
    for srv in SERVICE_DEFINITIONS:
        for suffix in ("Request", "Response"):
            ours[f"{srv}_{suffix}"] = service_type_hash(srv, suffix)
    assert len(ours) > 100
    assert {n: h for n, h in ours.items() if generated[n] != h} == {}


def test_every_taiji2_message_type_crosses_between_rclpy_and_embedded_both_ways(ros):
    # each configuration is a round trip: the driver's messages are decoded by the other runtime and
    # encoded again by it, so both directions of every type are checked field by field
    peer = f"python3 {REPO / 'test' / 'rclpy' / 'interop_peer.py'}"
    embedded = {"TAIJI2_RUNTIME": "cyclonedds"}
    for echo_env, drive_env in ((None, embedded), (embedded, None)):
        echo = ros(f"exec {peer} echo", env=echo_env, background=True)
        try:
            drive = ros(f"{peer} drive", env=drive_env, timeout=120)
        finally:
            status, err = _stop(echo)
        lines = [json.loads(line) for line in drive.stdout.splitlines() if line.startswith("{")]
        assert [line["type"] for line in lines] == ["GrsVoltages", "StarTracker", "ScaleFactorEstimate",
                                                    "ComOffsetEstimate", "SpacePackets"], drive.stderr
        for line in lines:
            assert line["received"] == line["sent"], (echo_env, line)
        assert drive.returncode == 0 and status == 0, (drive.stderr, err)
        assert _rmw_warnings(drive.stderr + err) == [], drive.stderr + err


def test_node_suite_passes_under_real_rclpy(ros):
    # the node tests again, now with rclpy and the colcon-built messages: every node's rclpy API (parameters,
    # QoS, executors, timers, checkpoints, diagnostics), the graphs and the link nodes; tests of the embedded
    # runtime's own internals skip themselves with their reason (test/conftest.py). Left out for CI time (the CI
    # took 21-24 min against its 20-min limit with them): test/runtime (mostly the embedded runtime itself, which
    # rclpy replaces) and the node tests that run whole `taiji2 experiment`s or maneuver choices, whose node
    # behaviour the tests below already cover under rclpy: test_replay (69 s), test_experiment_cli (20 s; the
    # README's ROS 2 section runs the graph with ros2 run below), test_default_maneuver (17 s),
    # test_live_vs_offline_parts (7 s), test_load_independence (9 s). Run alone (not beside the CLI tests): its
    # graphs and the ros2 CLI calls each bound their waits in wall time
    chosen = " ".join(f"test/nodes/{name}.py" for name in (
        "test_epochs", "test_estimate_qos", "test_estimator_nodes", "test_gridding_rule", "test_link_commanding",
        "test_link_nodes", "test_link_start_hold", "test_live_vs_offline", "test_node_parameters",
        "test_onboard_security", "test_sim_graph"))
    out = ros(f"cd {REPO} && TAIJI2_RUNTIME=rclpy python3 -m pytest -q -p no:cacheprovider -rs {chosen}", timeout=900)
    assert out.returncode == 0, out.stdout[-6000:] + out.stderr[-2000:]
