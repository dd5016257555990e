"""PUS 11 commanding on DDS: command_planner -> space_link -> onboard_executor on the graph's clock, the
telecommands in SDLS-signed TC frames (a key file of the test's own). The executor flies the maneuver
exactly; a table delayed by a missed pass is refused as late (TM[1,8]) and never executed, the maneuver
stopped safely until the next table; every frame authenticated, none refused."""

from __future__ import annotations

import numpy as np

from taiji2_ground_pkg.nodes.command_planner import CommandPlanner
from taiji2_model.config import load_config
from taiji2_model.maneuver import SquareWaveManeuver
from taiji2_runtime import link_topics as lt
from taiji2_runtime.packets.scheduling import FAILURE_LATE, decode_report
from taiji2_runtime.packets.sdls_keys import new_key_table, write_key_file
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.nodes.onboard_executor import OnboardExecutor
from taiji2_sim_pkg.nodes.space_link import SpaceLink

from support import spin_until

MODEL = """light_time_s: 5.0
contacts: {period_s: 100.0, first_start_s: 0.0, duration_s: 50.0}
uplink_rate_bps: 1000000.0
onboard_schedule_capacity: 100
command_lead_s: 2.0
"""


def test_planned_tables_flown_on_time_and_late_table_refused(context, executor, tmp_path):
    (tmp_path / "m.yaml").write_text(MODEL)
    model = str(tmp_path / "m.yaml")
    keys = write_key_file(tmp_path / "keys.json", new_key_table((3, 4)))
    planner = CommandPlanner(context=context, cli_args=["--ros-args", "-p", f"link_model:={model}", "-p",
                                                        f"key_file:={keys}", "-p", "maneuver:=paper",
                                                        "-p", "start_s:=20.0", "-p", "duration_s:=300.0"])
    link = SpaceLink(context=context, cli_args=["--ros-args", "-p", f"model:={model}", "-p", "missed_contacts:=[1]"])
    onboard = OnboardExecutor(context=context, cli_args=["--ros-args", "-p", "use_sim_time:=true", "-p",
                                                         "schedule_capacity:=100", "-p", "time_margin_s:=2.0",
                                                         "-p", f"key_file:={keys}"])
    probe = rclpy.node.Node("probe", context=context)
    for n in (planner, link, onboard, probe):
        executor.add_node(n)
    qos = lt.reliable_all()
    commands, reports, sent = {}, [], []
    probe.create_subscription(messages.geometry_msgs.WrenchStamped, "/onboard/taiji2/maneuver/command",
                              lambda m: commands.__setitem__(lt.stamp_ns(m.header), m.wrench.torque.z), qos)
    probe.create_subscription(messages.taiji2_msgs.SpacePackets, "/onboard/link/tm_reports",
                              lambda m: sent.extend(zip(lt.split(m), m.times_ns, strict=True)), qos)
    clock = probe.create_publisher(messages.rosgraph_msgs.Clock, "/clock", 10)
    assert spin_until(executor, lambda: onboard._horizon_ns > 0, timeout_s=20.0)  # the plan is onboard
    for t in range(0, 331):
        msg = messages.rosgraph_msgs.Clock()
        msg.clock.sec = t
        clock.publish(msg)
        spin_until(executor, lambda t=t: max(commands, default=-1) >= t * 10**9, timeout_s=5.0)
    m = load_config("type1").maneuver
    maneuver = SquareWaveManeuver(m.period_s, m.amplitude_n_m, m.phase_s, 20.0, 300.0)
    stamps = np.array(sorted(commands))
    t = stamps / 1e9
    flown = np.array([commands[s] for s in stamps])
    truth = np.array([maneuver.torque_at(x)[2] for x in t])
    arrival_1 = 200.0 + 5.0  # pass 1 missed: table 1 goes up in pass 2 at 200 s, onboard at 205 s
    table_1 = (t >= 107.1) & (t < 207.1)  # released in [pass-1 earliest, pass-2 earliest)
    bad = np.flatnonzero((flown != truth) & ~table_1 & (t < 320.0))
    assert bad.size == 0, (t[bad][:10], flown[bad][:10], truth[bad][:10])
    assert np.all(flown[table_1] == 0.0)  # refused as late (never executed), the maneuver stopped safely
    assert np.any(truth[table_1] != 0.0)
    # each report twice, the same packet report_repeat_s (10 s) later: the ground keeps one
    first = {}
    for packet, t_ns in sent:
        first.setdefault(packet, []).append(t_ns)
    assert all(len(ts) == 2 and ts[1] - ts[0] == 10 * 10**9 for ts in first.values()), first.values()
    reports = [decode_report(p) for p in first]
    late = [r for r in reports if r.subtype == 8]
    assert late and late[0].failure_code == FAILURE_LATE and abs(late[0].onboard_ns / 1e9 - arrival_1) < 1.0
    assert onboard.schedule.refused_late > 0 and sum(r.subtype == 1 for r in reports) == len(planner.plan)
    assert planner.signer.spi == 4 and onboard.verifier.accepted == len(planner.plan)
    assert sum(onboard.verifier.refused.values()) == 0 and onboard.verifier.last_sequence == {4: len(planner.plan)}
