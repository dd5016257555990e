"""Timing and actuation in the diagnosis: data from the reference fidelity, stamp conventions, the naming rule.

Runs of 1 h. The magnitude checks are seeded statistical tests at 3 sigma (a false failure rate of
0.3 % per check were the seed drawn anew); the benchmark (benchmarks/bench_diagnosis_blind.py) has
the statistics over many 3-h draws.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_dist
from scipy.stats import norm

from taiji2_estimator_pkg.diagnosis import align_streams, diagnose, prepare_input
from taiji2_estimator_pkg.diagnosis.candidates import TIMING_FAMILIES
from taiji2_estimator_pkg.diagnosis.partners import jointly_determined
from taiji2_estimator_pkg.diagnosis.standing import (
    FAMILY_VARIANTS_MAX,
    HELDOUT_POWER_MARGIN,
    HELDOUT_Z_MIN,
    HELDOUT_Z_MIN_UNEXPLAINED,
    HELDOUT_Z_STRONG,
    SHRINK_MIN,
    is_fluctuation,
    standing_verdict,
    unconfirmed_floor,
)
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.reference import simulate_reference
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

from support import assert_corrected_calibration

HOUR = 36000


def _assert_corrected(result, data_config):
    """The timing family's corrected calibration (issue 39): the named timing folded into the model, G and d
    re-calibrated within 3 sigma of the truth and no further from it than the nominal + 1 sigma."""
    sensors = data_config.grs.sensors
    assert_corrected_calibration(result, [s.angular_scale_factors for s in sensors], [s.com_offset_m for s in sensors])


@pytest.fixture(scope="module")
def latency_data():
    """Reference fidelity, 1 h, a 0.1-s command latency and nothing else."""
    config = load_config("type1")
    commands = maneuver_torque_commands(config, HOUR)
    out = simulate_reference(config, 41, commands, effects=[make_effect("actuation_delay", delay_s=0.1)])
    return prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)


def test_reference_latency_is_named_and_sized(latency_data):
    result = diagnose(latency_data, load_config("type1"))
    named = [e for e in result.effects if e.accepted]
    assert not result.verdict["unexplained"]
    assert [e.name for e in named if e.name not in TIMING_FAMILIES] == []  # no physical effect named
    delay = [e for e in named if e.name == "actuation_delay"]
    assert len(delay) == 1, result.verdict["summary"]
    assert abs(delay[0].magnitude - 0.1) < 3.0 * delay[0].sigma
    assert delay[0].sigma < 0.02
    _assert_corrected(result, load_config("type1"))


def test_reference_latency_configured_is_no_gap(latency_data):
    result = diagnose(latency_data, load_config("type1", {"timing.actuation_latency_s": 0.1}))
    assert result.verdict["summary"] == "no significant gap", result.verdict["summary"]


def _latency_and_lag(latency_s, lag_s, seed):
    """Diagnose 1 h of reference data with a command latency and a thruster lag (the readout unclipped) and
    check that the two are named, nothing else, each within 3 sigma of the truth; (data layout, result)."""
    data_config = load_config("type1", {"timing.actuation_latency_s": latency_s,
                                        "timing.thruster_time_constant_s": lag_s, "grs.readout_saturation": False})
    commands = maneuver_torque_commands(data_config, HOUR)
    out = simulate_reference(data_config, seed, commands)
    inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, data_config.sample_rate_hz)
    result = diagnose(inp, load_config("type1"))
    named = {e.name: e for e in result.effects if e.accepted}
    assert set(named) == {"actuation_delay", "thruster_response"}, result.verdict["summary"]
    delay, lag = named["actuation_delay"], named["thruster_response"]
    assert abs(delay.magnitude - latency_s) < 3.0 * delay.sigma
    assert abs(lag.magnitude - lag_s) < 3.0 * lag.sigma
    return data_config, result


@pytest.mark.long  # CI time (35 s): the reference-latency tests above keep a timing effect named and sized in CI
def test_latency_and_lag_are_fitted_jointly():
    """A command latency and a thruster lag together (reference fidelity, 1 h, the readout unclipped: the
    paper's preset leaves the GRS range, and clipped samples are transients of their own): the delay and
    lag signatures are exact only jointly. Fitted side by side (3 h), the split came out 0.052 / 0.148 s
    +- 0.006 s (11 sigma off) with a residual of significance 408 at torque_z 0.3-1 Hz; the joint
    fit (diagnosis.joint_timing) finds the split within its sigma. Checks (seeded, 3 sigma): no
    physical effect named, latency and lag each within 3 sigma of the truth, and the residual left
    at the torque channels at most 2 % of that of the side-by-side fit at 3 h (in -log10 p; 3.5 measured at
    1 h, where the side-by-side residual would be ~1/3 of 408: still 17 times the bound). 1 h instead of the
    3 h first measured (5.4 there) keeps the test at ~35 s. What remains is second order in the calibration
    (docs/diagnosis.md section 11): the same data with the timing configured read "no significant gap"."""
    data_config, result = _latency_and_lag(0.12, 0.08, 45)
    assert all(loc["significance"] < 8.16 for loc in result.verdict["remaining"]
               if loc["channel"].startswith("torque")), result.verdict["remaining"]
    _assert_corrected(result, data_config)


def test_a_lag_beside_a_delay_is_named_with_its_split():
    """A 73-ms latency with a 103-ms thruster lag (reference fidelity, 1 h, readout unclipped): the selection
    scores the second of the pair by their joint exact fit (diagnosis.joint_timing) and one delay family only
    from the start. Checks (seeded, 3 sigma): the lag and the delay named, no other delay family, each within
    3 sigma of the truth, nothing unexplained."""
    _, result = _latency_and_lag(0.073, 0.103, 46)
    assert not result.verdict["unexplained"], result.verdict["summary"]


def test_a_delay_from_an_onset_lists_the_lag_as_its_alias():
    """A 20-ms actuation delay from 1800 s of 1 h (standard simulator, seed 47). From an onset no exact timing
    scan is run, so a delay and a thruster lag (both shift the thrust by -tau d(torque)/dt to first order) are
    told apart by nothing: whichever is named lists the other as its alias. Blind seed 13, set 21: a 5.7-ms
    delay from 5,404 s was named as a 7.2-ms lag from 5,483 s with no alias (only the two delay families were
    compared with each other from an onset)."""
    config = load_config("type1")
    commands = maneuver_torque_commands(config, HOUR)
    out = simulate_batch(config, 47, commands, effects=[make_effect(name="actuation_delay", delay_s=0.02,
                                                                    onset_s=1800.0)])
    result = diagnose(prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz),
                      config)
    timing = [e for e in result.effects if e.accepted and e.name in TIMING_FAMILIES]
    assert len(timing) == 1, result.verdict["summary"]
    (named,) = timing
    assert named.parameters.get("onset_s", {}).get("modelled"), named.parameters
    listed = {named.key, *named.aliases}
    assert {"actuation_delay", "thruster_response"} <= listed, (named.key, named.aliases)


@pytest.mark.long  # CI time (37 s): test_diagnose.py's time_offset case names a GRS time offset in CI
def test_start_stamp_convention_is_a_grs_time_offset():
    # GRS stamped at the start of its integration interval: every GRS sample is 0.1 s early for the
    # nominal ("end") model, i.e. a GRS time offset of -0.1 s (docs/interfaces.md)
    data_config = load_config("type1", {"timing.grs_stamp": "start"})
    commands = maneuver_torque_commands(data_config, HOUR)
    out = simulate_batch(data_config, 43, commands)
    inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, data_config.sample_rate_hz)
    result = diagnose(inp, load_config("type1"))
    named = [e for e in result.effects if e.accepted]
    assert [e.name for e in named] == ["grs_time_offset"], result.verdict["summary"]
    assert abs(named[0].magnitude + 0.1) < 3.0 * named[0].sigma
    _assert_corrected(result, data_config)
    # the same data diagnosed with the convention configured: nothing left
    assert diagnose(inp, data_config).verdict["summary"] == "no significant gap"


def test_align_streams_removes_a_constant_stamp_phase():
    config = load_config("type1")
    commands = maneuver_torque_commands(config, 600)
    out = simulate_batch(config, 44, commands)
    grs_phase, command_phase = 0.03, -0.02  # s, each stream's own sub-step stamping
    inp = align_streams(out.t_s, out.st_quat_xyzw, out.t_s + grs_phase, out.voltages_v[:, 0],
                        out.t_s + grs_phase, out.voltages_v[:, 1], out.t_s - config.dt_s + command_phase, commands,
                        config.sample_rate_hz)
    # the phases are medians of stamp offsets: exact up to the rounding of t / dt
    assert inp.stamp_phase_s["grs"] == pytest.approx(grs_phase, abs=1e-9)
    assert inp.stamp_phase_s["command"] == pytest.approx(command_phase, abs=1e-9)
    assert sum(inp.rejected.values()) == 0
    np.testing.assert_array_equal(inp.voltages_v, out.voltages_v)


def _report(key, shrink, heldout_z, name="", variant="", expected=None, delta_chi2=1e3, n_params=1, z_sd=None):
    return SimpleNamespace(key=key, name=name or key, variant=variant, accepted=True, rejected=None, shrink=shrink,
                           heldout_z=heldout_z, heldout_expected_z=expected, heldout_z_sd=z_sd,
                           delta_chi2=delta_chi2, n_params=n_params)


def test_naming_rule():
    standing = _report("a", SHRINK_MIN + 0.1, 5.0)
    shaving = _report("b", SHRINK_MIN - 0.1, 50.0)  # a few percent of a larger gap: never named
    weak = _report("c", 0.9, HELDOUT_Z_MIN_UNEXPLAINED - 0.5)  # fine alone, not beside an unexplained gap
    named, rejected = standing_verdict([standing, shaving, weak], unexplained=True)
    assert named == [standing] and set(rejected) == {"b", "c"}
    assert not shaving.accepted and "explains only" in shaving.rejected
    assert not weak.accepted and "held-out" in weak.rejected
    named, rejected = standing_verdict([_report("c", 0.9, HELDOUT_Z_MIN_UNEXPLAINED - 0.5)], unexplained=False)
    assert [r.key for r in named] == ["c"] and rejected == {}


def test_a_held_out_part_too_weak_to_confirm_an_effect_refuses_it_only_where_it_contradicts_it():
    # expected z 2.2 (< HELDOUT_Z_MIN + 2): z = 0.6 is no evidence against it; z = -1 is (3.2 below)
    weak_test = _report("drift", 0.9, 0.6, expected=2.2)
    contradicted = _report("other", 0.9, -1.0, expected=2.2)
    named, rejected = standing_verdict([weak_test, contradicted], unexplained=False)
    assert named == [weak_test] and "contradicted" in rejected["other"]
    # an informative held-out part (expected z 4) still needs z >= HELDOUT_Z_MIN
    named, rejected = standing_verdict([_report("x", 0.9, 0.6, expected=HELDOUT_Z_MIN + 3.0)], unexplained=False)
    assert not named and "not confirmed" in rejected["x"]
    # beside an unexplained gap the rule stays as it was (partial explanations)
    named, rejected = standing_verdict([_report("y", 0.9, 0.6, expected=2.2)], unexplained=True)
    assert not named and "not confirmed" in rejected["y"]


def test_a_contradiction_is_measured_against_the_spread_the_trained_magnitude_gives():
    # a gravity gradient's x and z components trained on 2 h and extrapolated to the last hour read
    # z = -2.4 where 2.6 was expected (blind seed 17, set 11): 5 below it, with the training error s = 2.4
    extrapolated = _report("gravity_gradient[z]", 0.99, -2.4, expected=2.6, z_sd=2.4)
    exact = _report("same_reading_exact_training", 0.99, -2.4, expected=2.6, z_sd=1.0)
    named, rejected = standing_verdict([extrapolated, exact], unexplained=False)
    assert named == [extrapolated] and "contradicted" in rejected["same_reading_exact_training"]
    # 3 spreads below still contradicts
    named, rejected = standing_verdict([_report("far", 0.99, 2.6 - 3.1 * 2.4, expected=2.6, z_sd=2.4)],
                                       unexplained=False)
    assert not named and "+- 2.4" in rejected["far"]


def test_partners_are_effects_whose_magnitudes_correlate_almost_perfectly():
    # a latency and a lag splitting one group delay (rho = -0.999), and an unrelated effect (rho = 0.1)
    sigma = np.array([1.0, 0.02, 0.02, 3.0])
    rho = np.eye(4)
    rho[1, 2] = rho[2, 1] = -0.999
    rho[1, 3] = rho[3, 1] = 0.1
    cov = rho * np.outer(sigma, sigma)
    current = ["nuisance", "delay", "lag", "drift"]
    partners = jointly_determined([["delay"], ["lag"], ["drift"]], ["actuation_delay", "thruster_response", "com"],
                                  current, cov, 0.95)
    assert partners == {"actuation_delay": ["thruster_response"], "thruster_response": ["actuation_delay"]}
    # just under the threshold: no partners
    rho[1, 2] = rho[2, 1] = -0.94
    cov = rho * np.outer(sigma, sigma)
    assert jointly_determined([["delay"], ["lag"]], ["a", "b"], current, cov, 0.95) == {}


def test_a_stack_of_variants_of_one_family_is_not_named():
    # each variant stands on its own, but FAMILY_VARIANTS_MAX + 1 of one family together imitate a gap
    stack = [_report(f"cc[{v}]", 0.9, 5.0, "cross_coupling", v) for v in ("a", "b", "c", "d")[:FAMILY_VARIANTS_MAX + 1]]
    delay = _report("actuation_delay", 0.99, 100.0)
    named, rejected = standing_verdict([delay, *stack], unexplained=False)
    assert named == [delay] and set(rejected) == {r.key for r in stack}
    assert all("variants of cross_coupling" in r.rejected for r in stack)
    # FAMILY_VARIANTS_MAX of them (two independent misalignments, say) are named
    pair = [_report(f"cc[{v}]", 0.9, 5.0, "cross_coupling", v) for v in ("a", "b")[:FAMILY_VARIANTS_MAX]]
    named, rejected = standing_verdict(pair, unexplained=False)
    assert named == pair and rejected == {}


def test_a_gap_in_other_channels_does_not_raise_the_held_out_threshold():
    """Beside a gap unexplained in torque_z, an effect whose cells lie in the linear channels keeps the plain
    rule (blind seed 14, set 21: a c.m. drift, z 1.1, expected 1.4, beside a timing remainder); one with a
    cell in the gap's channel, or without cells, is held to the raised threshold."""
    def report(key, channels):
        out = _report(key, 0.9, 1.1, expected=1.4)
        out.cells = [{"channel": channel} for channel in channels]
        return out

    apart, shaving, unknown = (report("drift", ["lin_diff_z", "lin_common_z"]),
                               report("gain", ["torque_z", "lin_diff_z"]), report("other", []))
    named, rejected = standing_verdict([apart, shaving, unknown], unexplained=True, gap_channels={"torque_z"})
    assert named == [apart] and set(rejected) == {"gain", "other"}
    assert all("not confirmed" in reason for reason in rejected.values())
    # the gap's channels unknown: every effect beside it is held to the raised threshold
    named, rejected = standing_verdict([report("drift", ["lin_diff_z"])], unexplained=True)
    assert not named and "not confirmed" in rejected["drift"]


def test_an_effect_the_held_out_part_cannot_confirm_needs_the_floor_at_the_confirmed_level():
    """Rule 2b: where the held-out part cannot confirm an effect (expected z < HELDOUT_Z_MIN + 2), its gain must
    pass the selection floor at level x HELDOUT_NULL_PASS, unless its held-out z reaches HELDOUT_Z_STRONG (blind
    seed 16: drifts at 3.8-4.1 sigma with z 1.0-2.3, in 3 of 156 sets; seed 18, set 43: a drawn nonlinearity at
    delta chi2 15.9 with z 4.1); refused, it is a fluctuation, not a gap."""
    level = 1e-4  # alpha 1 % over 100 candidates: the selection floor is chi2_1 15.1
    floor = unconfirmed_floor(level, 1)
    assert floor == pytest.approx(float(chi2_dist.isf(level * norm.sf(HELDOUT_Z_MIN), 1)))
    assert 18.0 < floor < 19.0 and unconfirmed_floor(level, 2) > floor
    at_floor = _report("drift", 1.0, 1.1, expected=1.2, delta_chi2=15.2)
    above = _report("strong_drift", 1.0, 0.4, expected=2.2, delta_chi2=floor + 0.5)
    confirmable = _report("gain", 1.0, 1.1, expected=HELDOUT_Z_MIN + HELDOUT_POWER_MARGIN, delta_chi2=15.2)
    named, rejected = standing_verdict([at_floor, above, confirmable], unexplained=False, level=level)
    assert named == [above, confirmable] and set(rejected) == {"drift"}
    assert is_fluctuation(rejected["drift"]) and not at_floor.accepted
    # a strong held-out confirmation carries it: the same gain with z = HELDOUT_Z_STRONG stands, just below it not
    strong = _report("confirmed", 1.0, HELDOUT_Z_STRONG, expected=1.9, delta_chi2=15.9)
    barely = _report("barely", 1.0, HELDOUT_Z_STRONG - 0.1, expected=1.9, delta_chi2=15.9)
    named, rejected = standing_verdict([strong, barely], unexplained=False, level=level)
    assert named == [strong] and is_fluctuation(rejected["barely"])
    # without a level (the rule not asked for) the effect at the floor stands
    named, _ = standing_verdict([_report("drift", 1.0, 1.1, expected=1.2, delta_chi2=15.2)], unexplained=False)
    assert [r.key for r in named] == ["drift"]
    # other refusals are no fluctuations
    named, rejected = standing_verdict([_report("x", 0.9, 0.6, expected=HELDOUT_Z_MIN + 3.0)], unexplained=False,
                                       level=level)
    assert not is_fluctuation(rejected["x"])
