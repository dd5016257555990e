"""Star-tracker ground processing: small angles, sign continuity, non-unit quaternions, gaps, smoothing."""

import numpy as np
import pytest

from taiji2_estimator_pkg.core.attitude import (
    AttitudeIntegrator,
    SmoothingDerivative,
    attitude_increments,
    integrate_attitude,
    quat_multiply,
)
from taiji2_estimator_pkg.core.validation import InputValidator, ValidationOptions, validate_batch

from estimator_support import noise_free, simulate


def _random_walk_quaternions(n: int = 2000, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = np.empty((n, 4))
    q[0] = [0.0, 0.0, 0.0, 1.0]
    for k in range(1, n):
        # realistic steps: ~3e-8 rad of maneuver plus 1e-7 rad of jitter per 0.1 s sample
        step = rng.normal(size=3) * 1e-7 + np.array([3e-8, 1e-8, -2e-8])
        half = 0.5 * np.linalg.norm(step)
        q[k] = quat_multiply(q[k - 1], np.concatenate((np.sin(half) * step / (2 * half), [np.cos(half)])))
    return q


def test_phi_is_the_integral_of_the_body_rate():
    # noise-free simulator: the increments are exactly omega_mid dt (tolerance: rounding, 1e-13 rad)
    config, out = simulate("type1", 1200.0, 0, **noise_free())
    phi = integrate_attitude(out.st_quat_xyzw)
    omega = out.truth.omega_rad_s
    omega_mid = 0.5 * (omega[1:] + omega[:-1])
    expected = np.concatenate((np.zeros((1, 3)), np.cumsum(omega_mid * config.dt_s, axis=0)))
    assert np.max(np.abs(phi - expected)) < 1e-13
    # the attitude drifts far enough that log(q_0^* q_k) would differ by coning terms
    assert np.max(np.abs(phi)) > 1e-5


def test_sign_flips_are_harmless_and_counted():
    q = _random_walk_quaternions()
    flipped = q.copy()
    flip_rows = np.arange(5, q.shape[0], 7)
    flipped[flip_rows] *= -1.0
    np.testing.assert_allclose(integrate_attitude(flipped), integrate_attitude(q), atol=1e-15)
    t = np.arange(q.shape[0]) * 0.1
    checked = validate_batch(t, flipped, np.zeros((q.shape[0], 2, 6)))
    assert np.all(checked.star_tracker_ok)
    # every sign change against the previous readout is counted (a flipped row flips back after it)
    changes = int(np.count_nonzero(np.sign(flipped[1:, 3]) != np.sign(flipped[:-1, 3])))
    assert checked.counts["star_tracker"]["sign_flip_corrected"] == changes
    np.testing.assert_allclose(checked.quat_xyzw, q * np.sign(q[:1, 3]), atol=1e-15)
    # per sample, with the reject policy: the flipped readouts are rejected with their reason
    validator = InputValidator(ValidationOptions(sign_flip_policy="reject"))
    reasons = [validator.check_star_tracker(tk, qk).reason for tk, qk in zip(t[:40], flipped[:40], strict=True)]
    assert reasons.count("sign_flip") == validator.counts["star_tracker"]["sign_flip"] > 0


def test_non_unit_quaternions_rejected_and_small_errors_renormalised():
    q = _random_walk_quaternions(200)
    bad = q.copy()
    bad[10] *= 1.01
    bad[20] *= 1.0 + 1e-8  # inside the tolerance: renormalised
    t = np.arange(q.shape[0]) * 0.1
    checked = validate_batch(t, bad, np.zeros((q.shape[0], 2, 6)))
    assert not checked.star_tracker_ok[10] and checked.star_tracker_ok[20]
    assert checked.counts["star_tracker"]["non_unit_quaternion"] == 1
    assert abs(np.linalg.norm(checked.quat_xyzw[20]) - 1.0) < 1e-15
    validator = InputValidator()
    assert validator.check_star_tracker(0.0, q[0]).ok
    check = validator.check_star_tracker(0.1, bad[10] * 1.0)
    assert not check.ok and check.reason == "non_unit_quaternion"


def test_gaps_are_bridged_by_the_increment_across_them():
    q = _random_walk_quaternions(1000)
    keep = np.ones(q.shape[0], dtype=bool)
    keep[100:160] = False
    keep[500] = False
    full = integrate_attitude(q)
    gappy = integrate_attitude(q, keep)
    assert np.all(np.isnan(gappy[~keep]))
    # across a gap the single increment equals the sum of the missing ones up to coning terms
    # (~ (60 x 1e-7 rad)^2 here): tolerance 1e-10 rad
    assert np.max(np.abs(gappy[keep] - full[keep])) < 1e-10


def test_per_sample_integrator_equals_batch():
    q = _random_walk_quaternions(500)
    integrator = AttitudeIntegrator()
    per_sample = np.array([integrator.add(qk) for qk in q])
    np.testing.assert_allclose(per_sample, integrate_attitude(q), rtol=0, atol=1e-16)
    state = integrator.state_dict()
    restored = AttitudeIntegrator()
    restored.load_state_dict(state)
    np.testing.assert_array_equal(restored.add(q[-1]), integrator.add(q[-1]))
    assert attitude_increments(q).shape == (499, 3)


def test_smoothing_derivative_matches_grs_side_exactly():
    # both sides of the paper's regression get the same transfer function (noise-free: 1e-9 rel.)
    config, out = simulate("type1", 1200.0, 0, **noise_free())
    smoother = SmoothingDerivative(201, 2, config.dt_s)
    _, st_acc = smoother.apply_attitude(integrate_attitude(out.st_quat_xyzw))
    grs_acc = smoother.apply_grs(out.truth.omega_dot_rad_s2)
    ok = np.isfinite(st_acc[:, 0]) & np.isfinite(grs_acc[:, 0])
    assert np.count_nonzero(ok) > 10000
    assert np.max(np.abs(st_acc[ok] - grs_acc[ok])) < 1e-9 * np.max(np.abs(st_acc[ok]))


def test_smoothing_noise_propagation():
    # white phi noise sigma -> per-sample std sigma ||c|| (Monte Carlo, 200k samples: 2 % tolerance)
    smoother = SmoothingDerivative(101, 2, 0.1)
    noise = np.random.default_rng(3).normal(size=(200_000, 1)) * 1e-6
    _, acc = smoother.apply_attitude(noise)
    assert np.nanstd(acc) == pytest.approx(1e-6 * smoother.acceleration_noise_gain(), rel=0.02)
    with pytest.raises(ValueError, match="numerically inaccurate"):
        SmoothingDerivative(2001, 4, 0.1)
