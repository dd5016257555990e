"""Effects that start mid-run (simulator onset, diagnosis onset), and the corrected calibration.

Runs of 1 h (a few seconds each). Magnitude and onset checks are seeded statistical tests at 3
sigma (a false failure rate of 0.3 % per check were the seed drawn anew); the benchmark
(benchmarks/bench_diagnosis_blind.py) has the statistics over many 3-h draws.
"""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.diagnosis import diagnose, prepare_input
from taiji2_estimator_pkg.diagnosis.candidates import ONSET_KINDS
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import EFFECTS, make_effect
from taiji2_model.effects import Effect
from taiji2_sim_pkg.core.reference import simulate_reference
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

HOUR = 36000

_SPECS = {
    "scale_factor_drift": {"rate_per_s": 1e-6, "grs": 1, "axis": "x"},
    "cross_coupling": {"grs": 2, "misalignment_rad": [0, 0, 3e-3], "imbalance": [1e-3, 0, 0]},
    "time_offset": {"offset_s": 0.2},
    "star_tracker_lowfreq_noise": {"knee_hz": 0.01},
    "thruster_torque_gain": {"gain": 0.03, "axis": "y"},
    "com_drift": {"rate_m_s": [1e-6, 0, 0], "grs": 1},
    "readout_nonlinearity": {"k": 1e6, "grs": 1, "readout": "phi"},
    "inertia_error": {"relative": [0.01, 0, 0]},
    "gravity_gradient": {"scale": 1.0},
    "tm_stiffness": {"stiffness_s2": 1e-5, "grs": 1, "axis": "x"},
    "thruster_force_leakage": {"leakage_per_m": (np.eye(3) * 1e-3).tolist()},
    "actuation_delay": {"delay_s": 0.1},
    "thruster_response": {"time_constant_s": 0.1},
    "grs_time_offset": {"offset_s": 0.05},
    "impulse": {"time_s": 200.03, "angular_momentum_n_m_s": [2e-7, 0.0, 0.0], "linear_impulse_n_s": [1e-7, 0.0, 0.0]},
}


def _data(effects=(), n=HOUR, seed=1, layout="type1"):
    config = load_config(layout)
    commands = maneuver_torque_commands(config, n)
    out = simulate_batch(config, seed, commands, effects=[make_effect(**e) for e in effects])
    return config, prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)


def test_every_catalog_effect_has_an_onset_kind():
    assert set(_SPECS) == set(EFFECTS)
    # and the naming rule's rival of a nonlinearity from an onset, a readout step (diagnosis.readout_step)
    assert set(ONSET_KINDS) == set(EFFECTS) | {"readout_step"}
    assert {name for name, kind in ONSET_KINDS.items() if kind == "ramp"} == {"scale_factor_drift", "com_drift"}


@pytest.mark.parametrize("name", sorted(_SPECS))
def test_catalog_onset(name):
    """onset_s = 0 is bit-identical to no onset (both fidelities); a step effect changes nothing before
    its onset and, for the sensor-side ones, exactly what it changes without onset after it; a drift is
    frozen before its onset."""
    config = load_config("type1")
    n, onset = 3000, 150.0
    commands = maneuver_torque_commands(config, n)
    spec = _SPECS[name]
    for simulate in (simulate_batch, simulate_reference):
        plain = simulate(config, 3, commands, effects=[make_effect(name, **spec)])
        zero = simulate(config, 3, commands, effects=[make_effect(name, **spec, onset_s=0.0)])
        assert np.array_equal(plain.voltages_v, zero.voltages_v)
        assert np.array_equal(plain.st_quat_xyzw, zero.st_quat_xyzw)
    if name == "grs_time_offset":
        with pytest.raises(ValueError, match="onset_s"):
            make_effect(name, **spec, onset_s=onset)
        return
    base = simulate_batch(config, 3, commands)
    late = simulate_batch(config, 3, commands, effects=[make_effect(name, **spec, onset_s=onset)])
    before, after = late.t_s < onset - 1.0, late.t_s > onset + 1.0
    dv = np.abs(late.voltages_v - base.voltages_v).reshape(n, -1).max(axis=1)
    dq = np.abs(late.st_quat_xyzw - base.st_quat_xyzw).max(axis=1)
    if ONSET_KINDS[name] == "ramp":  # frozen before the onset, drifting after it
        field = "grs_angular_scale_factors" if name == "scale_factor_drift" else "com_offset_m"
        truth = np.asarray(getattr(late.truth, field))[:, 0]
        assert np.ptp(truth[before], axis=0).max() == 0.0 and np.ptp(truth[after], axis=0).max() > 0.0
        return
    assert dv[before].max() == 0.0 and dq[before].max() == 0.0
    assert max(dv[after].max(), dq[after].max()) > 0.0
    if name in ("cross_coupling", "readout_nonlinearity", "tm_stiffness", "scale_factor_drift"):
        whole = simulate_batch(config, 3, commands, effects=[make_effect(name, **spec)])
        np.testing.assert_array_equal(late.voltages_v[after], whole.voltages_v[after])


