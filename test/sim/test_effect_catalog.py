"""Effect catalog: every effect changes the data where its physics says, and off is bit-identical."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taiji2_model.config import load_config
from taiji2_model.effect_catalog import (
    EFFECTS,
    ActuationDelay,
    ComDrift,
    CrossCoupling,
    EffectParameterError,
    GravityGradient,
    GrsTimeOffset,
    Impulse,
    InertiaError,
    ReadoutNonlinearity,
    ScaleFactorDrift,
    StarTrackerLowFreqNoise,
    ThrusterForceLeakage,
    ThrusterResponse,
    ThrusterTorqueGain,
    TimeOffset,
    TmStiffness,
    effects_from_config,
    make_effect,
    suspension_filter,
)
from taiji2_model.frames import quat_conjugate, quat_multiply, rotvec_from_quat
from taiji2_sim_pkg.core.simulator import Simulator, maneuver_torque_commands, simulate_batch

NOISE = ("thruster_torque", "thruster_force", "srp", "lfs_translational", "lfs_rotational", "tm_environment",
         "grs_voltage", "star_tracker")
N = 3000  # 300 s


@pytest.fixture(scope="module")
def config():
    return load_config("type1")


@pytest.fixture(scope="module")
def quiet():
    return load_config("type1", overrides={f"noise.{s}.enabled": False for s in NOISE})


@pytest.fixture(scope="module")
def commands(config):
    return maneuver_torque_commands(config, N)


@pytest.fixture(scope="module")
def baseline(config, commands):
    return simulate_batch(config, 7, commands)


# name -> (an active instance, which outputs it must change: "st", "grs1", "grs2")
ACTIVE = {
    "scale_factor_drift": (lambda: ScaleFactorDrift(1e-6, grs=2, axis="z"), {"grs2"}),
    "cross_coupling": (lambda: CrossCoupling(1, misalignment_rad=(0, 0, 1e-3), imbalance=(1e-3, 0, 0)), {"grs1"}),
    "time_offset": (lambda: TimeOffset(0.25), {"st"}),
    "star_tracker_lowfreq_noise": (lambda: StarTrackerLowFreqNoise(3e-3), {"st"}),
    "thruster_torque_gain": (lambda: ThrusterTorqueGain(1e-2, axis="x"), {"st", "grs1", "grs2"}),
    "com_drift": (lambda: ComDrift((0, 1e-7, 0), grs=1), {"grs1"}),
    "readout_nonlinearity": (lambda: ReadoutNonlinearity(1e6, grs=2, readout="theta"), {"grs2"}),
    "inertia_error": (lambda: InertiaError((0.01, 0, 0), (0, 5.0, 0)), {"st", "grs1", "grs2"}),
    "gravity_gradient": (lambda: GravityGradient(scale=0.1), {"st", "grs1", "grs2"}),
    "tm_stiffness": (lambda: TmStiffness(1e-5, grs=1, axis="y"), {"grs1"}),
    "thruster_force_leakage": (lambda: ThrusterForceLeakage(np.diag([0.01, 0.0, 0.0])), {"grs1", "grs2"}),
    "actuation_delay": (lambda: ActuationDelay(0.13), {"st", "grs1", "grs2"}),
    "thruster_response": (lambda: ThrusterResponse(0.2), {"st", "grs1", "grs2"}),
    "grs_time_offset": (lambda: GrsTimeOffset(0.05), {"st", "grs1", "grs2"}),
    "impulse": (lambda: Impulse(10.03, (2e-7, 0.0, 0.0), (1e-7, 0.0, 0.0)), {"st", "grs1", "grs2"}),
}


def test_registry_has_the_issue_names():
    required = {"scale_factor_drift", "cross_coupling", "time_offset", "star_tracker_lowfreq_noise",
                "thruster_torque_gain", "com_drift", "readout_nonlinearity", "inertia_error", "gravity_gradient",
                "tm_stiffness"}
    assert required <= set(EFFECTS)
    assert set(ACTIVE) == set(EFFECTS)
    for name, cls in EFFECTS.items():
        assert cls.name == name


@pytest.mark.parametrize("name", sorted(ACTIVE))
def test_effect_changes_expected_outputs_only(name, config, commands, baseline):
    factory, expected = ACTIVE[name]
    out = simulate_batch(config, 7, commands, effects=[factory()])
    changed = {"st": not np.array_equal(out.st_quat_xyzw, baseline.st_quat_xyzw),
               "grs1": not np.array_equal(out.voltages_v[:, 0], baseline.voltages_v[:, 0]),
               "grs2": not np.array_equal(out.voltages_v[:, 1], baseline.voltages_v[:, 1])}
    assert {key for key, value in changed.items() if value} == expected


@pytest.mark.parametrize("name", sorted(ACTIVE))
def test_disabled_or_zero_is_bit_identical(name, config, commands, baseline):
    factory, _ = ACTIVE[name]
    params = {k: v for k, v in factory().to_dict().items() if k not in ("name", "type", "enabled")}
    disabled = make_effect(name, **params, enabled=False)
    zero = {"gravity_gradient": {"scale": 0.0}}.get(name, {})  # the others default to zero magnitude
    for effect in (disabled, make_effect(name, **zero)):
        out = simulate_batch(config, 7, commands, effects=[effect])
        assert np.array_equal(out.voltages_v, baseline.voltages_v)
        assert np.array_equal(out.st_quat_xyzw, baseline.st_quat_xyzw)


@pytest.mark.parametrize("name", ["time_offset", "tm_stiffness", "star_tracker_lowfreq_noise", "gravity_gradient",
                                  "impulse"])
def test_streaming_equals_batch(name, config, commands):
    """Effects with memory give the same data stepped one sample at a time."""
    factory, _ = ACTIVE[name]
    batch = simulate_batch(config, 3, commands[:400], effects=[factory()])
    sim = Simulator(config, seed=3, effects=[factory()])
    steps = [sim.step(c) for c in commands[:400]]
    np.testing.assert_allclose(np.array([s.voltages_v for s in steps]), batch.voltages_v, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.array([s.st_quat_xyzw for s in steps]), batch.st_quat_xyzw, rtol=0, atol=1e-13)


def test_scale_factor_drift_truth(quiet, commands):
    out = simulate_batch(quiet, 1, commands, effects=[ScaleFactorDrift(2e-6, grs=1, axis="y", t_ref_s=100.0)])
    nominal = quiet.grs.sensors[0]
    factor = 1.0 + 2e-6 * (out.t_s - 100.0)
    np.testing.assert_allclose(out.truth.grs_angular_scale_factors[:, 0, 0], nominal.angular_scale_factors[0] * factor)
    np.testing.assert_allclose(out.truth.grs_linear_scale_factors[:, 0, 1], nominal.linear_scale_factors[1] * factor)
    np.testing.assert_array_equal(out.truth.grs_angular_scale_factors[:, 1], np.broadcast_to(
        quiet.grs.sensors[1].angular_scale_factors, (N, 3)))


def test_com_drift_moves_both_offsets(quiet, commands):
    out = simulate_batch(quiet, 1, commands, effects=[ComDrift((1e-7, 0, -1e-7))])
    for i, sensor in enumerate(quiet.grs.sensors):
        expected = sensor.com_offset_m + out.t_s[:, None] * np.array([1e-7, 0, -1e-7])
        np.testing.assert_allclose(out.truth.com_offset_m[:, i], expected, rtol=0, atol=1e-15)


def test_inertia_error_and_torque_gain_dynamics(quiet, commands):
    effect = InertiaError((0.02, -0.01, 0.0), (3.0, 0.0, -2.0))
    true_inertia = effect.true_inertia(quiet.spacecraft.inertia_kg_m2)
    out = simulate_batch(quiet, 1, commands, effects=[effect])
    omega, acc = out.truth.omega_rad_s, out.truth.omega_dot_rad_s2
    w_mid = 0.5 * (np.vstack((np.zeros((1, 3)), omega[:-1])) + omega)
    torque = commands - np.cross(w_mid, w_mid @ true_inertia.T)
    np.testing.assert_allclose(acc @ true_inertia.T, torque, rtol=0, atol=1e-12 * np.abs(commands).max())
    gain = simulate_batch(quiet, 1, commands, effects=[ThrusterTorqueGain((0.01, 0.0, -0.02))])
    np.testing.assert_allclose(gain.truth.torque_applied_n_m, commands * np.array([1.01, 1.0, 0.98]), rtol=1e-15)


def test_gravity_gradient_torque_and_harmonics(config):
    effect = GravityGradient(orbit_period_s=5400.0, orbit_normal=(0.1, -0.3, 1.0), phase_rad=0.4, scale=2.0)
    effect.bind(config, 0)
    t = np.linspace(0.0, 5400.0, 37)
    torque = effect.torque_n_m(t)
    n = 2 * math.pi / 5400.0
    e1, e2 = effect.plane_axes()
    assert abs(e1 @ effect.orbit_normal) < 1e-15 and abs(e2 @ effect.orbit_normal) < 1e-15
    inertia = config.spacecraft.inertia_kg_m2
    for k in (0, 11, 23):
        theta = n * t[k] + 0.4
        r = math.cos(theta) * e1 + math.sin(theta) * e2
        np.testing.assert_allclose(torque[k], 2.0 * 3 * n * n * np.cross(r, inertia @ r), rtol=1e-12, atol=1e-20)
    tau_0, tau_c, tau_s = effect.harmonic_coefficients_n_m(inertia)
    theta = n * t + 0.4
    rebuilt = tau_0 + np.cos(2 * theta)[:, None] * tau_c + np.sin(2 * theta)[:, None] * tau_s
    np.testing.assert_allclose(rebuilt, torque, rtol=0, atol=1e-12 * np.abs(torque).max())


@pytest.mark.parametrize("offset_s", [0.25, 0.03, -0.12])
def test_time_offset_reads_the_attitude_offset_late(quiet, commands, offset_s):
    out = simulate_batch(quiet, 1, commands, effects=[TimeOffset(offset_s)])
    measured = rotvec_from_quat(quat_multiply(quat_conjugate(out.truth.quat_xyzw), out.st_quat_xyzw))
    # exact: the body rotation -int_{t - offset}^{t} omega, the rate linear within each step
    times = np.concatenate(([0.0], out.t_s))
    omega = np.vstack((np.zeros((1, 3)), out.truth.omega_rad_s))
    fine = np.linspace(0.0, 1.0, 401)
    expected = np.empty((N, 3))
    for j, t in enumerate(out.t_s):
        s_grid = t - offset_s + offset_s * fine
        rate = np.stack([np.interp(s_grid, times, omega[:, i]) for i in range(3)], axis=1)
        expected[j] = -offset_s * np.trapezoid(rate, fine, axis=0)
    usable = np.ones(N, dtype=bool)
    if offset_s < 0:  # a lead extrapolates the current acceleration: exact away from command edges
        acc = out.truth.omega_dot_rad_s2
        steps = int(np.ceil(-offset_s / quiet.dt_s))
        for k in range(1, steps + 1):
            usable[:-k] &= np.all(np.abs(acc[k:] - acc[:-k]) <= 1e-6 * np.abs(acc).max(), axis=1)
        usable[-steps:] = False
    usable[:3] = False  # before t0 the rate is the initial one
    scale = np.abs(expected).max()
    assert scale > 0.5 * abs(offset_s) * np.abs(out.truth.omega_rad_s).max()
    # tolerance: the effect follows the rate without the gyroscopic torque (1e-9 of the maneuver torque,
    # accumulated over the run): 1e-4 of the rotation, 1e-11 rad, five orders below the star-tracker noise
    np.testing.assert_allclose(measured[usable], expected[usable], rtol=0, atol=1e-4 * scale)


def test_star_tracker_lowfreq_noise_level(quiet):
    """The extra error has the stationary variance of its PSD and rises at low frequency."""
    noisy = load_config("type1", overrides={f"noise.{s}.enabled": s == "star_tracker" for s in NOISE})
    commands = maneuver_torque_commands(noisy, 36000)
    effect = StarTrackerLowFreqNoise(knee_hz=5e-3, corner_hz=1e-3)
    with_effect = simulate_batch(noisy, 2, commands, effects=[effect])
    without = simulate_batch(noisy, 2, commands)
    extra = rotvec_from_quat(quat_multiply(quat_conjugate(without.st_quat_xyzw), with_effect.st_quat_xyzw))
    _, _, stationary = StarTrackerLowFreqNoise.ar1_parameters(noisy.noise.star_tracker.sigma_rad, 5e-3, 1e-3, 10.0)
    # 1 h is ~23 correlation times: the sample variance is within ~30 %
    assert np.std(extra, axis=0) == pytest.approx(stationary, rel=0.35)


def test_tm_stiffness_dc_gain(config):
    b, a = suspension_filter(0.01, 0.7, 10.0)
    omega2 = (2 * math.pi * 0.01) ** 2
    assert np.sum(b) / np.sum(a) == pytest.approx(1.0 / omega2, rel=1e-9)
    effect = TmStiffness(2e-6, grs=1, axis="x")
    effect.bind(config, 0)
    constant = np.full((20000, 3), 1e-9)
    _, linear = effect.grs_accelerations(np.zeros(20000), 1, np.zeros((20000, 3)), constant)
    assert linear[-1, 0] == pytest.approx(1e-9 * (1 - 2e-6 / omega2), rel=1e-6)
    np.testing.assert_array_equal(linear[:, 1:], constant[:, 1:])


def test_force_leakage_and_cross_coupling_physics(quiet, commands):
    leak = simulate_batch(quiet, 1, commands, effects=[ThrusterForceLeakage([[0, 0, 0.02], [0, 0, 0], [0, 0, 0]])])
    np.testing.assert_allclose(leak.truth.a_sc_m_s2[:, 0], 0.02 * commands[:, 2] / quiet.spacecraft.mass_kg)
    eps = np.array([0.0, 0.0, 2e-3])
    mis = simulate_batch(quiet, 1, commands, effects=[CrossCoupling(2, misalignment_rad=eps)])
    base = simulate_batch(quiet, 1, commands)
    expected = base.truth.grs_angular_meas[:, 1] - np.cross(eps, base.truth.grs_angular_meas[:, 1])
    np.testing.assert_allclose(mis.truth.grs_angular_meas[:, 1], expected, rtol=1e-13, atol=1e-25)


def test_bad_parameters_and_config_list():
    with pytest.raises(EffectParameterError, match=r"scale_factor_drift\.axis"):
        ScaleFactorDrift(1e-7, axis="w")
    with pytest.raises(EffectParameterError, match=r"com_drift\.rate_m_s"):
        ComDrift((1.0, 2.0))
    with pytest.raises(EffectParameterError, match=r"cross_coupling\.grs"):
        CrossCoupling(grs=3)
    with pytest.raises(ValueError, match="unknown effect 'nope'"):
        make_effect("nope")
    with pytest.raises(ValueError, match="time_offset"):
        make_effect("time_offset", offset=1.0)
    effects = effects_from_config([{"name": "time_offset", "offset_s": 0.1},
                                   {"name": "thruster_torque_gain", "gain": [0.01, 0, 0]}])
    assert [e.name for e in effects] == ["thruster_torque_gain", "time_offset"]
    with pytest.raises(ValueError, match=r"effects\[0\]"):
        effects_from_config([{"offset_s": 0.1}])
    assert effects[1].to_dict() == {"name": "time_offset", "type": "TimeOffset", "enabled": True, "offset_s": 0.1}
