"""GRS readout model: coupling term, TMRF rotation, voltage conversion and its inverse."""

import numpy as np
import pytest

from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
from taiji2_model.frames import crf_to_tmrf
from taiji2_model.grs import (
    a_tilde_matrix,
    accelerations_from_voltages,
    coupling_acceleration_m_s2,
    voltages_from_accelerations,
)
from taiji2_model.noise import white_noise_std
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

N_STEPS = 6000  # 10 min: several maneuver edges on every axis


def run(layout, enabled=NOISE_SOURCE_NAMES, seed=11):
    overrides = {f"noise.{name}.enabled": name in enabled for name in NOISE_SOURCE_NAMES}
    cfg = load_config(layout, overrides=overrides)
    return cfg, simulate_batch(cfg, seed, maneuver_torque_commands(cfg, N_STEPS))


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_coupling_term_equals_cross_product_form(layout):
    """grs_linear_maneuver = C_i (omega_dot x d_i + w_m x (w_m x d_i)) to 1e-15 relative (all noise on,
    so the rates carry thruster torque noise); the same with the paper's printed matrix A~."""
    cfg, out = run(layout)
    truth = out.truth
    omega = np.vstack((cfg.spacecraft.initial_rate_rad_s, truth.omega_rad_s))
    omega_mid = 0.5 * (omega[:-1] + omega[1:])
    for i, sensor in enumerate(cfg.grs.sensors):
        c = crf_to_tmrf(sensor.grs_id, np.radians(60.0))
        d = sensor.com_offset_m
        reference = (np.cross(truth.omega_dot_rad_s2, d) + np.cross(omega_mid, np.cross(omega_mid, d))) @ c.T
        scale = np.linalg.norm(reference, axis=1, keepdims=True)
        assert np.max(np.abs(truth.grs_linear_maneuver[:, i] - reference) / scale) <= 1e-15
        paper = np.einsum("nij,j->ni", a_tilde_matrix(omega_mid, truth.omega_dot_rad_s2), d) @ c.T
        assert np.max(np.abs(paper - reference) / scale) <= 1e-15
        # linear truth adds a_SC; angular truth is C_i (omega_{k+1} - omega_k) / dt
        np.testing.assert_allclose(truth.grs_linear_true[:, i], (truth.a_sc_m_s2 @ c.T) + reference,
                                   rtol=0, atol=1e-15 * np.max(np.abs(truth.grs_linear_true)))
        difference = np.diff(omega, axis=0) / cfg.dt_s @ c.T
        np.testing.assert_allclose(truth.grs_angular_true[:, i], difference,
                                   rtol=0, atol=1e-9 * np.max(np.abs(difference)))


def test_coupling_function_against_explicit_components():
    w, a, d = np.array([1e-6, -2e-6, 3e-6]), np.array([2e-9, 5e-9, -1e-9]), np.array([0.2164, 0.1251, 2e-4])
    explicit = np.array([
        a[1] * d[2] - a[2] * d[1] + w[0] * (w @ d) - d[0] * (w @ w),
        a[2] * d[0] - a[0] * d[2] + w[1] * (w @ d) - d[1] * (w @ w),
        a[0] * d[1] - a[1] * d[0] + w[2] * (w @ d) - d[2] * (w @ w),
    ])
    np.testing.assert_allclose(coupling_acceleration_m_s2(a, w, d), explicit, rtol=1e-14)


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_voltages_invert_to_the_accelerations(layout):
    """Without voltage noise, the paper's conversion of the simulated voltages with the configured
    scale factors returns the measured accelerations (1e-13 relative, rounding of the solve), the
    linear ones saturated at the range (grs.readout_saturation, on by default)."""
    enabled = tuple(n for n in NOISE_SOURCE_NAMES if n != "grs_voltage")
    cfg, out = run(layout, enabled)
    for i, sensor in enumerate(cfg.grs.sensors):
        angular, linear = accelerations_from_voltages(out.voltages_v[:, i], sensor.angular_scale_factors,
                                                      sensor.linear_scale_factors)
        np.testing.assert_allclose(angular, out.truth.grs_angular_meas[:, i], rtol=0,
                                   atol=1e-13 * np.max(np.abs(out.truth.grs_angular_meas)))
        limit = cfg.grs.range_m_s2
        np.testing.assert_allclose(linear, np.clip(out.truth.grs_linear_meas[:, i], -limit, limit), rtol=0,
                                   atol=1e-13 * np.max(np.abs(out.truth.grs_linear_meas)))
        np.testing.assert_array_equal(out.truth.grs_angular_scale_factors[:, i],
                                      np.broadcast_to(sensor.angular_scale_factors, (N_STEPS, 3)))


def test_conversion_formulas_channel_by_channel():
    rng = np.random.default_rng(3)
    angular, linear = rng.standard_normal((100, 3)) * 5e-9, rng.standard_normal((100, 3)) * 1e-9
    g_ang = np.array([5.524e-8, 5.524e-8, 7.365e-8])
    g_lin = np.array([2.2586e-9, 1.694e-9, 1.694e-9])
    v = voltages_from_accelerations(angular, linear, g_ang, g_lin)
    vx1, vx2, vy1, vy2, vz1, vz2 = v.T
    np.testing.assert_allclose(g_ang[0] * (vy1 - vy2), angular[:, 0], rtol=1e-12)
    np.testing.assert_allclose(g_ang[1] * (vz1 - vz2), angular[:, 1], rtol=1e-12)
    np.testing.assert_allclose(g_ang[2] * (vx1 - vx2), angular[:, 2], rtol=1e-12)
    np.testing.assert_allclose(g_lin[0] * (vx1 + vx2), linear[:, 0], rtol=1e-12)
    np.testing.assert_allclose(g_lin[1] * (vy1 + vy2), linear[:, 1], rtol=1e-12)
    np.testing.assert_allclose(g_lin[2] * (vz1 + vz2), linear[:, 2], rtol=1e-12)
    back = accelerations_from_voltages(v, g_ang, g_lin)
    np.testing.assert_allclose(back[0], angular, rtol=1e-12)
    np.testing.assert_allclose(back[1], linear, rtol=1e-12)


def test_voltage_noise_has_the_linear_equivalent_level():
    """Per channel white noise of ASD S/(sqrt(2) G_lin): the sum pair converted with G_lin has the
    per-sample std S sqrt(fs/2) = 4.9e-14 m/s^2 (tolerance 3 % at 2 x 6000 x 3 samples; the std
    estimate's own 1-sigma is 0.5 %)."""
    cfg, out = run("type1", ("grs_voltage",))
    expected = white_noise_std(cfg.noise.grs_voltage.linear_equivalent_asd_m_s2_rthz, cfg.sample_rate_hz)
    for i, sensor in enumerate(cfg.grs.sensors):
        _, linear = accelerations_from_voltages(out.voltages_v[:, i], sensor.angular_scale_factors,
                                                sensor.linear_scale_factors)
        residual = linear - out.truth.grs_linear_meas[:, i]
        np.testing.assert_allclose(residual.std(axis=0), expected, rtol=0.03)
