"""Record from and play into the live graph: round trip, timing, /clock, unknown types (in-process)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from taiji2_runtime.bag.bulk_decode import encode_messages
from taiji2_runtime.bag.player import Player, PlayOptions
from taiji2_runtime.bag.recorder import Recorder, RecordOptions
from taiji2_runtime.bag.writer import BagWriter
from taiji2_runtime.interfaces import typestore
from taiji2_runtime.ros import messages, rclpy

ST, GRS, CMD, STR = ("taiji2_msgs/msg/StarTracker", "taiji2_msgs/msg/GrsVoltages",
                     "geometry_msgs/msg/WrenchStamped", "std_msgs/msg/String")


def _reliable_all():
    q = rclpy.qos
    return q.QoSProfile(history=q.HistoryPolicy.KEEP_ALL, reliability=q.ReliabilityPolicy.RELIABLE)


def _spin(executor, predicate, timeout_s=10.0, tick=None):
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
        if tick is not None:
            tick()
    return predicate()


def _messages(n):
    m = messages
    out = {"/bagtest/st": [], "/bagtest/grs": [], "/bagtest/cmd": []}
    for k in range(n):
        st = m.taiji2_msgs.StarTracker()
        st.header.stamp.sec, st.header.stamp.nanosec, st.header.frame_id = k, 7 * k, "crf"
        st.attitude.x, st.attitude.w = 0.001 * k, 1.0
        st.attitude_covariance = [1e-12 * (k + i) for i in range(9)]
        out["/bagtest/st"].append(st)
        grs = m.taiji2_msgs.GrsVoltages(grs_id=1)
        grs.header.stamp.sec, grs.header.frame_id = k, "tmrf1"
        grs.vx1, grs.vz2 = 1e-3 * k, -1e-3 * k
        out["/bagtest/grs"].append(grs)
        if k % 5 == 0:
            cmd = m.geometry_msgs.WrenchStamped()
            cmd.header.stamp.sec, cmd.header.frame_id = k, "crf"
            cmd.wrench.torque.z = 1e-4 * k
            out["/bagtest/cmd"].append(cmd)
    return out


def test_record_then_play_round_trip_is_byte_exact(tmp_path, context, executor):
    publisher_node = rclpy.node.Node("bagtest_source", context=context)
    recorder_node = rclpy.node.Node("bagtest_recorder", context=context)
    types = {"/bagtest/st": messages.taiji2_msgs.StarTracker, "/bagtest/grs": messages.taiji2_msgs.GrsVoltages,
             "/bagtest/cmd": messages.geometry_msgs.WrenchStamped}
    publishers = {t: publisher_node.create_publisher(cls, t, _reliable_all()) for t, cls in types.items()}
    latched_qos = rclpy.qos.QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
    latched = publisher_node.create_publisher(messages.std_msgs.String, "/bagtest/latched", latched_qos)
    latched.publish(messages.std_msgs.String(data="published before the recorder started"))
    for node in (publisher_node, recorder_node):
        executor.add_node(node)
    logs: list[str] = []
    recorder = Recorder(recorder_node, RecordOptions(output=tmp_path / "bag", regex=r"^/bagtest/",
                                                     journal_period_s=0.1, discovery_period_s=0.1), log=logs.append)
    assert _spin(executor, lambda: all(p.get_subscription_count() for p in [*publishers.values(), latched]),
                 tick=recorder.tick), logs
    sent = _messages(60)
    for topic, items in sent.items():
        for msg in items:
            publishers[topic].publish(msg)
    total = sum(len(v) for v in sent.values()) + 1
    assert _spin(executor, lambda: recorder.message_count >= total, tick=recorder.tick), recorder.message_count
    report = recorder.close()
    assert report.counts == {"/bagtest/st": 60, "/bagtest/grs": 60, "/bagtest/cmd": 12, "/bagtest/latched": 1}
    assert report.types["/bagtest/st"] == ST and report.types["/bagtest/latched"] == STR

    recorded: dict[str, list[bytes]] = {}
    stamps = []
    with Reader(tmp_path / "bag") as reader:
        for connection, stamp, data in reader.messages():
            recorded.setdefault(connection.topic, []).append(data)
            stamps.append(stamp)
    for topic, items in sent.items():
        assert recorded[topic] == [m.serialize() for m in items], topic
    # stored as received: a length not a multiple of 4 comes padded with zeros, as rmw delivers it
    latched_bytes = messages.std_msgs.String(data="published before the recorder started").serialize()
    assert recorded["/bagtest/latched"] == [latched_bytes + bytes(-len(latched_bytes) % 4)]
    assert typestore().deserialize_cdr(recorded["/bagtest/latched"][0], STR).data == \
        "published before the recorder started"
    assert abs(stamps[-1] - time.time_ns()) < 60e9, "receive stamps are system time"

    # play everything back, remapped, as fast as the subscribers take it
    player_node = rclpy.node.Node("bagtest_player", context=context)
    sink_node = rclpy.node.Node("bagtest_sink", context=context)
    received: dict[str, list[bytes]] = {}
    for topic, cls in [*types.items(), ("/bagtest/latched", messages.std_msgs.String)]:
        target = topic.replace("/bagtest/", "/replay/")
        qos = _reliable_all() if topic != "/bagtest/latched" else rclpy.qos.QoSProfile(
            depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        sink_node.create_subscription(cls, target, lambda data, t=topic: received.setdefault(t, []).append(
            bytes(data)), qos, raw=True)
    remap = {t: t.replace("/bagtest/", "/replay/") for t in recorded}
    player = Player(player_node, PlayOptions(bag=tmp_path / "bag", fast=True, remap=remap, wait_for_subscribers=1),
                    log=logs.append)
    result = player.run()
    assert result.published == report.counts and not result.unacknowledged and not result.skipped
    executor.add_node(sink_node)
    assert _spin(executor, lambda: sum(map(len, received.values())) >= total)
    assert received == recorded


def _timed_bag(path, count=101, step_ns=10_000_000):
    store = typestore()
    writer = BagWriter(path, store)
    handle = writer.add_topic("/timed", GRS)
    t0 = 5_000_000_000
    for k in range(count):
        writer.write(handle, t0 + k * step_ns, encode_messages(store, GRS, {"header.stamp.sec": k, "grs_id": 1,
                                                                            "header.frame_id": "tmrf1"}, 1)[0])
    writer.close()
    return t0, t0 + (count - 1) * step_ns


def test_play_keeps_timing_scaled_by_rate_and_publishes_clock(tmp_path, context, executor):
    t0, t1 = _timed_bag(tmp_path / "bag")  # 1 s of bag time
    sink = rclpy.node.Node("bagtest_timed_sink", context=context)
    arrivals, clocks = [], []
    sink.create_subscription(messages.taiji2_msgs.GrsVoltages, "/timed", lambda m: arrivals.append(time.monotonic()),
                             _reliable_all())
    sink.create_subscription(messages.rosgraph_msgs.Clock, "/clock",
                             lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), _reliable_all())
    executor.add_node(sink)
    player = Player(rclpy.node.Node("bagtest_timed_player", context=context),
                    PlayOptions(bag=tmp_path / "bag", rate=2.0, clock_hz=50.0, wait_for_subscribers=1))
    import threading

    thread = threading.Thread(target=player.run)
    thread.start()
    assert _spin(executor, lambda: len(arrivals) >= 101 and not thread.is_alive(), timeout_s=10)
    thread.join()
    span = arrivals[-1] - arrivals[0]
    # paced by the bag's stamps at rate 2: never faster than 0.5 s (minus the receive jitter); how much slower
    # a busy machine makes it is not the player's timing but the machine's (no upper bound in wall time here)
    assert span > 0.4, f"1 s of bag time at rate 2 took {span:.3f} s: played ahead of its stamps"
    assert clocks == sorted(clocks) and clocks[0] >= t0 and clocks[-1] <= t1
    assert clocks[-1] - clocks[0] > 0.8e9 and len(clocks) >= 20


def test_unknown_type_with_embedded_definition_is_played_and_one_without_is_skipped(tmp_path, context, executor):
    store = get_typestore(Stores.ROS2_HUMBLE)
    definition = "float64 reading  # [V]\nstring label\nuint16[3] flags\n"
    store.register(get_types_from_msg(definition, "groundseg_msgs/msg/Probe"))
    probe_cls = store.types["groundseg_msgs/msg/Probe"]
    with Writer(tmp_path / "bag", version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        known = writer.add_connection("/probe", "groundseg_msgs/msg/Probe", typestore=store)
        blind = writer.add_connection("/blind", "blind_msgs/msg/Thing", msgdef="", rihs01="RIHS01_" + "0" * 64)
        for k in range(5):
            msg = probe_cls(reading=0.5 * k, label=f"p{k}", flags=np.array([k, 2, 3], dtype=np.uint16))
            writer.write(known, 1000 + k, store.serialize_cdr(msg, "groundseg_msgs/msg/Probe"))
            writer.write(blind, 1000 + k, b"\x00\x01\x00\x00")
    logs: list[str] = []
    player = Player(rclpy.node.Node("bagtest_unknown_player", context=context),
                    PlayOptions(bag=tmp_path / "bag", fast=True, wait_for_subscribers=1), log=logs.append)
    assert set(player.skipped) == {"/blind"} and "no definition" in player.skipped["/blind"]
    got = []
    sink = rclpy.node.Node("bagtest_unknown_sink", context=context)
    sink.create_subscription(messages.groundseg_msgs.Probe, "/probe", lambda m: got.append((m.reading, m.label)),
                             _reliable_all())
    result = player.run()
    executor.add_node(sink)
    assert _spin(executor, lambda: len(got) == 5)
    assert got == [(0.5 * k, f"p{k}") for k in range(5)] and result.published == {"/probe": 5}


def test_player_and_recorder_reject_bad_options(tmp_path, context):
    node = rclpy.node.Node("bagtest_options", context=context)
    with pytest.raises(ValueError, match="nothing to record"):
        Recorder(node, RecordOptions(output=tmp_path / "x"))
    _timed_bag(tmp_path / "bag", count=3)
    with pytest.raises(ValueError, match="rate"):
        Player(node, PlayOptions(bag=tmp_path / "bag", rate=0.0))
    with pytest.raises(ValueError, match="no topic /nope"):
        Player(node, PlayOptions(bag=tmp_path / "bag", topics=["/nope"]))
    player = Player(node, PlayOptions(bag=tmp_path / "bag", fast=True, wait_for_subscribers=1, wait_timeout_s=0.3))
    with pytest.raises(RuntimeError, match="subscriber"):
        player.run()


def test_loop_repeats_until_stopped(tmp_path, context):
    _timed_bag(tmp_path / "bag", count=20, step_ns=1_000_000)
    sink = rclpy.node.Node("bagtest_loop_sink", context=context)
    sink.create_subscription(messages.taiji2_msgs.GrsVoltages, "/timed", lambda m: None, _reliable_all())
    player = Player(rclpy.node.Node("bagtest_loop_player", context=context),
                    PlayOptions(bag=tmp_path / "bag", fast=True, loop=True, wait_for_subscribers=1))
    report = player.run(stop=lambda: player.published_count >= 60)
    assert report.loops == 3 and report.published == {"/timed": 60}
    assert abs(report.bag_span_s - 3 * 0.019) < 1e-9


def test_max_duration_stops_the_recorder(tmp_path, context, executor):
    source = rclpy.node.Node("bagtest_duration_source", context=context)
    publisher = source.create_publisher(messages.std_msgs.String, "/bagtest/ticks", _reliable_all())
    node = rclpy.node.Node("bagtest_duration_recorder", context=context)
    executor.add_node(node)
    recorder = Recorder(node, RecordOptions(output=tmp_path / "bag", topics=["/bagtest/ticks"], max_duration_s=0.3,
                                            discovery_period_s=0.05), log=lambda _text: None)
    assert _spin(executor, lambda: publisher.get_subscription_count() > 0, tick=recorder.tick)
    start = time.monotonic()
    # the limit is wall time by definition (as `ros2 bag record --max-duration`): it must not stop before
    # it; how late after it the recorder notices depends on the machine's load, so only a generous cap
    while not recorder.stopped and time.monotonic() - start < 60:
        publisher.publish(messages.std_msgs.String(data="tick"))
        executor.spin_once(timeout_sec=0.01)
        recorder.tick()
    assert recorder.stopped and time.monotonic() - start > 0.3
    assert recorder.close().counts["/bagtest/ticks"] > 5
