"""GRS readout saturation (issue 42 item 1): the linear readout is clipped at the range by default,
a named layout switch turns it off, the range check counts signal plus every noise source either way,
and the per-sample noise sigma the design adds to the maneuver's peak is the simulator's."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
from taiji2_model.grs import accelerations_from_voltages, saturate_linear_readout
from taiji2_model.noise import linear_readout_noise_std_m_s2
from taiji2_sim_pkg.core.range_check import RangeMonitor
from taiji2_sim_pkg.core.reference import simulate_reference
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands, simulate_batch

SEED = 4242
STEPS = 6000  # 600 s of the paper's Type-1 preset: its rotation part peaks near 0.86 of the range


def _readout(out):
    return accelerations_from_voltages(out.voltages_v, out.truth.grs_angular_scale_factors,
                                       out.truth.grs_linear_scale_factors)


def _config(saturation, **overrides):
    return load_config("type1", overrides={"grs.readout_saturation": saturation, **overrides})


def test_the_switch_is_on_by_default_and_named_in_the_layout():
    for layout in ("type1", "type2"):
        config = load_config(layout)
        assert config.grs.readout_saturation is True
        assert config.to_dict()["grs"]["readout_saturation"] is True
    assert load_config("type1", overrides={"grs.readout_saturation": False}).grs.readout_saturation is False
    plain = load_config("type1").to_dict()
    del plain["grs"]["readout_saturation"]  # optional key: default on
    assert load_config(plain).grs.readout_saturation is True
    from taiji2_model.config import ConfigError

    with pytest.raises(ConfigError, match="readout_saturation"):
        load_config("type1", overrides={"grs.readout_saturation": "yes"})


def test_saturation_clips_the_linear_readout_at_the_range_and_keeps_the_angular_one():
    on, off = _config(True), _config(False)
    commands = maneuver_torque_commands(on, STEPS)
    clipped, free = simulate_batch(on, SEED, commands), simulate_batch(off, SEED, commands)
    limit = on.grs.range_m_s2
    angular_on, linear_on = _readout(clipped)
    angular_off, linear_off = _readout(free)
    outside = np.abs(clipped.truth.grs_linear_meas) > limit
    assert 0.01 < outside.mean() < 0.5  # thruster force noise (0.15 of the range per sample) drives it out
    # on: never beyond the range (up to rounding of the voltage sum), on the rail where the demand is beyond
    assert np.max(np.abs(linear_on)) <= limit * (1 + 1e-12)
    rail = np.abs(linear_on) >= limit * (1 - 1e-12)
    assert rail.sum() >= 0.99 * outside.sum()  # the voltage noise (5e-5 of the range) may move a few across
    # off: the unclipped readout goes beyond, by the same samples
    assert np.max(np.abs(linear_off)) > 1.2 * limit
    np.testing.assert_array_equal(np.abs(linear_off) > limit, np.abs(linear_on) >= limit * (1 - 1e-12))
    # samples inside the range are bitwise those of the unclipped run; the angular readout is kept
    inside = ~np.repeat(np.abs(linear_off) > limit, 2, axis=-1)
    np.testing.assert_array_equal(clipped.voltages_v[inside], free.voltages_v[inside])
    np.testing.assert_allclose(angular_on, angular_off, rtol=0, atol=1e-12 * np.max(np.abs(angular_off)))
    # the truth keeps the unclipped demand (what the range check counts), identical with the switch either way
    np.testing.assert_array_equal(clipped.truth.grs_linear_meas, free.truth.grs_linear_meas)


def test_streaming_saturates_as_the_batch():
    config = _config(True)
    commands = maneuver_torque_commands(config, 400)
    batch = simulate_batch(config, SEED, commands)
    sim = Simulator(config, seed=SEED)
    streamed = np.array([sim.step(c).voltages_v for c in commands])
    np.testing.assert_array_equal(streamed, batch.voltages_v)


def test_the_reference_simulator_saturates_too():
    on, off = _config(True), _config(False)
    commands = maneuver_torque_commands(on, 3000)
    clipped, free = simulate_reference(on, SEED, commands), simulate_reference(off, SEED, commands)
    limit = on.grs.range_m_s2
    linear_on, linear_off = _readout(clipped)[1], _readout(free)[1]
    assert np.max(np.abs(linear_off)) > 1.1 * limit
    assert np.max(np.abs(linear_on)) <= limit * (1 + 1e-12)
    inside = np.abs(linear_off) <= limit
    np.testing.assert_array_equal(linear_on[inside], linear_off[inside])


def test_saturate_moves_both_channels_by_half_the_excess():
    volts = np.array([[3.0, 2.0, 0.1, 0.2, -4.0, -1.0]])
    saturate_linear_readout(volts, np.array([1.0, 1.0, 1.0]), 1.0)
    np.testing.assert_allclose(volts[0, 0::2] + volts[0, 1::2], [1.0, 0.3, -1.0])
    np.testing.assert_allclose(volts[0, 0::2] - volts[0, 1::2], [1.0, -0.1, -3.0])


def test_the_range_check_counts_signal_plus_every_noise_source():
    """Fraction of samples beyond the range with all noise on: the monitor counts the unclipped
    readout demand (signal + every noise), the same with saturation on or off, and it matches the
    Gaussian expectation of the noise sigma the design uses (linear_readout_noise_std_m_s2)."""
    config = _config(True)
    commands = maneuver_torque_commands(config, STEPS)
    out = simulate_batch(config, SEED, commands)
    limit = config.grs.range_m_s2
    monitor = RangeMonitor(limit)
    monitor.update_block(out.t_s, out.truth.grs_linear_maneuver, out.truth.grs_linear_meas)
    counted = monitor.samples_outside["total"]
    np.testing.assert_array_equal(counted, np.sum(np.abs(out.truth.grs_linear_meas) > limit, axis=0))
    assert monitor.summary()["maneuver"]["within_range"]  # the rotation part alone stays inside
    quiet = load_config("type1", overrides={f"noise.{n}.enabled": False for n in NOISE_SOURCE_NAMES})
    signal = simulate_batch(quiet, SEED, commands).truth.grs_linear_maneuver
    assert np.all(np.abs(signal) <= limit)  # so every counted sample is the noise's doing
    from scipy.stats import norm

    sigma = linear_readout_noise_std_m_s2(config)
    expected = np.sum(norm.sf((limit - signal) / sigma) + norm.cdf((-limit - signal) / sigma), axis=0)
    # binomial scatter of the count (a few 100 per axis): 5 sigma, plus 10 % for the slow SRP part
    assert np.all(np.abs(counted - expected) <= 5 * np.sqrt(expected) + 0.1 * expected), (counted, expected)
    assert counted.sum() > 1000


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_noise_sigma_of_the_design_is_the_simulators(layout):
    config = load_config(layout)
    n = 30000  # no maneuver: the linear readout is noise only
    out = simulate_batch(config, SEED, np.zeros((n, 3)))
    measured = np.std(out.truth.grs_linear_meas, axis=0)
    predicted = linear_readout_noise_std_m_s2(config)
    # standard error of a std of 30000 samples: 0.4 %; the slow SRP part (1 % of the variance) is
    # under-sampled in 3000 s
    np.testing.assert_allclose(measured, predicted, rtol=0.02)
    assert np.all((predicted > 0.14e-9) & (predicted < 0.16e-9))  # thruster force noise dominates
