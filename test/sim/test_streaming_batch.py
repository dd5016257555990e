"""Streaming (step by step) equals batch (whole run) for the same seed; streams are independent."""

from dataclasses import fields

import numpy as np
import pytest

from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
from taiji2_model.effects import Effect
from taiji2_model.noise import NoiseStreams
from taiji2_sim_pkg.core.simulator import SimOutput, Simulator, maneuver_torque_commands, simulate_batch

N_STEPS = 3000  # 5 min at 10 Hz, several edges per axis
SEED = 20240917


def _relative_max(a, b):
    scale = max(np.max(np.abs(a)), np.max(np.abs(b)))
    return 0.0 if scale == 0 else float(np.max(np.abs(a - b)) / scale)


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_streaming_equals_batch_all_noise_on(layout):
    """States and readouts to 1e-12 relative (of each field's max), noise draws bitwise."""
    cfg = load_config(layout)
    commands = maneuver_torque_commands(cfg, N_STEPS)
    batch = simulate_batch(cfg, SEED, commands)
    sim = Simulator(cfg, seed=SEED)
    samples = [sim.step(commands[k]) for k in range(N_STEPS)]
    stream = SimOutput.concatenate([
        SimOutput(np.array([s.t_s]), s.st_quat_xyzw[None], s.st_cov_rad2[None], s.voltages_v[None],
                  type(s.truth)(**{f.name: getattr(s.truth, f.name)[None] for f in fields(s.truth)}))
        for s in samples
    ])
    np.testing.assert_array_equal(stream.t_s, batch.t_s)
    np.testing.assert_array_equal(stream.st_cov_rad2, batch.st_cov_rad2)
    for field in fields(batch.truth):
        name = field.name
        assert _relative_max(getattr(stream.truth, name), getattr(batch.truth, name)) <= 1e-12, name
    assert _relative_max(stream.voltages_v, batch.voltages_v) <= 1e-12
    assert np.max(np.abs(stream.st_quat_xyzw - batch.st_quat_xyzw)) <= 1e-12  # |q| = 1
    # the noise itself is bitwise identical: torque noise = applied - command
    np.testing.assert_array_equal(stream.truth.torque_applied_n_m - commands,
                                  batch.truth.torque_applied_n_m - commands)
    np.testing.assert_array_equal(stream.truth.a_sc_m_s2, batch.truth.a_sc_m_s2)
    assert sim.step_index == N_STEPS and sim.time_s == pytest.approx(N_STEPS * cfg.dt_s, rel=1e-15)


def test_noise_draws_are_bitwise_identical_in_any_blocking():
    cfg = load_config("type2")
    one_go = NoiseStreams(cfg, SEED).draw(1000)
    streams = NoiseStreams(cfg, SEED)
    blocks = [streams.draw(n) for n in (1, 1, 7, 250, 1, 740)]
    for field in fields(one_go):
        joined = np.concatenate([getattr(b, field.name) for b in blocks])
        np.testing.assert_array_equal(joined, getattr(one_go, field.name), err_msg=field.name)


def test_advance_in_blocks_equals_one_batch():
    cfg = load_config("type1")
    commands = maneuver_torque_commands(cfg, 2000)
    batch = simulate_batch(cfg, SEED, commands)
    sim = Simulator(cfg, seed=SEED)
    parts = [sim.advance(commands[:700]), sim.advance(commands[700:701]), sim.advance(commands[701:])]
    joined = SimOutput.concatenate(parts)
    assert _relative_max(joined.truth.omega_rad_s, batch.truth.omega_rad_s) <= 1e-12
    assert _relative_max(joined.voltages_v, batch.voltages_v) <= 1e-12
    assert len(joined) == 2000 and joined[1999].t_s == batch.t_s[-1]


def test_switching_one_source_off_leaves_the_others_unchanged():
    cfg_all = load_config("type1")
    cfg_no_st = load_config("type1", overrides={"noise.star_tracker.enabled": False,
                                                "noise.thruster_force.enabled": False})
    a = NoiseStreams(cfg_all, SEED).draw(500)
    b = NoiseStreams(cfg_no_st, SEED).draw(500)
    for name in ("thruster_torque_n_m", "srp_m_s2", "lfs_translational_m_s2", "lfs_rotational_rad_s2",
                 "tm_environment_m_s2", "grs_voltage_v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert np.all(b.star_tracker_rad == 0.0) and np.all(b.thruster_force_n == 0.0)
    # different seeds differ, equal seeds repeat
    assert not np.array_equal(NoiseStreams(cfg_all, SEED + 1).draw(10).grs_voltage_v, a.grs_voltage_v[:10])
    np.testing.assert_array_equal(NoiseStreams(cfg_all, SEED).draw(10).grs_voltage_v, a.grs_voltage_v[:10])


def test_seed_none_is_recorded_and_reproduces():
    cfg = load_config("type1")
    sim = Simulator(cfg)
    first = sim.step(np.zeros(3))
    again = Simulator(cfg, seed=sim.seed).step(np.zeros(3))
    np.testing.assert_array_equal(first.voltages_v, again.voltages_v)
    prov = sim.provenance()
    assert prov["seed"] == sim.seed and prov["config"] == cfg.to_dict()
    assert set(NOISE_SOURCE_NAMES) == set(prov["config"]["noise"])


def test_bad_commands_are_refused():
    sim = Simulator(load_config("type1"), seed=1)
    with pytest.raises(ValueError, match="torque_cmd_n_m"):
        sim.step([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="torque_cmd_n_m"):
        sim.step([1.0, 0.0])
    assert sim.step_index == 0


class _Bias(Effect):
    """Test effect: a constant torque bias and a scale-factor change on GRS2."""

    name = "test_bias"

    def applied_torque_n_m(self, t_s, torque_n_m):
        return torque_n_m + 1e-6

    def grs_scale_factors(self, t_s, grs_id, angular, linear):
        return (angular * 1.01, linear) if grs_id == 2 else (angular, linear)


def test_effect_hooks_apply_identically_in_streaming_and_batch():
    cfg = load_config("type2")
    commands = maneuver_torque_commands(cfg, 200)
    batch = simulate_batch(cfg, SEED, commands, effects=[_Bias()])
    sim = Simulator(cfg, seed=SEED, effects=[_Bias()])
    last = [sim.step(c) for c in commands][-1]
    plain = simulate_batch(cfg, SEED, commands)
    np.testing.assert_allclose(batch.truth.torque_applied_n_m - 1e-6, plain.truth.torque_applied_n_m,
                               rtol=0, atol=1e-18)
    np.testing.assert_allclose(batch.truth.grs_angular_scale_factors[-1, 1],
                               1.01 * cfg.grs.sensors[1].angular_scale_factors, rtol=1e-15)
    assert _relative_max(last.voltages_v, batch.voltages_v[-1]) <= 1e-12
