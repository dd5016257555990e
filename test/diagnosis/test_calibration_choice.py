"""The report's choice of calibration: calibrate's (star tracker) beside the torque channel's, with the difference."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis.calibration_choice import CONSISTENT_SIGMA, calibration_choice
from taiji2_estimator_pkg.report import EstimateTable, GrsResult


def _tables(shift_sigma: float):
    g, g_sigma, d, d_sigma = np.full(3, 5.5e-8), np.full(3, 1e-10), np.full(3, 1e-4), np.full(3, 2e-4)
    star = EstimateTable("gls", [GrsResult(i, g, np.diag(g_sigma**2), d, np.diag(d_sigma**2)) for i in (1, 2)])
    combined = np.hypot(g_sigma, g_sigma)  # both sigmas equal below: combined = sqrt(2) sigma
    torque = {"g_angular": [list(g + shift_sigma * combined)] * 2, "g_angular_sigma_relative": [list(g_sigma / g)] * 2,
              "com_offset_m": [list(d)] * 2, "com_offset_sigma_m": [list(d_sigma)] * 2}
    return star, torque


def test_calibrate_is_the_one_to_use_and_the_difference_is_in_combined_sigma():
    choice = calibration_choice(*_tables(1.5))
    assert choice["use"] == "calibrate" and len(choice["rows"]) == 12
    g_rows = [r for r in choice["rows"] if r["parameter"].startswith("G")]
    # the torque channel's sigma is relative to its own value, (1 + 2.7e-3) times calibrate's here
    np.testing.assert_allclose([r["difference_sigma"] for r in g_rows], 1.5, rtol=5e-3)
    assert all(r["difference_sigma"] == 0.0 for r in choice["rows"] if r["parameter"].startswith("d"))
    assert abs(choice["max_difference_sigma"] - 1.5) < 1e-2 and "agree within 1.5" in choice["why"]


def test_a_difference_beyond_three_sigma_is_named_as_a_bias_of_the_torque_channel():
    choice = calibration_choice(*_tables(CONSISTENT_SIGMA + 2.0))
    assert "biases the torque channel" in choice["why"]


def test_named_effects_point_to_calibrate_with_the_extended_layout_and_the_corrected_calibration_has_its_caveats():
    star, torque = _tables(0.5)
    corrected = {**torque, "alias_uncertain": ["G.1.phi"]}
    choice = calibration_choice(star, torque, corrected, {"effects": ["thruster_torque_gain"], "unexplained": False})
    assert choice["use"] == "calibrate --config" and "--write-config" in choice["why"]
    assert all(r["corrected"] is not None and r["corrected_sigma"] > 0 for r in choice["rows"])
    assert any("alias" in c and "G.1.phi" in c for c in choice["caveats"])
    unexplained = calibration_choice(star, torque, corrected, {"effects": ["com_drift"], "unexplained": True})
    assert unexplained["use"] == "calibrate" and any("unexplained" in c for c in unexplained["caveats"])


def test_a_blind_spot_beyond_three_sigma_is_a_caveat_and_one_below_is_not():
    star, torque = _tables(0.5)
    spots = [{"family": "cross_coupling", "parameter": "G.2.psi", "bias_sigma": CONSISTENT_SIGMA + 3.4},
             {"family": "tm_stiffness", "parameter": "d.1.x", "bias_sigma": CONSISTENT_SIGMA - 0.1}]
    caveats = calibration_choice(star, torque, None, {"effects": [], "unexplained": False}, spots)["caveats"]
    assert len(caveats) == 1 and "cross_coupling up to 6 sigma on G.2.psi" in caveats[0], caveats
    assert "tm_stiffness" not in caveats[0]
    assert calibration_choice(star, torque, None, None, spots[1:])["caveats"] == []
