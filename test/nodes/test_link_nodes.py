"""The link nodes on DDS: telemetry_packetizer -> space_link -> ground_receiver equal the plain link model,
and the ground's contract topics come out in stamp order, each sample once, with the link's losses as gaps."""

from __future__ import annotations

import itertools
import json
import time

import numpy as np

from taiji2_ground_pkg.nodes import ground_receiver
from taiji2_ground_pkg.nodes.ground_receiver import GroundReceiver
from taiji2_runtime.packets.definition import STREAMS
from taiji2_runtime.packets.packetize import encode_packet
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.link import Downlink, load_link_model
from taiji2_sim_pkg.nodes.space_link import SpaceLink
from taiji2_sim_pkg.nodes.telemetry_packetizer import TelemetryPacketizer

from support import ground_reader, spin_until

N = 300  # samples of 0.1 s: 30 s of data
MODEL = """light_time_s: 2.0
contacts: {windows: [[0.0, 12.0], [20.0, 1000.0]]}
downlink_rate_bps: 40000.0
random_loss_probability: 0.02
burst_loss: {p_good_to_bad: 0.005, p_bad_to_good: 0.3}
duplicate_probability: 0.01
duplicate_delay_s: 0.5
"""
CONTRACT = {"/taiji2/star_tracker": "StarTracker", "/taiji2/grs1/voltages": "GrsVoltages",
            "/taiji2/grs2/voltages": "GrsVoltages"}


def _values(k):
    return {"star_tracker": [0.0, 0.0, np.sin(k), np.cos(k), *([1e-10] * 9)], "grs": [0.01 * k + j for j in range(6)]}


def test_link_chain_matches_the_model_and_delivers_in_order(context, executor, tmp_path, monkeypatch):
    from taiji2_sim_pkg.nodes import space_link

    monkeypatch.setattr(space_link, "MAX_BURST_PACKETS", 50)  # the playback at the end goes out in many bursts
    (tmp_path / "fast.yaml").write_text(MODEL)
    args = ["--ros-args", "-p", f"model:={tmp_path / 'fast.yaml'}", "-p", "seed:=3"]
    nodes = [TelemetryPacketizer(context=context, cli_args=["--ros-args", "-p", f"end_of_data_s:={N / 10}"]),
             SpaceLink(context=context, cli_args=args), GroundReceiver(context=context)]
    source = rclpy.node.Node("onboard_source", context=context)
    observer = rclpy.node.Node("ground_observer", context=context)
    for n in (*nodes, source, observer):
        executor.add_node(n)
    qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                               reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
    t, g = messages.taiji2_msgs, messages.geometry_msgs
    pubs = {topic: source.create_publisher(getattr(t, name), "/onboard" + topic, qos)
            for topic, name in CONTRACT.items()}
    cmd_pub = source.create_publisher(g.WrenchStamped, "/onboard/taiji2/maneuver/command", qos)
    got, reception = ground_reader(observer, CONTRACT, qos)
    health: list = []  # the receiver's /diagnostics statuses
    observer.create_subscription(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics",
                                 lambda m: health.extend(s for s in m.status if s.name == "ground_receiver"), qos)
    started = time.monotonic()
    assert spin_until(executor, lambda: all(p.get_subscription_count() > 0 for p in (*pubs.values(), cmd_pub)))
    for k in range(1, N + 1):
        stamp = divmod(k * 100_000_000, 1_000_000_000)
        v = _values(k)
        st = t.StarTracker()
        st.header.stamp.sec, st.header.stamp.nanosec = stamp
        st.header.frame_id = "crf"
        st.attitude.x, st.attitude.y, st.attitude.z, st.attitude.w = v["star_tracker"][:4]
        st.attitude_covariance = v["star_tracker"][4:]
        pubs["/taiji2/star_tracker"].publish(st)
        for gid in (1, 2):
            msg = t.GrsVoltages(grs_id=gid)
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
            msg.header.frame_id = f"tmrf{gid}"
            msg.vx1, msg.vx2, msg.vy1, msg.vy2, msg.vz1, msg.vz2 = v["grs"]
            pubs[f"/taiji2/grs{gid}/voltages"].publish(msg)
        cmd = g.WrenchStamped()
        cmd.header.stamp.sec, cmd.header.stamp.nanosec = stamp
        cmd.header.frame_id = "crf"
        cmd.wrench.torque.z = 1e-6 * (k // 50 % 2)
        cmd_pub.publish(cmd)
        executor.spin_once(timeout_sec=0.0)
    assert spin_until(executor, lambda: bool(reception) and reception[-1]["end_of_data"], timeout_s=60.0)
    assert spin_until(executor, lambda: sum(len(v) for v in got.values()) >= sum(
        reception[-1]["counts"][s]["released"] for s in ("star_tracker", "grs1", "grs2")), timeout_s=30.0)
    # /diagnostics: the end of data at once, otherwise at most once a wall second and at each change of level,
    # not once per burst (the reception records)
    assert spin_until(executor, lambda: bool(health) and json.loads(
        {v.key: v.value for v in health[-1].values}["end_of_data"]), timeout_s=30.0)
    assert {v.key: json.loads(v.value) for v in health[-1].values}["counts"] == reception[-1]["counts"]
    levels = [any(c["missing"] for c in r["counts"].values()) for r in reception]
    changes = sum(a != b for a, b in itertools.pairwise(levels))
    assert len(reception) > 20
    assert len(health) <= 2 + changes + (time.monotonic() - started) / ground_receiver.DIAGNOSTICS_PERIOD_S
    # the plain model, offered the same packets in the packetizer's order and bursts, gives the same link
    link = Downlink(load_link_model(tmp_path / "fast.yaml"), 3)
    expected = {}
    for k in range(1, N + 1):
        for s, values in zip(STREAMS, (_values(k)["star_tracker"], _values(k)["grs"], _values(k)["grs"],
                                       [0, 0, 1e-6 * (k // 50 % 2), 0, 0, 0]), strict=True):
            if s.name != "executed_torque" or k < N:  # a command at the end acts after the run
                link.offer(k / 10, s.apid, encode_packet(s, k - 1, k * 100_000_000, values))
    link.drain()
    for s in STREAMS:
        expected[s.name] = link.stats[s.apid]
    final = reception[-1]["counts"]
    for topic, name in zip(CONTRACT, ("star_tracker", "grs1", "grs2"), strict=True):
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got[topic]]
        assert np.all(np.diff(stamps) > 0)  # in order, each once
        e = expected[name]
        assert final[name]["released"] == len(stamps) == e.delivered
        assert final[name]["duplicate"] == e.duplicated and final[name]["held"] == 0
        assert e.lost > 0 and e.reordered > 0  # the case exercises loss and playback
        k = np.rint(np.array(stamps) / 1e8).astype(int)
        assert final[name]["missing"] == (k[-1] - k[0] + 1) - len(k)
        if name != "star_tracker":
            assert all(m.vx1 == 0.01 * kk for m, kk in zip(got[topic], k, strict=True))
