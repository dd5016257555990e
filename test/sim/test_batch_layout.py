"""The batch simulator's faster layouts give bitwise the results of the plain formulas they replace.

Component-first (3, n) rows in the attitude solve, per-component matrix products (zero entries
skipped), chunked readouts written into the output arrays and per-source noise draws change where
numbers live in memory, not which floating-point operations produce each of them; these tests hold
every output bit to the (n, 3)-layout formulas the simulator used before. The one exception is the
quaternion scan: its association by step index (:class:`AttitudeScan`) differs from any earlier
one, so the attitude is held to the left-to-right product within its rounding bound.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

import taiji2_sim_pkg.core.simulator as simulator
from taiji2_model.config import load_config
from taiji2_model.effects import Effect
from taiji2_model.frames import apply_matrix, cross, quat_from_rotvec, quat_multiply
from taiji2_model.noise import NoiseStreams
from taiji2_sim_pkg.core.attitude_scan import AttitudeScan
from taiji2_sim_pkg.core.dynamics import propagate_attitude
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands

SEED = 4242


def _apply_matrix_broadcast(m, v):  # the former apply_matrix
    m, v = np.asarray(m, dtype=np.float64), np.asarray(v, dtype=np.float64)
    vx, vy, vz = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    if m.ndim == 2:
        return vx * m[:, 0] + vy * m[:, 1] + vz * m[:, 2]
    return vx * m[..., :, 0] + vy * m[..., :, 1] + vz * m[..., :, 2]


def _solve_block_nx3(omega_start, torque, inertia, inertia_inv, dt_s):  # the former Picard solve
    count = torque.shape[0]
    stacked = np.empty((count + 1, 3))
    stacked[0] = omega_start
    gyroscopic = np.zeros((count, 3))
    previous, previous_change = None, np.inf
    for _ in range(40):
        omega_dot = _apply_matrix_broadcast(inertia_inv, torque - gyroscopic)
        stacked[1:] = dt_s * omega_dot
        omega = np.cumsum(stacked, axis=0)
        omega_mid = 0.5 * (omega[:-1] + omega[1:])
        gyroscopic = cross(omega_mid, _apply_matrix_broadcast(inertia, omega_mid))
        if previous is not None:
            change = float(np.max(np.abs(omega[1:] - previous)))
            scale = float(np.max(np.abs(omega)))
            if change <= 8.0 * np.finfo(np.float64).eps * scale or not change < previous_change:
                return omega[1:], omega_mid, omega_dot
            previous_change = change
        previous = omega[1:]
    raise AssertionError("no convergence")


def _sequential_product(initial, q):  # q_init q_0 ... q_k, left to right (the streaming simulator's order)
    out = np.empty_like(q)
    current = np.asarray(initial, dtype=np.float64)
    for k in range(q.shape[0]):
        current = quat_multiply(current, q[k])
        out[k] = current
    return out


#: A product of unit quaternions rounds each component by at most 4 eps (a sum of four products of
#: numbers <= 1); the error of a chain of n products grows at most linearly: 4 eps n per chain, and
#: the scan and the left-to-right product are two different chains.
def _product_chain_bound(n):
    return 2 * 4 * np.finfo(np.float64).eps * n


@pytest.mark.parametrize("shape", [(3,), (1000, 3), (500, 2, 3)])
def test_apply_matrix_is_bitwise_the_broadcast_formula(shape):
    rng = np.random.default_rng(1)
    v = rng.standard_normal(shape)
    m = rng.standard_normal((3, 3))
    np.testing.assert_array_equal(apply_matrix(m, v), _apply_matrix_broadcast(m, v))
    if len(shape) == 2:
        per_row = rng.standard_normal((shape[0], 3, 3))
        np.testing.assert_array_equal(apply_matrix(per_row, v), _apply_matrix_broadcast(per_row, v))


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_attitude_solve_and_scan_are_bitwise_the_nx3_formulas(layout):
    cfg = load_config(layout)
    torque = maneuver_torque_commands(cfg, 20000) + 1e-5 * np.random.default_rng(2).standard_normal((20000, 3))
    inertia = np.asarray(cfg.spacecraft.inertia_kg_m2)
    omega0 = np.array([1e-4, -2e-4, 5e-5])
    got = propagate_attitude([0.0, 0.0, 0.0, 1.0], omega0, torque, inertia, cfg.dt_s)
    omega, omega_mid, omega_dot = _solve_block_nx3(omega0, torque, inertia, np.linalg.inv(inertia), cfg.dt_s)
    np.testing.assert_array_equal(got.omega_rad_s, omega)
    np.testing.assert_array_equal(got.omega_mid_rad_s, omega_mid)
    np.testing.assert_array_equal(got.omega_dot_rad_s2, omega_dot)
    for array in (got.omega_rad_s, got.omega_mid_rad_s, got.omega_dot_rad_s2):
        assert array.flags.c_contiguous  # consumers' reductions sum in memory order
    increments = quat_from_rotvec(omega_mid * cfg.dt_s)
    sequential = _sequential_product([0.0, 0.0, 0.0, 1.0], increments)
    bound = _product_chain_bound(increments.shape[0])
    np.testing.assert_allclose(got.quat_xyzw, sequential, rtol=0, atol=bound)
    np.testing.assert_allclose(AttitudeScan([0.0, 0.0, 0.0, 1.0]).extend(increments), sequential, rtol=0, atol=bound)


@pytest.mark.parametrize("count", [1, 63, 64, 65, 300])
def test_both_solve_layouts_agree_bitwise(count):
    from taiji2_sim_pkg.core.dynamics import _solve_block_rows, _solve_block_vectors

    cfg = load_config("type1")
    inertia = np.asarray(cfg.spacecraft.inertia_kg_m2)
    torque = 1e-4 * np.random.default_rng(count).standard_normal((count, 3))
    args = (np.array([1e-3, -2e-3, 5e-4]), torque, inertia, np.linalg.inv(inertia), cfg.dt_s)
    for a, b in zip(_solve_block_vectors(*args), _solve_block_rows(*args), strict=True):
        np.testing.assert_array_equal(a, b)


def test_per_source_draws_are_bitwise_draw():
    cfg = load_config("type2")
    one_go = NoiseStreams(cfg, SEED).draw(1000)
    streams = NoiseStreams(cfg, SEED)
    by_source = {f.name: f.name for f in fields(one_go)}
    names = {"thruster_torque_n_m": "thruster_torque", "thruster_force_n": "thruster_force", "srp_m_s2": "srp",
             "lfs_translational_m_s2": "lfs_translational", "lfs_rotational_rad_s2": "lfs_rotational",
             "tm_environment_m_s2": "tm_environment", "grs_voltage_v": "grs_voltage",
             "star_tracker_rad": "star_tracker"}
    assert set(names) == set(by_source)
    for field, source in reversed(names.items()):  # any order of the sources, any blocking
        joined = np.concatenate([streams.draw_source(source, n) for n in (1, 600, 399)])
        np.testing.assert_array_equal(joined, getattr(one_go, field), err_msg=field)


def test_chunked_readouts_equal_one_block(monkeypatch):
    """Without effects the readouts go in chunks (the last one partial); with a no-op effect in one
    block: every output bitwise equal."""
    monkeypatch.setattr(simulator, "_READOUT_CHUNK_STEPS", 700)
    cfg = load_config("type1")
    commands = maneuver_torque_commands(cfg, 2500)
    chunked = Simulator(cfg, seed=SEED).advance(commands)
    one_block = Simulator(cfg, seed=SEED, effects=[Effect()]).advance(commands)
    for name in ("t_s", "st_quat_xyzw", "st_cov_rad2", "voltages_v"):
        np.testing.assert_array_equal(getattr(chunked, name), getattr(one_block, name), err_msg=name)
    for field in fields(chunked.truth):
        np.testing.assert_array_equal(getattr(chunked.truth, field.name), getattr(one_block.truth, field.name),
                                      err_msg=field.name)


def test_constant_fields_are_read_only_views_of_the_configured_values():
    """Without effects the covariance, scale factors and offsets are broadcast views (no copies);
    with an effect (which may change them per step) they are arrays of their own."""
    cfg = load_config("type2")
    commands = maneuver_torque_commands(cfg, 50)
    plain = Simulator(cfg, seed=SEED).advance(commands)
    expected = {"grs_angular_scale_factors": [s.angular_scale_factors for s in cfg.grs.sensors],
                "grs_linear_scale_factors": [s.linear_scale_factors for s in cfg.grs.sensors],
                "com_offset_m": [s.com_offset_m for s in cfg.grs.sensors]}
    for name, values in expected.items():
        field = getattr(plain.truth, name)
        assert field.shape == (50, 2, 3) and not field.flags.writeable, name
        np.testing.assert_array_equal(field, np.broadcast_to(np.asarray(values), (50, 2, 3)), err_msg=name)
    assert plain.st_cov_rad2.shape == (50, 9) and not plain.st_cov_rad2.flags.writeable
    with_effect = Simulator(cfg, seed=SEED, effects=[Effect()]).advance(commands)
    assert all(getattr(with_effect.truth, name).flags.writeable for name in expected)
