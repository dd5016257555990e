"""Frames and quaternion conventions (xyzw, Hamilton, q = orientation of the CRF in inertial)."""

import math

import numpy as np
import pytest

from taiji2_model.frames import (
    apply_matrix,
    crf_to_tmrf,
    cross,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_rotate,
    rotvec_from_quat,
)

RNG = np.random.default_rng(20240601)


def _random_unit_quats(n):
    q = RNG.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def test_crf_to_tmrf_as_printed_in_the_paper():
    a = math.pi / 3
    c1 = crf_to_tmrf(1, a)
    c, s = math.cos(a / 2), math.sin(a / 2)
    expected = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_array_equal(c1, expected)
    np.testing.assert_array_equal(crf_to_tmrf(2, a), expected.T)
    np.testing.assert_allclose(c1 @ c1.T, np.eye(3), atol=1e-15)
    with pytest.raises(ValueError, match="grs_id"):
        crf_to_tmrf(3, a)


def test_multiply_composes_rotations_and_conjugate_inverts():
    qa, qb = _random_unit_quats(50), _random_unit_quats(50)
    v = RNG.standard_normal((50, 3))
    np.testing.assert_allclose(quat_rotate(quat_multiply(qa, qb), v), quat_rotate(qa, quat_rotate(qb, v)),
                               atol=1e-14)
    np.testing.assert_allclose(quat_multiply(qa, quat_conjugate(qa)), np.tile([0, 0, 0, 1.0], (50, 1)),
                               atol=1e-15)
    # Hamilton, xyzw: i j = k
    np.testing.assert_array_equal(quat_multiply([1, 0, 0, 0], [0, 1, 0, 0]), [0, 0, 1, 0])


def test_rotation_sense_and_kinematics_convention():
    # q = exp(theta/2 z): the body x axis seen in the inertial frame turns towards +y
    q = quat_from_rotvec([0, 0, 0.1])
    np.testing.assert_allclose(quat_rotate(q, [1, 0, 0]), [math.cos(0.1), math.sin(0.1), 0], atol=1e-16)
    # q_dot = 0.5 q (0, omega): a body-frame increment multiplies on the right
    q0 = _random_unit_quats(1)[0]
    omega, dt = np.array([1e-3, -2e-3, 5e-4]), 1e-3
    numeric = (quat_multiply(q0, quat_from_rotvec(omega * dt)) - q0) / dt
    analytic = 0.5 * quat_multiply(q0, np.append(omega, 0.0))
    np.testing.assert_allclose(numeric, analytic, atol=1e-9)


def test_rotvec_round_trip_including_zero_and_tiny_angles():
    direction = RNG.standard_normal((100, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    v = direction * np.logspace(-14, np.log10(3.0), 100)[:, None]  # angles up to 3 rad < pi
    np.testing.assert_allclose(rotvec_from_quat(quat_from_rotvec(v)), v, rtol=1e-13, atol=0)
    np.testing.assert_array_equal(quat_from_rotvec(np.zeros(3)), [0, 0, 0, 1])
    np.testing.assert_array_equal(rotvec_from_quat([0, 0, 0, 1.0]), np.zeros(3))
    np.testing.assert_allclose(rotvec_from_quat(-quat_from_rotvec(v)), v, rtol=1e-13)  # q and -q


def test_cross_and_matrix_helpers_equal_numpy():
    a, b = RNG.standard_normal((20, 3)), RNG.standard_normal((20, 3))
    np.testing.assert_array_equal(cross(a, b), np.cross(a, b))
    m = RNG.standard_normal((3, 3))
    np.testing.assert_allclose(apply_matrix(m, a), a @ m.T, rtol=1e-15, atol=1e-15)
    ms = RNG.standard_normal((20, 3, 3))
    np.testing.assert_allclose(apply_matrix(ms, a), np.einsum("nij,nj->ni", ms, a), rtol=1e-14, atol=1e-15)
