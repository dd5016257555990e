"""Attitude dynamics against closed forms and an independent high-accuracy integration."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
from taiji2_model.frames import quat_multiply, quat_rotate, rotvec_from_quat
from taiji2_sim_pkg.core.dynamics import gyroscopic_torque_n_m, propagate_attitude
from taiji2_sim_pkg.core.simulator import simulate_batch


def noise_off(layout, **more):
    overrides = {f"noise.{name}.enabled": False for name in NOISE_SOURCE_NAMES}
    overrides.update(more)
    return load_config(layout, overrides=overrides)


@pytest.mark.parametrize("layout", ["type1", "type2"])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_torque_step_from_rest_matches_closed_form(layout, axis):
    """theta(t) = tau t^2 / (2 J), omega(t) = tau t / J about a principal axis (all noise off).

    Tolerance: 1e-12 relative; the midpoint scheme is exact for constant torque about a principal
    axis (no gyroscopic term), so only rounding remains.
    """
    cfg = noise_off(layout)
    n = 1250  # 125 s, half a maneuver period
    torque = np.zeros((n, 3))
    torque[:, axis] = cfg.maneuver.amplitude_n_m[axis]
    out = simulate_batch(cfg, seed=7, torque_cmd_n_m=torque)
    t = out.t_s
    inertia = cfg.spacecraft.inertia_kg_m2[axis, axis]
    tau = cfg.maneuver.amplitude_n_m[axis]
    theta = rotvec_from_quat(out.truth.quat_xyzw)
    np.testing.assert_allclose(theta[:, axis], tau * t**2 / (2 * inertia), rtol=1e-12)
    others = [k for k in range(3) if k != axis]
    assert np.max(np.abs(theta[:, others])) == 0.0
    np.testing.assert_allclose(out.truth.omega_rad_s[:, axis], tau * t / inertia, rtol=1e-12)
    np.testing.assert_allclose(out.truth.omega_dot_rad_s2[:, axis], tau / inertia, rtol=1e-15)
    # with noise off the star tracker reads the truth
    np.testing.assert_array_equal(out.st_quat_xyzw, out.truth.quat_xyzw)


def _reference_solution(q0, w0, torque, inertia, t_end):
    inertia_inv = np.linalg.inv(inertia)

    def rhs(_t, y):
        q, w = y[:4], y[4:]
        w_dot = inertia_inv @ (torque - np.cross(w, inertia @ w))
        q_dot = 0.5 * quat_multiply(q, np.append(w, 0.0))
        return np.concatenate((q_dot, w_dot))

    sol = solve_ivp(rhs, (0.0, t_end), np.concatenate((q0, w0)), method="DOP853", rtol=1e-13, atol=1e-16)
    return sol.y[:4, -1], sol.y[4:, -1]


def test_tumbling_body_is_second_order_accurate():
    """Torque-free plus constant torque on a body with products of inertia, fast rates so that the
    gyroscopic term matters: errors against an rtol 1e-13 reference integration fall by 4 when dt
    halves (tolerance: observed order within 2 +- 0.15), and are small at the nominal 10 Hz."""
    inertia = np.array([[1100.0, 20.0, -15.0], [20.0, 1400.0, 30.0], [-15.0, 30.0, 2400.0]])
    q0 = np.array([0.1, -0.2, 0.3, 0.9])
    q0 /= np.linalg.norm(q0)
    w0 = np.array([2e-2, -1e-2, 3e-2])
    torque = np.array([3e-6, -3e-6, 13e-6])
    t_end = 200.0
    q_ref, w_ref = _reference_solution(q0, w0, torque, inertia, t_end)
    errors = []
    for dt in (0.1, 0.05, 0.025):
        n = round(t_end / dt)
        steps = propagate_attitude(q0, w0, np.tile(torque, (n, 1)), inertia, dt)
        q_err = np.linalg.norm(rotvec_from_quat(quat_multiply(np.array([-1, -1, -1, 1]) * q_ref,
                                                              steps.quat_xyzw[-1])))
        w_err = np.linalg.norm(steps.omega_rad_s[-1] - w_ref) / np.linalg.norm(w_ref)
        errors.append((q_err, w_err))
    errors = np.array(errors)
    order = np.log2(errors[:-1] / errors[1:])
    assert np.all(np.abs(order - 2.0) < 0.15), order
    assert errors[0, 0] < 1e-5 and errors[0, 1] < 1e-5


def test_angular_momentum_is_conserved_without_torque():
    """Inertial angular momentum q (J omega) q* of a torque-free tumbling body: relative drift
    below 1e-6 over 2000 s at 10 Hz (second-order scheme, (omega dt)^2 ~ 1e-5)."""
    inertia = np.diag([1100.0, 1400.0, 2400.0])
    w0 = np.array([1e-2, 3e-2, -2e-2])
    n = 20000
    steps = propagate_attitude([0, 0, 0, 1.0], w0, np.zeros((n, 3)), inertia, 0.1)
    momentum = quat_rotate(steps.quat_xyzw, steps.omega_rad_s @ inertia.T)
    drift = np.linalg.norm(momentum - inertia @ w0, axis=1) / np.linalg.norm(inertia @ w0)
    assert drift.max() < 1e-6
    kinetic = 0.5 * np.einsum("ni,ij,nj->n", steps.omega_rad_s, inertia, steps.omega_rad_s)
    assert np.max(np.abs(kinetic / (0.5 * w0 @ inertia @ w0) - 1.0)) < 1e-12  # midpoint rule keeps energy


def test_midpoint_relation_holds_exactly():
    inertia = np.diag([1100.0, 1400.0, 2400.0])
    steps = propagate_attitude([0, 0, 0, 1.0], [1e-3, -2e-3, 5e-4], np.full((50, 3), 1e-5), inertia, 0.1)
    omega = np.vstack(([1e-3, -2e-3, 5e-4], steps.omega_rad_s))
    mid = 0.5 * (omega[:-1] + omega[1:])
    np.testing.assert_allclose(steps.omega_mid_rad_s, mid, rtol=1e-15)
    rhs = (1e-5 - gyroscopic_torque_n_m(mid, inertia)) @ np.linalg.inv(inertia).T
    np.testing.assert_allclose(steps.omega_dot_rad_s2, rhs, rtol=1e-14)
    np.testing.assert_allclose(np.diff(omega, axis=0) / 0.1, rhs, rtol=1e-11)
