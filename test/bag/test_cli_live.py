"""``taiji2 bag`` as a user runs it, in subprocesses: SIGKILL crash safety, a simulated experiment
recorded with provenance, decoded by an independent decoder, and played back into a recorder."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from taiji2_runtime.interfaces import typestore

from support import PYTHON, REPO, python_subprocess_env

try:
    from taiji2_estimator_pkg.io import load_raw_bag
except ImportError:  # an editable install made before the package had modules
    sys.path.insert(0, str(REPO / "src" / "taiji2_estimator_pkg"))
    from taiji2_estimator_pkg.io import load_raw_bag

RAW = ["/taiji2/star_tracker", "/taiji2/grs1/voltages", "/taiji2/grs2/voltages", "/taiji2/maneuver/command"]

PUBLISHER = textwrap.dedent("""
    import time
    from taiji2_runtime.ros import rclpy, messages
    rclpy.init(args=["pub"])
    node = rclpy.create_node("bagtest_crash_source")
    q = rclpy.qos
    qos = q.QoSProfile(history=q.HistoryPolicy.KEEP_ALL, reliability=q.ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(messages.taiji2_msgs.StarTracker, "/crash/st", qos)
    k, start = 0, time.monotonic()
    while rclpy.ok() and time.monotonic() - start < 60:
        msg = messages.taiji2_msgs.StarTracker()
        msg.header.stamp.sec, msg.header.frame_id = k, "crf"
        pub.publish(msg)
        k += 1
        time.sleep(0.005)
""")


def _env():
    env = python_subprocess_env()
    env["ROS_DOMAIN_ID"] = os.environ["ROS_DOMAIN_ID"]
    env["TAIJI2_RUNTIME"] = os.environ.get("TAIJI2_RUNTIME", "cyclonedds")
    return env


def _taiji2(*args):
    return [PYTHON, "-m", "taiji2_apps.cli.main", *args]


def _listed_messages(bag: Path) -> int:
    try:
        info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, TypeError, KeyError, yaml.YAMLError):
        return 0
    return int(info["message_count"])


def _wait(predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def _stop(process, sig=signal.SIGINT, timeout_s=20):
    if process.poll() is None:
        process.send_signal(sig)
    try:
        return process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        raise


def _mcap_decoded(bag: Path) -> list[tuple[str, int, object]]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    out = []
    for name in info["relative_file_paths"]:
        with open(bag / name, "rb") as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
                out.append((channel.topic, message.log_time, decoded))
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_sigkill_loses_at_most_the_last_second(tmp_path, storage):
    bag = tmp_path / "bag"
    source = subprocess.Popen([PYTHON, "-c", PUBLISHER], env=_env(), stderr=subprocess.PIPE, text=True)
    recorder = subprocess.Popen(_taiji2("bag", "record", "/crash/st", "-o", str(bag), "-s", storage),
                                env=_env(), stderr=subprocess.PIPE, text=True)
    try:
        _wait(lambda: _listed_messages(bag) > 50, 20, "the first closed journal")
        time.sleep(1.5)
        killed_ns = time.time_ns()
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=10)
    finally:
        _stop(source, signal.SIGTERM)
        if recorder.poll() is None:
            recorder.kill()
    with Reader(bag) as reader:
        stamps, counters = [], []
        store = typestore()
        for connection, stamp, data in reader.messages():
            stamps.append(stamp)
            counters.append(store.deserialize_cdr(data, connection.msgtype).header.stamp.sec)
    assert counters == list(range(counters[0], counters[0] + len(counters))), "no message lost in between"
    assert killed_ns - stamps[-1] < 1.0e9, f"lost the last {(killed_ns - stamps[-1]) / 1e9:.2f} s"
    if storage == "mcap":
        assert [d.header.stamp.sec for _, _, d in _mcap_decoded(bag)] == counters


@pytest.mark.slow
def test_simulated_experiment_record_info_decode_and_replay(tmp_path):
    bag, replayed = tmp_path / "experiment", tmp_path / "replayed"
    env = _env()
    recorder = subprocess.Popen(_taiji2("bag", "record", "-a", "--use-sim-time", "-o", str(bag), "--custom-data",
                                        "mission.pass=42", "mission.note=a=b"), env=env,
                                stderr=subprocess.PIPE, text=True)
    sim = commander = None
    try:
        sim = subprocess.Popen(_taiji2("run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args", "-p",
                                       "duration_s:=20.0", "-p", "seed:=1", "-p", "wait_for_subscribers:=[1, 1, 1]"),
                               env=env, stderr=subprocess.PIPE, text=True)
        commander = subprocess.Popen(_taiji2("run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p",
                                             "use_sim_time:=true", "-p", "lookahead_s:=2.0"), env=env,
                                     stderr=subprocess.PIPE, text=True)
        assert sim.wait(timeout=90) == 0, sim.stderr.read()
        _stop(commander)
        time.sleep(0.5)
    finally:
        for process in (sim, commander):
            if process is not None and process.poll() is None:
                process.kill()
        code = _stop(recorder)
    assert code == 0, recorder.stderr.read()

    info = subprocess.run(_taiji2("bag", "info", str(bag), "--json"), capture_output=True, text=True, env=env,
                          timeout=60)
    assert info.returncode == 0, info.stderr
    summary = json.loads(info.stdout)
    counts = {t["topic"]: t["count"] for t in summary["topics"]}
    assert counts["/taiji2/star_tracker"] == counts["/taiji2/grs1/voltages"] == 200
    assert summary["custom_data"]["taiji2.sim.seed"] == "1"
    assert summary["custom_data"]["taiji2.sim.provenance"]["config"]["layout"] == "type1"
    assert "bag record -a" in summary["custom_data"]["taiji2.recorder.command_line"]
    # --custom-data, as ros2 bag record's: stored verbatim (the first '=' splits)
    assert summary["custom_data"]["mission.pass"] == "42" and summary["custom_data"]["mission.note"] == "a=b"
    exp = load_raw_bag(bag)
    assert len(exp.star_tracker) == 200 and exp.star_tracker.stamp_ns[-1] == 20 * 10**9
    assert all(not r.dropped for r in exp.report.values()), exp.report_lines()
    # sim-time receive stamps: within the simulated 20 s, never system time
    assert exp.star_tracker.receive_ns.max() <= 21 * 10**9

    # every message decodes with the independent decoder, with the values rosbags sees
    store = typestore()
    independent = _mcap_decoded(bag)
    with Reader(bag) as reader:
        reference = [(c.topic, t, store.deserialize_cdr(d, c.msgtype)) for c, t, d in reader.messages()]
    assert len(independent) == len(reference) == summary["message_count"]
    assert _canonical(independent) == _canonical(reference)

    # play the raw topics back, as fast as a recorder takes them, and record them again
    second = subprocess.Popen(_taiji2("bag", "record", *RAW, "-o", str(replayed)), env=env,
                              stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(1.0)
        play = subprocess.run(_taiji2("bag", "play", str(bag), "--fast", "--topics", *RAW,
                                      "--wait-for-subscribers", "1"), capture_output=True, text=True, env=env,
                              timeout=120)
        assert play.returncode == 0, play.stderr
    finally:
        assert _stop(second) == 0, second.stderr.read()
    with Reader(bag) as a, Reader(replayed) as b:
        first = sorted((c.topic, d) for c, _, d in a.messages() if c.topic in RAW)
        again = sorted((c.topic, d) for c, _, d in b.messages())
    assert first == again


def _plain(value):
    """Field values of a message from either decoder as nested tuples (floats as repr, bit-exact)."""
    if hasattr(value, "__slots__") and not isinstance(value, str | bytes):
        return tuple((name, _plain(getattr(value, name))) for name in value.__slots__)
    if dataclasses.is_dataclass(value):  # rosbags: fields of the definition (constants are fields too)
        names = [name for name, _ in typestore().fielddefs[value.__msgtype__][1]]
        return tuple((name, _plain(getattr(value, name))) for name in names)
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return tuple(_plain(v) for v in value)
    return repr(value)


def _canonical(decoded):
    return sorted((topic, stamp, _plain(msg)) for topic, stamp, msg in decoded)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ground_segment_bag_is_played_by_the_cli(tmp_path, storage, context, executor):
    from test_raw_bag import write_ground_segment_bag

    from taiji2_runtime.ros import messages, rclpy

    data = write_ground_segment_bag(tmp_path / "bag", storage)
    node = rclpy.node.Node("bagtest_ground_sink", context=context)
    q = rclpy.qos
    qos = q.QoSProfile(history=q.HistoryPolicy.KEEP_ALL, reliability=q.ReliabilityPolicy.RELIABLE)
    got = {topic: [] for topic in RAW}
    kinds = [messages.taiji2_msgs.StarTracker, messages.taiji2_msgs.GrsVoltages, messages.taiji2_msgs.GrsVoltages,
             messages.geometry_msgs.WrenchStamped]
    for topic, cls in zip(RAW, kinds, strict=True):
        node.create_subscription(cls, topic, lambda msg, t=topic: got[t].append(msg), qos)
    executor.add_node(node)
    play = subprocess.Popen(_taiji2("bag", "play", str(tmp_path / "bag"), "--fast", "--wait-for-subscribers", "1"),
                            env=_env(), stderr=subprocess.PIPE, text=True)
    n = len(data["stamps"])
    deadline = time.monotonic() + 60
    while sum(map(len, got.values())) < 3 * n + n // 10 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    _, err = play.communicate(timeout=60)
    assert play.returncode == 0, err
    assert [len(got[t]) for t in RAW] == [n, n, n, n // 10], err
    assert [m.attitude.w for m in got["/taiji2/star_tracker"]] == data["quat"][:, 3].tolist()
    assert [m.vz2 for m in got["/taiji2/grs2/voltages"]] == data["volts"][1, :, 5].tolist()
    assert {m.header.frame_id for m in got["/taiji2/grs1/voltages"]} == {"tmrf1"}