@pytest.fixture(scope="module")
def mid_run():
    """A thruster torque gain of 1.2 % about y from t = 1800 s (1 h, standard fidelity, ~40 sigma)."""
    config, inp = _data([{"name": "thruster_torque_gain", "gain": 0.012, "axis": "y", "onset_s": 1800.0}], seed=11)
    return config, inp, diagnose(inp, config)


def test_mid_run_effect_is_named_with_its_onset(mid_run):
    _, _, result = mid_run
    assert not result.verdict["unexplained"], result.verdict["summary"]
    assert result.verdict["effects"][0] in ("thruster_torque_gain", "inertia_error")
    top = result.effects[0]
    onset = top.parameters["onset_s"]
    assert onset["modelled"] and onset["kind"] == "step"
    assert abs(onset["value"] - 1800.0) < 3.0 * onset["sigma"], onset
    assert onset["sigma"] < 600.0 and onset["interval"][0] < onset["value"] < onset["interval"][1]
    assert result.plots["onsets"] and result.plots["onsets"][0][0] == top.key


def test_aliases_hold_from_the_onset(mid_run):
    """A torque gain about y and an inertia error about y are aliases from the start; from a modelled
    onset they still are (each is compared with the other variants started at the same onset), so the
    named one lists the other."""
    _, _, result = mid_run
    top = result.effects[0]
    other = "inertia_error[y]" if top.key == "thruster_torque_gain[y]" else "thruster_torque_gain[y]"
    assert top.parameters["onset_s"]["modelled"]
    assert other in top.aliases, (top.key, top.aliases)


def test_corrected_calibration_removes_the_bias(mid_run):
    """The torque gain biases the nominal G (torque channel); under the model extended with the named
    effect the re-calibrated G is back at the truth within 3 sigma, and the shift is reported in sigmas."""
    config, _, result = mid_run
    corrected = result.corrected
    truth = np.array([s.angular_scale_factors for s in config.grs.sensors])
    nominal_z = (np.array(result.calibration["g_angular"]) / truth - 1.0) / np.array(
        result.calibration["g_angular_sigma_relative"])
    corrected_z = (np.array(corrected["g_angular"]) / truth - 1.0) / np.array(corrected["g_angular_sigma_relative"])
    assert np.max(np.abs(nominal_z)) > 4.0
    assert np.max(np.abs(corrected_z)) < 3.0, corrected_z
    assert np.array(corrected["covariance"]).shape == (12, 12)
    assert np.max(np.abs(corrected["g_shift_sigma"])) > 3.0
    assert corrected["effects"][0]["onset_s"] == pytest.approx(result.effects[0].parameters["onset_s"]["value"])


def test_extended_layout_reads_no_significant_gap(mid_run):
    """The layout written with the named effect (effects section, onset) is a valid layout, and the same
    data diagnosed with it read "no significant gap"."""
    _, inp, result = mid_run
    layout = result.extended_layout
    extended = load_config(layout)
    assert extended.effects and extended.effects[0]["onset_s"] > 0
    assert load_config(extended.to_dict()) == extended
    again = diagnose(inp, extended)
    assert again.verdict["summary"] == "no significant gap", again.verdict["summary"]


@pytest.mark.long  # CI time (13 s): test_mid_run_effect_is_named_with_its_onset keeps the onset fit in CI
def test_effect_from_the_start_reads_onset_zero():
    """A misalignment present from the start: its onset is not modelled and reads 0 within 3 sigma."""
    config, inp = _data([{"name": "cross_coupling", "grs": 2, "misalignment_rad": [0, 0, 3e-3]}], seed=21)
    result = diagnose(inp, config)
    top = result.effects[0]
    assert top.key == "cross_coupling[grs2.misalign_z]" and top.accepted
    onset = top.parameters["onset_s"]
    assert not onset["modelled"]
    assert onset["value"] - float(inp.t_s[0]) < 3.0 * onset["sigma"], onset


