"""Each GRS's "N samples used, M rejected" line counts the streams its estimates use, not the command stream."""

from __future__ import annotations

from taiji2_estimator_pkg.calibration import _rejected_for


def test_a_refused_command_packet_is_not_a_rejected_sample_of_either_grs():
    rejected = {"/taiji2/maneuver/command": {"duplicate_stamp": 1}, "star_tracker": {"gated": 2},
                "/taiji2/grs1/voltages": {"nan_or_inf": 3}, "grs2": {"out_of_order_stamp": 5}}
    assert _rejected_for(rejected, 1) == 2 + 3
    assert _rejected_for(rejected, 2) == 2 + 5
    assert _rejected_for({"/taiji2/maneuver/command": {"duplicate_stamp": 1}}, 1) == 0
