"""Timing conventions: exact actuation averages, GRS stamp conventions, streaming = batch."""

import math

import numpy as np
import pytest

from taiji2_model.config import ConfigError, load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_model.timing import actuated_commands, actuation_weights
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands, simulate_batch

DT = 0.1
QUIET = {f"noise.{name}.enabled": False for name in ("thruster_torque", "thruster_force", "srp", "lfs_translational",
                                                    "lfs_rotational", "tm_environment", "grs_voltage",
                                                    "star_tracker")}


@pytest.mark.parametrize("delay", [0.0, 0.05, 0.1, 0.13, -0.13, -0.1, 0.37])
def test_pure_delay_is_linear_interpolation(delay):
    commands = np.random.default_rng(3).normal(size=(40, 3))
    out = actuated_commands(commands, delay, 0.0, DT)
    whole, fraction = divmod(delay / DT, 1.0)
    whole = round(whole) if abs(fraction - 1.0) > 1e-12 else round(whole) + 1
    fraction = 0.0 if abs(fraction - 1.0) < 1e-12 else fraction
    padded = np.vstack([np.zeros((5, 3)), commands, np.repeat(commands[-1:], 5, axis=0)])
    k = np.arange(40) + 5
    expected = (1.0 - fraction) * padded[k - whole] + fraction * padded[k - whole - 1]
    # a sum of two products of the commands: rounding of a few ulps of |c|
    assert np.max(np.abs(out - expected)) <= 8 * np.finfo(float).eps * np.max(np.abs(commands))


@pytest.mark.parametrize(("delay", "tau"), [(0.0, 0.2), (0.13, 0.05), (-0.07, 0.5)])
def test_lagged_step_matches_closed_form(delay, tau):
    # unit step commanded at t = 0: thrust 1 - exp(-(t - D)/T) after t = D; mean over (k dt, (k+1) dt]
    commands = np.zeros((60, 1))
    commands[10:] = 1.0
    out = actuated_commands(commands, delay, tau, DT)[:, 0]
    start = (np.arange(60) - 10) * DT - delay  # interval start relative to the thrust onset
    end = start + DT
    a, b = np.maximum(start, 0.0), np.maximum(end, 0.0)
    integral = (b - a) - tau * (np.exp(-a / tau) - np.exp(-b / tau))
    integral[end <= 0.0] = 0.0
    assert np.max(np.abs(out - integral / DT)) < 1e-12


def test_weights_sum_to_one_and_reject_bad_values():
    for delay, tau in [(0.0, 0.0), (0.21, 0.3), (-0.4, 1.0)]:
        _, weights = actuation_weights(delay, tau, DT)
        assert math.isclose(float(np.sum(weights)), 1.0, rel_tol=0, abs_tol=1e-14)
    with pytest.raises(ValueError, match="time constant"):
        actuation_weights(0.0, -0.1, DT)


def test_config_timing_section_and_errors():
    config = load_config("type1", {"timing.grs_stamp": "midpoint", "timing.actuation_latency_s": 0.1})
    assert config.timing.grs_stamp == pytest.approx(-0.05)
    assert config.timing.reduced == pytest.approx((0.05, 0.05, 0.0))
    assert load_config(config.to_dict()).timing == config.timing
    with pytest.raises(ConfigError, match=r"timing\.grs_stamp"):
        load_config("type1", {"timing.grs_stamp": "begin"})
    with pytest.raises(ConfigError, match=r"timing\.thruster_time_constant_s"):
        load_config("type1", {"timing.thruster_time_constant_s": -1.0})


def test_start_convention_is_the_end_convention_one_sample_earlier():
    # noise-free: a GRS stamped at the start of its interval reads, at t_k, what the default reads
    # at t_{k+1}; the star tracker is unchanged (instantaneous at its stamp in both)
    # (the maneuver starts after the first sample, so both runs start from the same state)
    window = {"maneuver.start_s": 1.0, "maneuver.duration_s": 600.0, **QUIET}
    base_config = load_config("type1", window)
    start_config = load_config("type1", {**window, "timing.grs_stamp": "start"})
    commands = maneuver_torque_commands(base_config)
    base = simulate_batch(base_config, 1, commands)
    start = simulate_batch(start_config, 1, commands)
    scale = np.max(np.abs(base.voltages_v))
    # both propagate the same trajectory in a different order of operations (rounding, ~1e-12 relative)
    assert np.max(np.abs(start.voltages_v[:-1] - base.voltages_v[1:])) < 1e-9 * scale
    angle = 2.0 * np.max(np.abs(start.st_quat_xyzw[:, :3] - base.st_quat_xyzw[:, :3]))
    rate = np.max(np.abs(base.truth.omega_rad_s))
    # read at the same instant: the offset follows the rate without the gyroscopic term (|w x Jw| /
    # |tau| ~ 3e-5 here), so the bound is a thousandth of one step's rotation (one sample off: all of it)
    assert angle < 1e-3 * rate * DT


def test_streaming_equals_batch_with_positive_delay_and_lag():
    config = load_config("type1", {"maneuver.duration_s": 300.0, "timing.actuation_latency_s": 0.13,
                                   "timing.thruster_time_constant_s": 0.2})
    commands = maneuver_torque_commands(config)
    batch = simulate_batch(config, 5, commands)
    simulator = Simulator(config, seed=5)
    assert simulator.lookahead_steps == 0
    parts = [simulator.advance(commands[i:i + 13]) for i in range(0, commands.shape[0], 13)]
    streamed = np.concatenate([part.voltages_v for part in parts])
    assert np.array_equal(streamed, batch.voltages_v)


def test_timing_effects_add_to_the_configuration():
    config = load_config("type1", {"timing.actuation_latency_s": 0.1})
    effects = [make_effect("actuation_delay", delay_s=0.05), make_effect("thruster_response", time_constant_s=0.3),
               make_effect("grs_time_offset", offset_s=-0.02)]
    timing = Simulator(config, seed=1, effects=effects).timing
    assert timing.actuation_latency_s == pytest.approx(0.15)
    assert timing.thruster_time_constant_s == pytest.approx(0.3)
    assert timing.grs_stamp == pytest.approx(-0.02)
    assert Simulator(config, seed=1, effects=[make_effect("grs_time_offset", offset_s=-0.2)]).lookahead_steps == 2
