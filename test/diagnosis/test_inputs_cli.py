"""Raw input preparation (bad input counted or refused in one line) and the ``taiji2 diagnose`` verb."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

try:
    import taiji2_estimator_pkg.diagnosis  # noqa: F401
except ImportError:  # an editable install made before the package had modules
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src" / "taiji2_estimator_pkg"))

from taiji2_apps.cli import diagnose as verb
from taiji2_estimator_pkg.core.attitude import quat_conjugate, quat_multiply, rotvec_from_quat
from taiji2_estimator_pkg.diagnosis import InputError, align_streams, commands_on_grid, prepare_input
from taiji2_estimator_pkg.epochs import UndeterminedError


def _arrays(n=1200, seed=3, effects=()):
    config = load_config("type1")
    commands = maneuver_torque_commands(config, n)
    out = simulate_batch(config, seed, commands, effects=[make_effect(**e) for e in effects])
    return out, commands


def test_prepare_input_counts_bridges_short_gaps_and_keeps_the_longest_segment():
    out, commands = _arrays()
    q = out.st_quat_xyzw.copy()
    v = out.voltages_v.copy()
    t = out.t_s.copy()
    q[100] = np.nan  # a bad quaternion
    v[700, 1, 3] = np.inf  # a bad voltage
    q[900] *= 1.01  # not unit norm
    inp = prepare_input(t, q, v, commands, 10.0)
    assert inp.rejected == {"nan_or_inf": 2, "non_unit_quaternion": 1}
    # each bad value removes its own stream's sample; a gap of 1 sample is bridged: every sample used
    assert inp.bridged == {"star_tracker": 2, "grs2": 1} and inp.n == 1200
    np.testing.assert_allclose(inp.t_s, t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(inp.voltages_v[:700], v[:700])
    # the bridged attitude is within the star tracker's noise of the reading removed (0.2 arcsec = 1e-6 rad)
    change = quat_multiply(quat_conjugate(out.st_quat_xyzw[100]), inp.st_quat_xyzw[100])
    angle = np.linalg.norm(rotvec_from_quat(change))
    assert angle < 5e-6
    # a gap longer than 5 s (60 GRS1 samples) ends a segment: the longest one is used, the rest counted
    v[300:360, 0] = np.nan
    inp = prepare_input(t, q, v, commands, 10.0)
    assert inp.n == 1200 - 360
    np.testing.assert_allclose(inp.t_s, t[360:], rtol=0, atol=1e-9)
    assert inp.rejected["outside_run"] == 300 and inp.rejected["unmatched"] == 60
    # sign flips of the quaternion are the same attitude: made continuous
    q2 = out.st_quat_xyzw.copy()
    q2[500:] *= -1.0
    flipped = prepare_input(t, q2, out.voltages_v, commands, 10.0)
    np.testing.assert_allclose(flipped.st_quat_xyzw, out.st_quat_xyzw / np.linalg.norm(out.st_quat_xyzw, axis=1,
                                                                                         keepdims=True), atol=1e-15)


def test_prepare_input_duplicates_disorder_and_shapes():
    out, commands = _arrays(200)
    t = out.t_s.copy()
    t[50] = t[49]  # duplicate stamp
    t[120], t[121] = t[121], t[120]  # disorder
    inp = prepare_input(t, out.st_quat_xyzw, out.voltages_v, commands, 10.0)
    # the epoch rule: the repeated stamp refused in each stream (its epoch 5.0 s bridged), the swapped rows
    # sorted by stamp (used, not refused)
    assert inp.rejected == {"duplicate_stamp": 3} and inp.n == 200
    assert inp.bridged == {"star_tracker": 1, "grs1": 1, "grs2": 1}
    np.testing.assert_array_equal(inp.voltages_v[[120, 121]], out.voltages_v[[121, 120]])
    with pytest.raises(InputError, match=r"voltages_v: wrong shape \(200, 12\), expected \(n, 2, 6\)"):
        prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v.reshape(200, 12), commands, 10.0)
    with pytest.raises(InputError, match="torque_cmd_n_m: 10 samples, but t_s has 200"):
        prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands[:10], 10.0)
    with pytest.raises(InputError, match="sample_rate_hz"):
        prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, -1.0)


def test_align_streams_from_separate_stamps():
    out, commands = _arrays(600)
    rng = np.random.default_rng(0)
    jitter = rng.uniform(-0.01, 0.01, size=600)  # stamps within a quarter step of the grid
    st_t = out.t_s + jitter
    g1_t = np.delete(out.t_s, [300]) + 0.002  # one GRS1 sample lost
    g1_v = np.delete(out.voltages_v[:, 0], [300], axis=0)
    cmd_rows = np.arange(0, 600, 10)
    inp = align_streams(st_t, out.st_quat_xyzw, g1_t, g1_v, out.t_s, out.voltages_v[:, 1],
                        out.t_s[cmd_rows] - 0.1, commands[cmd_rows], 10.0)
    assert inp.rejected == {} and inp.n == 600 and inp.bridged == {"grs1": 1}  # the lost sample bridged
    keep = np.arange(600) != 300
    np.testing.assert_array_equal(inp.voltages_v[keep], out.voltages_v[keep])
    # taken from GRS2 through the map between the two GRS: the spacecraft's common acceleration noise comes with
    # it (here 8 mV from the lost sample at most, against 74 mV for the mean of its neighbours)
    midpoint = 0.5 * (out.voltages_v[299, 0] + out.voltages_v[301, 0])
    error = np.abs(inp.voltages_v[300, 0] - out.voltages_v[300, 0])
    assert np.max(error) < 0.25 * np.max(np.abs(midpoint - out.voltages_v[300, 0]))
    np.testing.assert_array_equal(inp.torque_cmd_n_m, commands[np.arange(600) // 10 * 10])  # ZOH of the 1 Hz stream
    # the diagnosis's grid is the star tracker's instants: the GRS (1 ms on average) against it
    assert abs(inp.stamp_phase_s["grs"] - (0.001 - (inp.t_s[0] - out.t_s[0]))) < 1e-6
    held = commands_on_grid([0.0, 5.0], [[1.0, 0, 0], [2.0, 0, 0]], [0.05, 0.1, 5.07, 5.2], 10.0)
    np.testing.assert_array_equal(held[:, 0], [0.0, 1.0, 1.0, 2.0])
    with pytest.raises(UndeterminedError, match=r"^grs1: no valid sample$"):
        align_streams(st_t, out.st_quat_xyzw, g1_t, g1_v * np.nan, out.t_s, out.voltages_v[:, 1], [0.0],
                      [[0.0, 0.0, 0.0]], 10.0)


def _args(bag, out, *extra):
    parser = argparse.ArgumentParser()
    verb.add_arguments(parser)
    return parser.parse_args([str(bag), "--out", str(out), "--quiet", *extra])


def _write_npz(path, n, seed, effects=()):
    out, commands = _arrays(n, seed, effects)
    np.savez(path, t_s=out.t_s, st_quat_xyzw=out.st_quat_xyzw, voltages_v=out.voltages_v, torque_cmd_n_m=commands)


def test_cli_npz_with_effect_and_json(tmp_path, capsys):
    _write_npz(tmp_path / "run.npz", 27000, 51, [{"name": "time_offset", "offset_s": 0.3}])
    status = verb.main(_args(tmp_path / "run.npz", tmp_path / "out", "--json", "--no-plots"))
    assert status == 0
    report = json.loads(capsys.readouterr().out)
    assert report["verdict"]["effects"] == ["time_offset"]
    assert (tmp_path / "out" / "report.md").exists()


def test_cli_short_and_bad_inputs(tmp_path, capsys):
    _write_npz(tmp_path / "short.npz", 2000, 52)
    assert verb.main(_args(tmp_path / "short.npz", tmp_path / "o1")) == 3
    assert "insufficient data" in capsys.readouterr().out
    with pytest.raises(ValueError, match="no such bag"):
        verb.main(_args(tmp_path / "missing", tmp_path / "o2"))
    np.savez(tmp_path / "bad.npz", t_s=np.arange(10.0))
    with pytest.raises(ValueError, match="missing arrays st_quat_xyzw"):
        verb.main(_args(tmp_path / "bad.npz", tmp_path / "o3"))
    with pytest.raises(ValueError, match="unknown effect family 'nope'"):
        verb.main(_args(tmp_path / "short.npz", tmp_path / "o4", "--exclude", "nope"))
    (tmp_path / "notabag").mkdir()
    with pytest.raises(ValueError):
        verb.main(_args(tmp_path / "notabag", tmp_path / "o5"))


def _write_bag(path, n, seed):
    """A contract bag of a simulated run, written as the recorder would (header stamp = measurement time)."""
    from taiji2_runtime.bag.bulk_decode import encode_messages
    from taiji2_runtime.bag.writer import BagWriter
    from taiji2_runtime.interfaces import typestore

    out, commands = _arrays(n, seed)
    store = typestore()
    ns = np.round(out.t_s * 1e9).astype(np.int64)
    sec, nsec = ns // 10**9, ns % 10**9
    st = encode_messages(store, "taiji2_msgs/msg/StarTracker", {
        "header.stamp.sec": sec, "header.stamp.nanosec": nsec, "header.frame_id": "crf",
        **{f"attitude.{a}": out.st_quat_xyzw[:, i] for i, a in enumerate("xyzw")},
        "attitude_covariance": out.st_cov_rad2}, n)
    grs = [encode_messages(store, "taiji2_msgs/msg/GrsVoltages", {
        "header.stamp.sec": sec, "header.stamp.nanosec": nsec, "header.frame_id": f"tmrf{i + 1}", "grs_id": i + 1,
        **{k: out.voltages_v[:, i, j] for j, k in enumerate(("vx1", "vx2", "vy1", "vy2", "vz1", "vz2"))}}, n)
        for i in range(2)]
    changes = np.flatnonzero(np.any(np.diff(commands, axis=0) != 0.0, axis=1)) + 1
    rows = np.union1d(np.arange(0, n, 10), changes)  # the contract: at each change, and at least 1 Hz
    cmd_ns = np.round((out.t_s[rows] - 0.1) * 1e9).astype(np.int64)
    cmd = encode_messages(store, "geometry_msgs/msg/WrenchStamped", {
        "header.stamp.sec": cmd_ns // 10**9, "header.stamp.nanosec": cmd_ns % 10**9, "header.frame_id": "crf",
        **{f"wrench.torque.{a}": commands[rows, i] for i, a in enumerate("xyz")}}, len(rows))
    writer = BagWriter(path, store, segment_period_s=1e9)
    handles = [writer.add_topic(t, m) for t, m in (
        ("/taiji2/star_tracker", "taiji2_msgs/msg/StarTracker"),
        ("/taiji2/grs1/voltages", "taiji2_msgs/msg/GrsVoltages"),
        ("/taiji2/grs2/voltages", "taiji2_msgs/msg/GrsVoltages"),
        ("/taiji2/maneuver/command", "geometry_msgs/msg/WrenchStamped"))]
    position = {int(row): i for i, row in enumerate(rows)}
    for k in range(n):
        if k in position:
            writer.write(handles[3], int(ns[k]), cmd[position[k]])
        writer.write(handles[0], int(ns[k]), st[k])
        writer.write(handles[1], int(ns[k]), grs[0][k])
        writer.write(handles[2], int(ns[k]), grs[1][k])
    writer.close()


def test_cli_on_a_recorded_bag(tmp_path, capsys):
    pytest.importorskip("taiji2_runtime.bag.writer")
    _write_bag(tmp_path / "bag", 12000, 53)
    status = verb.main(_args(tmp_path / "bag", tmp_path / "out"))
    assert status == 0
    assert "verdict: no significant gap" in capsys.readouterr().out
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["inputs"]["samples"] == 12000 and report["inputs"]["rejected_total"] == 0
    assert (tmp_path / "out" / "gap_map.png").exists()
