"""Commanding through Yamcs (issue 40 item 5) against a real Yamcs: the planner's TC[11,4] issued as XTCE
commands come out of Yamcs's link octet for octet (with Yamcs's sequence count and CRC), and the onboard
verification reports (the onboard executor's own encoder) drive the command history: Acceptance and Execution
passed, a table refused onboard as late shows as failed with its reason, one refused at acceptance too."""

from __future__ import annotations

import datetime as dt

import pytest
from spacepackets.ecss.tc import PusTc

from taiji2_ground_pkg.mcs.commanding import application_data
from taiji2_ground_pkg.mcs.yamcs_api import command_history
from taiji2_runtime.packets.scheduling import (
    ACCEPTANCE_FAILURE_CODES,
    FAILURE_LATE,
    Activity,
    encode_insert_activities,
    encode_report,
)

from support import command_through_yamcs, require_yamcs, running_yamcs

require_yamcs()

def tables_of_three():
    """Three tables of the planner's encoder (distinct activities, so distinct application data)."""
    return [encode_insert_activities(k, [Activity(10**12 * (k + 1) + j * 10**8, (1e-6 * j, -2e-6, 3e-6 * k))
                                         for j in range(3 + k)], first_request_seq=10 * k) for k in range(3)]


def test_tables_issued_in_yamcs_are_sent_whole_and_verified_from_the_onboard_reports(tmp_path):
    tables = tables_of_three()

    def reports(sent):
        # the onboard reports, as the executor encodes them: the first accepted and executed, the second accepted
        # then refused as late (5 activities), the third refused at acceptance (a CRC error). Each report goes
        # down twice (report_repeat_s); the first table's TM[1,1] is lost the first time: its TM[1,7] comes
        # alone, then both again (Execution waits for Acceptance: a completed command stops its verifiers)
        tcs = [PusTc.unpack(p) for p in sent]
        t_ns = 10**9
        accepted_0, executed_0 = encode_report(1, tcs[0], t_ns, 0), encode_report(7, tcs[0], t_ns + 1, 1)
        return [executed_0,
                encode_report(1, tcs[1], t_ns + 2, 2), encode_report(8, tcs[1], t_ns + 3, 3, FAILURE_LATE, 5),
                encode_report(2, sent[2], t_ns + 4, 4, ACCEPTANCE_FAILURE_CODES["crc_error"]),
                accepted_0, executed_0]

    with running_yamcs(tmp_path / "yamcs") as server:
        sent, history = command_through_yamcs(server, tables, reports, {"Acceptance": 3, "Execution": 2})
    # what Yamcs sent is the planner's table: the same application data, a valid PUS-C TC (CRC checked by
    # spacepackets), the count Yamcs gave it, as its command history has it
    tcs = [PusTc.unpack(p) for p in sent]
    assert [application_data(p) for p in sent] == [application_data(t) for t in tables]
    assert [(tc.service, tc.message_subtype, tc.apid) for tc in tcs] == [(11, 4, 0x140)] * 3
    assert [h["seq_count"] for h in history] == [tc.seq_count for tc in tcs] and len({tc.seq_count for tc in tcs}) == 3
    assert [h["comment"] for h in history] == ["table 0", "table 1", "table 2"]
    for h in history:
        assert (h["Queued"], h["Released"], h["Sent"]) == ("OK", "OK", "OK"), h
    assert (history[0]["Acceptance"], history[0]["Execution"], history[0]["message"]) == ("OK", "OK", None)
    assert (history[1]["Acceptance"], history[1]["Execution"]) == ("OK", "NOK")
    assert history[1]["message"] == "refused onboard: LATE, 5 activities not scheduled"
    assert history[2]["Acceptance"] == "NOK" and history[2]["message"] == "refused at acceptance onboard: CRC_ERROR"


def test_command_history_of_a_bad_address_is_a_ground_error():
    from taiji2_ground_pkg.mcs.errors import GroundError

    with pytest.raises(GroundError, match="not a Yamcs address"):
        command_history("http://127.0.0.1:1/taiji2", dt.datetime.now(dt.timezone.utc))
