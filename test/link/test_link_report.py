"""The experiment's link report: requirement met on the ground, commanding summary, the maneuver's start (no DDS)."""

from __future__ import annotations

import pytest

from taiji2_apps.cli.experiment_link import (
    commanding_summary,
    earliest_maneuver_start_s,
    pass_of,
    requirement_times,
)
from taiji2_sim_pkg.core.link import load_link_model


def test_requirement_met_on_the_ground_is_when_the_data_through_it_were_released():
    g = [5.5e-8, 5.5e-8, 7.4e-8]
    history = {"/taiji2/estimates/grs1/scale_factors": [
        (100 * 10**9, g, [1e-9, 1e-9, 1e-9]),  # 1.8 %: not met
        (200 * 10**9, g, [1e-10, 2e-9, 1e-10]),  # met for Pphi and Ppsi (0.18 %, 0.14 %)
        (300 * 10**9, g, [1e-10, 1e-10, 1e-10])],
        "/taiji2/estimates/grs1/com_offset": [(250 * 10**9, [0, 0, 0], [5e-5, 2e-4, 5e-5])]}
    reception = [{"ground_time_s": 150.0, "released_through_s": {"star_tracker": 190.0, "grs1": 210, "grs2": 210},
                  "end_of_data": False},
                 {"ground_time_s": 900.0, "released_through_s": {"star_tracker": 260.0, "grs1": 260, "grs2": 250},
                  "end_of_data": False},
                 {"ground_time_s": 2000.0, "released_through_s": {"star_tracker": 400.0, "grs1": 400, "grs2": 400},
                  "end_of_data": True}]
    rows = {(r["grs"], r["parameter"]): r for r in requirement_times(history, reception)}
    assert rows[(1, "G_Pphi")]["onboard_time_s"] == 200.0 and rows[(1, "G_Pphi")]["ground_time_s"] == 900.0
    assert rows[(1, "G_Ptheta")]["onboard_time_s"] == 300.0 and rows[(1, "G_Ptheta")]["ground_time_s"] == 2000.0
    assert rows[(1, "d_x")]["onboard_time_s"] == 250.0 and rows[(1, "d_x")]["ground_time_s"] == 900.0
    assert rows[(1, "d_y")]["onboard_time_s"] is None and rows[(2, "G_Pphi")]["ground_time_s"] is None


def test_commanding_summary_names_tables_lost_on_uplink():
    plan = [{"tc_seq": k, "activities": 50} for k in range(4)]
    reports = [{"subtype": 1, "tc_seq": 0, "ground_s": 400.0}, {"subtype": 7, "tc_seq": 0},
               {"subtype": 1, "tc_seq": 2, "ground_s": 900.0},
               {"subtype": 8, "tc_seq": 2, "failure_code": 1, "refused": 7}]
    c = commanding_summary(plan, reports)
    assert c["lost_on_uplink"] == [1, 3] and c["refused_activities"] == 7 and c["refused_late_tables"] == [2]
    assert (c["tables"], c["activities"], c["acknowledged"], c["completed"]) == (4, 200, 2, 1)


def test_maneuver_start_and_pass_of():
    deep = load_link_model("deep_space")
    assert earliest_maneuver_start_s(load_link_model("ideal")) == 0.0
    # first pass at 0 + 173 s light time + 3000 x 77 octets at 2 kbit/s (924 s) + 60 s margin, up to 10 s
    assert earliest_maneuver_start_s(deep) == pytest.approx(1160.0)
    assert pass_of(100.0, deep) == 0 and pass_of(86400.0 + 20000.0, deep) == 1 and pass_of(5.0, load_link_model(
        "ideal")) is None
