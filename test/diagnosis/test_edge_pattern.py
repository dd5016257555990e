"""The torque residual's pattern at the command changes (diagnosis/edge_pattern.py): removed at every change of a
repeated step, an impulse at one change kept whole, a rare step left guarded; and an impulse at a command change
of a simulated record found (before, samples within 0.5 s of a change were not searched).

Seeded; tolerances stated where used.
"""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis import diagnose, prepare_input
from taiji2_estimator_pkg.diagnosis.edge_pattern import MIN_REPEATS, remove_edge_pattern
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

H = 5


def test_a_repeated_pattern_leaves_and_an_impulse_at_one_change_stays():
    rng = np.random.default_rng(3)
    n, period = 20000, 250
    command = np.zeros((n, 3))
    for start in range(0, n, 2 * period):  # a square wave on x: 80 rises and 80 falls
        command[start + period:start + 2 * period, 0] = 1e-6
    command[12345:12400, 2] = 5e-7  # one rare step on z (a rise and a fall, each seen once)
    sigma = 1e-10
    torque = sigma * rng.standard_normal((n, 3))
    pattern = 20.0 * sigma * np.outer(np.array([0.0, 0.3, 1.0, -0.6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
                                      [1.0, 0.2, 0.0])
    changes = np.flatnonzero(np.any(np.diff(command, axis=0) != 0.0, axis=1)) + 1
    rises = [k for k in changes if command[k, 0] > command[k - 1, 0]]
    for k in rises:
        torque[k - H:k + H + 1] += pattern
    impulse_at = rises[7]
    torque[impulse_at, 1] += 12.0 * sigma
    cleaned, guarded = remove_edge_pattern(torque, command, H)
    # the pattern (20 sigma) is gone: what stays at the rises is noise, inflated by sqrt(1 + 1/(m - 1)) (m = 40):
    # the rms over ~440 samples within 15 % of sigma (its standard error is ~3.4 %)
    window = np.concatenate([np.arange(k - H, k + H + 1) for k in rises if k != impulse_at])
    assert np.sqrt(np.mean(cleaned[window, :2] ** 2)) < 1.15 * sigma
    # the impulse stays whole (leave-one-out): 12 sigma within 4 of the noise's sigma
    assert abs(cleaned[impulse_at, 1] - 12.0 * sigma) < 4.0 * sigma
    # the rare steps (seen once each, fewer than MIN_REPEATS) keep the guard; the square wave's changes do not
    assert MIN_REPEATS > 1 and guarded[12345] and guarded[12400] and not guarded[rises[3]]


def test_an_impulse_at_a_command_change_is_found():
    """1 h of Type-1 (seed 4; ~14 changes of each of the square wave's six steps, >= MIN_REPEATS), an impulse of
    12 sigma of the per-sample thruster torque noise 0.02 s after a change of the commanded torque: found within
    0.2 s (the issue's tolerance)."""
    config = load_config("type1")
    n = 36000
    commands = maneuver_torque_commands(config, n)
    change = int(np.flatnonzero(np.any(np.diff(commands, axis=0) != 0.0, axis=1))[20]) + 1
    t_change = change / config.sample_rate_hz  # the command of sample k holds over [k dt, (k + 1) dt)
    angular = 12.0 * 1e-7 * np.sqrt(5.0) * 0.1 * np.array([0.48, 0.6, -0.64])  # N m s
    effect = make_effect("impulse", time_s=t_change + 0.02, angular_momentum_n_m_s=angular.tolist())
    out = simulate_batch(config, 4, commands, effects=[effect])
    result = diagnose(prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz),
                      config)
    events = result.impulses["events"]
    assert [abs(e["time_s"] - (t_change + 0.02)) < 0.2 for e in events] == [True], (t_change, events)
