"""Time-tagged commanding (ECSS PUS 11): TC[11,4] and TM[1,x] through spacepackets, the uplink plan,
the onboard schedule (late and over-capacity activities refused, never executed late). No DDS."""

from __future__ import annotations

import numpy as np
import pytest
from spacepackets.ecss.tc import PusTc

from taiji2_ground_pkg.uplink_plan import PlanError, maneuver_activities, plan_uplinks
from taiji2_model.maneuver import SquareWaveManeuver
from taiji2_runtime.packets.packetize import PacketError, packet_crc
from taiji2_runtime.packets.scheduling import (
    ACCEPTANCE_FAILURE_CODES,
    FAILURE_LATE,
    MAX_ACTIVITIES_PER_TC,
    Activity,
    decode_insert_activities,
    decode_report,
    encode_insert_activities,
    encode_report,
)
from taiji2_sim_pkg.core.link import load_link_model
from taiji2_sim_pkg.core.onboard_schedule import OnboardSchedule


def test_insert_activities_and_reports_through_spacepackets():
    acts = [Activity(10**9 * (600 + k), (1e-6 * k, -2e-6, 3e-6)) for k in range(MAX_ACTIVITIES_PER_TC)]
    packet = encode_insert_activities(7, acts, first_request_seq=100)
    parsed = PusTc.unpack(packet)
    assert (parsed.service, parsed.message_subtype, parsed.apid, parsed.seq_count) == (11, 4, 0x140, 7)
    tc, commands = decode_insert_activities(packet)
    assert [c.execute_onboard_ns for c in commands] == [a.release_ns for a in acts]
    assert all(np.array_equal(c.torque_n_m, a.torque_n_m) for c, a in zip(commands, acts, strict=True))
    report = decode_report(encode_report(8, tc, 5 * 10**9, seq_count=3, failure_code=FAILURE_LATE, refused=4))
    assert (report.subtype, report.tc_seq_count, report.failure_code, report.refused) == (8, 7, FAILURE_LATE, 4)
    assert decode_report(encode_report(1, tc, 10**9, seq_count=4)).subtype == 1
    # an acceptance failure reports on the raw packet's request id (TM[1,2], the defect's code)
    code = ACCEPTANCE_FAILURE_CODES["wrong_length"]
    report = decode_report(encode_report(2, packet[:40], 10**9, seq_count=5, failure_code=code))
    assert (report.subtype, report.tc_seq_count, report.failure_code) == (2, 7, code)
    with pytest.raises(ValueError):
        encode_insert_activities(0, acts + acts[:1])


def test_onboard_schedule_refuses_late_and_full_never_executes_late():
    s = OnboardSchedule(capacity=3, time_margin_s=10.0)
    late, full = s.insert(100.0, [(105.0, (1, 0, 0)), (120.0, (2, 0, 0)), (130.0, (3, 0, 0)), (140.0, (4, 0, 0)),
                                  (150.0, (5, 0, 0))])
    assert (late, full, s.inserted) == (1, 1, 3)
    assert s.torque_at(105.0)[0] == 0.0  # the late activity never runs
    assert [s.torque_at(t)[0] for t in (119.9, 120.0, 135.0, 1000.0)] == [0.0, 2.0, 3.0, 4.0]


def test_plan_splits_over_passes_with_safe_stop_and_capacity():
    model = load_link_model({"light_time_s": 100.0, "uplink_rate_bps": 1e5, "command_lead_s": 30.0,
                             "contacts": {"period_s": 3600.0, "first_start_s": 0.0, "duration_s": 600.0},
                             "onboard_schedule_capacity": 200})
    maneuver = SquareWaveManeuver(250.0, [3e-6, 3e-6, 13e-6], [0.0, 62.5, 31.25], 300.0, 3 * 3600.0)
    acts = maneuver_activities(maneuver.torque_at, 300.0, 300.0 + 3 * 3600.0, 0.1)
    tables = plan_uplinks(acts, model)
    assert [t.contact for t in tables] == [0, 1, 2, 3] and all(len(t.activities) <= 200 for t in tables)
    s = OnboardSchedule(200, 30.0)
    for t in tables:
        arrival = t.ready_s + 100.0 + 8 * 77 * len(t.activities) / 1e5
        assert s.insert(arrival, t.activities) == (0, 0)
    grid = np.arange(300.0, 300.0 + 3 * 3600.0, 0.1)
    assert all(np.array_equal(s.torque_at(t), maneuver.torque_at(t)) for t in grid[::7])  # the maneuver, exactly
    with pytest.raises(PlanError, match="start the maneuver at or after"):
        plan_uplinks(maneuver_activities(maneuver.torque_at, 0.0, 600.0, 0.1), model)
    small = load_link_model({"light_time_s": 100.0, "uplink_rate_bps": 1e5, "command_lead_s": 30.0,
                             "onboard_schedule_capacity": 50,
                             "contacts": {"period_s": 3600.0, "first_start_s": 0.0, "duration_s": 600.0}})
    with pytest.raises(PlanError, match="capacity 50"):
        plan_uplinks(acts, small)


def test_a_telecommand_spacepackets_cannot_read_is_a_packet_defect():
    """Found by the fuzzing: a PUS-A TC (version 1) inside an authentic frame made spacepackets raise a plain
    ValueError through the onboard acceptance; it is a ``bad_header`` defect with its own TM[1,2] code."""
    packet = bytearray(encode_insert_activities(0, [Activity(200 * 10**9, (1e-6, 0.0, 0.0))]))
    packet[6] = (packet[6] & 0x0F) | 0x10
    packet[-2:] = packet_crc(bytes(packet[:-2])).to_bytes(2, "big")
    with pytest.raises(PacketError, match="bad_header"):
        decode_insert_activities(bytes(packet))
    assert ACCEPTANCE_FAILURE_CODES["bad_header"] not in {v for k, v in ACCEPTANCE_FAILURE_CODES.items()
                                                          if k != "bad_header"}


def test_a_report_with_a_foreign_time_field_is_a_packet_defect():
    """Found by the fuzzing (benchmarks/bench_fuzz.py, downlink): a TM[1,1] whose CUC P-field is not ours raised
    CucError out of the ground receiver; it is a ``bad_time_field`` defect, counted."""
    tc = encode_insert_activities(0, [Activity(200 * 10**9, (1e-6, 0.0, 0.0))])
    packet = bytearray(encode_report(1, PusTc.unpack(tc), 150 * 10**9, 3))
    packet[13] = 0x2E  # the time field's P-field (after the 6-octet primary and 7 octets of PUS-C header)
    packet[-2:] = packet_crc(bytes(packet[:-2])).to_bytes(2, "big")
    with pytest.raises(PacketError, match="bad_time_field"):
        decode_report(bytes(packet))
