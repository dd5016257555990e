"""The diagnosis on a record with samples lost at random uses every sample received (gaps bridged, counted)."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis import align_streams, diagnose
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

N = 12000  # 20 min at 10 Hz


def _diagnosed(keep, seed=53):
    """Diagnose the record with the samples of ``keep`` (stream -> (N,) bool) received, each stream played back
    out of order (as the deep_space link delivers), the commands at each change and at least 1 Hz."""
    config = load_config("type1")
    commands = maneuver_torque_commands(config, N)
    out = simulate_batch(config, seed, commands)
    rng = np.random.default_rng(1)
    order = {name: rng.permutation(np.flatnonzero(k)) for name, k in keep.items()}
    t = out.t_s
    changes = np.flatnonzero(np.any(np.diff(commands, axis=0) != 0.0, axis=1)) + 1
    rows = np.union1d(np.arange(0, N, 10), changes)  # the contract: at each change, and at least 1 Hz
    inp = align_streams(t[order["star_tracker"]], out.st_quat_xyzw[order["star_tracker"]],
                        t[order["grs1"]], out.voltages_v[order["grs1"], 0],
                        t[order["grs2"]], out.voltages_v[order["grs2"], 1],
                        t[rows] - config.dt_s, commands[rows], config.sample_rate_hz)
    return inp, diagnose(inp, config)


def _ends_kept(keep):
    return {name: k | (np.arange(N) < 10) | (np.arange(N) >= N - 1) for name, k in keep.items()}


def test_two_percent_of_samples_lost_at_random_are_bridged_and_the_record_diagnosed():
    rng = np.random.default_rng(8)
    keep = _ends_kept({name: rng.random(N) > 0.02 for name in ("star_tracker", "grs1", "grs2")})
    lost = {name: int(np.count_nonzero(~k)) for name, k in keep.items()}
    assert all(200 < n < 280 for n in lost.values())  # 2 % of 12000, 4.5 sigma
    inp, result = _diagnosed(keep)
    # every sample received is used: each lost one bridged, none refused, one segment of all N epochs
    assert inp.n == N and inp.rejected == {} and inp.bridged == lost
    assert result.status == "ok", result.verdict
    assert result.inputs["samples"] == N and result.inputs["bridged"] == lost
    # the bridged samples (no noise of their own, 2 % of each stream) do not read as a gap of the model
    assert result.verdict["summary"] == "no significant gap"


def test_the_deep_space_links_random_and_burst_losses_are_bridged_and_the_record_diagnosed():
    """1 % of the packets lost at random, and Gilbert-Elliott bursts of mean 10 packets on the one channel the
    four APIDs share (config/link.yaml, deep_space): every stream loses the same spans."""
    rng = np.random.default_rng(9)
    keep = {name: rng.random(N) > 0.01 for name in ("star_tracker", "grs1", "grs2")}
    for start in np.flatnonzero(rng.random(4 * N) < 0.001):  # packet index of a burst's start, 4 APIDs
        stop = start + rng.geometric(0.1)
        for k in keep.values():
            k[start // 4: stop // 4 + 1] = False
    keep = _ends_kept(keep)
    lost = {name: int(np.count_nonzero(~k)) for name, k in keep.items()}
    inp, result = _diagnosed(keep)
    assert inp.n == N and inp.rejected == {} and inp.bridged == lost
    assert result.status == "ok" and result.verdict["summary"] == "no significant gap", result.verdict



def test_link_losses_are_missing_samples_not_a_gap_and_a_command_lost_at_its_change_is_placed():
    """The deep_space pattern with the command rows lost too (issue 43): what read as spurious windows over 3 h.

    Every stream, the 10 Hz command rows included (the link loses their packets as well), loses 1 % at random and
    the same Gilbert-Elliott bursts (mean 10 packets of the four APIDs) at twice the link's rate: ~3.7 % of each
    stream over 20 min (unclipped readout: the preset leaves the GRS range, which the saturation would clip).
    Seed 11 loses two command changes with their rows, one inside a GRS gap. Before, a lost change was held to
    the next row received (one epoch late: ~100 sigma in the torque channel) and read as an unexplained torque_z
    1-5 Hz window at 781 s (significance 428 against a threshold of 5); now the change is put at the
    epoch the GRS step shows (in the middle of the GRS gap when hidden there, its epochs marked), every sample
    received is used (one segment, each lost sample bridged and counted), the location scan treats the
    estimated epochs as missing, and the verdict is ``no significant gap`` (largest location 2.7; tolerance:
    the Bonferroni threshold, 1 % family-wise).
    """
    rng = np.random.default_rng(11)
    names = ("star_tracker", "grs1", "grs2", "command")
    keep = {name: rng.random(N) > 0.01 for name in names}
    for start in np.flatnonzero(rng.random(4 * N) < 0.002):  # packet index of a burst's start, 4 APIDs
        stop = start + rng.geometric(0.1)
        for k in keep.values():
            k[start // 4: stop // 4 + 1] = False
    keep = _ends_kept(keep)
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, N)
    changes = np.flatnonzero(np.any(np.diff(commands, axis=0) != 0.0, axis=1)) + 1
    assert np.count_nonzero(~keep["command"][changes]) == 2  # the seed loses two changes with their rows
    out = simulate_batch(config, 53, commands)
    t = out.t_s
    order = {name: rng.permutation(np.flatnonzero(k)) for name, k in keep.items()}  # played back out of order
    rows = order["command"]
    inp = align_streams(t[order["star_tracker"]], out.st_quat_xyzw[order["star_tracker"]],
                        t[order["grs1"]], out.voltages_v[order["grs1"], 0],
                        t[order["grs2"]], out.voltages_v[order["grs2"], 1],
                        t[rows] - config.dt_s, commands[rows], config.sample_rate_hz)
    lost = {name: int(np.count_nonzero(~keep[name])) for name in names[:3]}
    assert all(380 < n < 520 for n in lost.values())  # ~3.7 % of each stream
    # every sample received used: one segment of all N epochs, each lost sample bridged and counted
    assert inp.n == N and inp.rejected == {} and inp.bridged == lost
    received = keep["star_tracker"] & keep["grs1"] & keep["grs2"]
    assert np.array_equal(inp.filled, ~received | (inp.filled & received))  # every bridged epoch marked
    assert np.count_nonzero(inp.filled & received) <= 10  # epochs whose command is in doubt
    # the commands flown, on every epoch whose command is not in doubt
    assert np.array_equal(inp.torque_cmd_n_m[~inp.filled], commands[~inp.filled])
    result = diagnose(inp, config)
    assert result.status == "ok" and result.inputs["samples"] == N
    assert result.verdict["summary"] == "no significant gap", result.verdict
    assert result.locations[0].significance < result.location_threshold


def test_the_angular_acceleration_both_grs_lost_is_in_the_noise_model_not_a_star_tracker_gap():
    """One hour of the same pattern (seed 12): 3 % of the epochs lost by both GRS and three command changes hidden
    in their gaps. The bridged angular acceleration lacks the spacecraft's own noise and a hidden change is
    placed to within its gap only, so the rate the star-tracker channel integrates is uncertain there
    (:mod:`taiji2_estimator_pkg.diagnosis.angular_gaps`). Before that uncertainty was in the noise model, this
    record read "unexplained gap at st_x, st_y, st_z 1-3 mHz" (significance 11.7 against a threshold of 5.2;
    star-tracker low-frequency noise delta chi2 106); a 24-h deep_space recording read the same at 0.1-1 mHz."""
    n = 36000
    rng = np.random.default_rng(12)
    names = ("star_tracker", "grs1", "grs2", "command")
    keep = {name: rng.random(n) > 0.01 for name in names}
    for start in np.flatnonzero(rng.random(4 * n) < 0.002):
        stop = start + rng.geometric(0.1)
        for k in keep.values():
            k[start // 4: stop // 4 + 1] = False
    for k in keep.values():
        k[:10] = True
        k[-1] = True
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, n)
    out = simulate_batch(config, 62, commands)
    t = out.t_s
    order = {name: rng.permutation(np.flatnonzero(k)) for name, k in keep.items()}
    inp = align_streams(t[order["star_tracker"]], out.st_quat_xyzw[order["star_tracker"]],
                        t[order["grs1"]], out.voltages_v[order["grs1"], 0],
                        t[order["grs2"]], out.voltages_v[order["grs2"], 1],
                        t[order["command"]] - config.dt_s, commands[order["command"]], config.sample_rate_hz)
    weight, torque_cov = inp.angular_loss
    assert weight > 0.05 and inp.command_doubt is not None and np.trace(torque_cov) > 0.0
    result = diagnose(inp, config)
    assert result.status == "ok" and result.verdict["summary"] == "no significant gap", result.verdict
    assert result.locations[0].significance < result.location_threshold