@pytest.mark.long  # CI time (27 s): the mid-run cross coupling above keeps a family named in CI
def test_a_full_cross_coupling_of_one_grs_is_named_as_one_family():
    """Misalignment about three axes and electrode imbalance of three pairs of GRS 1 (six parameters):
    selection takes four variants (its physical budget), the family as one candidate (six parameters in
    the penalty) beats the stack, and the effect is named once, with its six magnitudes within 4 sigma."""
    truth = {"misalign": [2e-3, -2.5e-3, 3e-3], "imbalance": [1e-3, -1e-3, 1.5e-3]}
    config, inp = _data([{"name": "cross_coupling", "grs": 1, "misalignment_rad": truth["misalign"],
                          "imbalance": truth["imbalance"]}], seed=23)
    result = diagnose(inp, config)
    assert result.verdict["effects"] == ["cross_coupling"], result.verdict["summary"]
    (family,) = [f for f in result.verdict["families"] if f["family"] == "cross_coupling[grs1]"]
    assert family["stands"] and family["n_params"] == 6
    expected = dict(zip([f"cross_coupling[grs1.misalign_{a}]" for a in "xyz"], truth["misalign"], strict=True))
    expected.update(zip([f"cross_coupling[grs1.imbalance_{a}]" for a in "xyz"], truth["imbalance"], strict=True))
    for key, value, sigma in zip(family["variants"], family["magnitudes"], family["sigmas"], strict=True):
        assert abs(value - expected[key]) < 4.0 * sigma, (key, value, expected[key], sigma)
    # the corrected calibration models the whole family at the family fit's values, the variants
    # selection did not take included (not only the stack)
    specs = [s for s in result.corrected["effects"] if s.get("name") == "cross_coupling"]
    modelled = np.sum([np.concatenate((s.get("misalignment_rad", np.zeros(3)), s.get("imbalance", np.zeros(3))))
                       for s in specs], axis=0)
    np.testing.assert_allclose(modelled, family["magnitudes"], rtol=1e-12, atol=0)


class _TorquePulse(Effect):
    """A 5-s disturbance torque about x at t = 2000 s (out of the catalog: a transient)."""

    name = "torque_pulse"

    def __init__(self, amplitude_n_m):
        self.amplitude_n_m = amplitude_n_m

    def applied_torque_n_m(self, t_s, torque_n_m):
        out = np.array(torque_n_m)
        out[(t_s >= 2000.0) & (t_s < 2005.0), 0] += self.amplitude_n_m
        return out


def test_a_transient_is_unexplained_at_its_time():
    """A torque pulse no catalog effect explains: "unexplained", and the remaining gap's time window
    (with its resolution) holds the pulse; the summary says when."""
    from taiji2_estimator_pkg.diagnosis.model import NominalModel

    config = load_config("type1")
    sigma = float(np.sqrt(np.max(NominalModel.from_config(config).var_torque)))
    commands = maneuver_torque_commands(config, HOUR)
    out = simulate_batch(config, 31, commands, effects=[_TorquePulse(8.0 * sigma)])
    inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)
    result = diagnose(inp, config)
    assert result.verdict["unexplained"], result.verdict["summary"]
    windows = [loc for loc in result.verdict["remaining"] if "window_s" in loc]
    assert windows, result.verdict["remaining"]
    first = windows[0]
    slack = first["window_resolution_s"]
    assert first["window_s"][0] - slack <= 2005.0 and 2000.0 <= first["window_s"][1] + slack, first
    assert first["window_s"][1] - first["window_s"][0] < 600.0
    assert " s +- " in result.verdict["summary"], result.verdict["summary"]


def test_raw_data_corrected_for_the_layout_effects():
    """`taiji2 calibrate --config` removes the known effects of an extended layout from the raw arrays:
    an electrode imbalance (exact), a scale-factor drift from an onset (exact but for the voltage noise)
    and a misalignment (first order) of GRS 1, and a star-tracker time offset (first order in the rate)."""
    from taiji2_estimator_pkg.diagnosis.correction import correct_raw

    config = load_config("type1")
    n = 3000
    commands = maneuver_torque_commands(config, n)
    effects = [{"name": "cross_coupling", "grs": 1, "misalignment_rad": [0, 0, 2e-3], "imbalance": [2e-3, 0, 0]},
               {"name": "scale_factor_drift", "rate_per_s": 2e-6, "grs": 1, "axis": "y", "onset_s": 100.0},
               {"name": "time_offset", "offset_s": 0.2}]
    clean = simulate_batch(config, 5, commands)
    dirty = simulate_batch(config, 5, commands, effects=[make_effect(**e) for e in effects])
    layout = load_config(dict(config.to_dict(), effects=effects))
    quat, volts, report = correct_raw(dirty.t_s, dirty.st_quat_xyzw, dirty.voltages_v, layout)
    assert set(report["corrected"]) == {"cross_coupling", "scale_factor_drift", "time_offset"}
    scale = np.max(np.abs(clean.voltages_v))
    assert np.max(np.abs(dirty.voltages_v - clean.voltages_v)) > 1e-3 * scale
    assert np.max(np.abs(volts - clean.voltages_v)) < 2e-5 * scale
    before = np.max(np.abs(dirty.st_quat_xyzw - clean.st_quat_xyzw))
    after = np.max(np.abs(quat - clean.st_quat_xyzw))
    assert after < 0.03 * before  # the offset rotates by 0.2 s x omega; what is left: the rate error
