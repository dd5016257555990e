"""Rigid-body attitude propagation of the spacecraft.

Model: ``J omega_dot = tau - omega x J omega`` (CRF) and ``q_dot = 0.5 q (0, omega)`` with q the
orientation of the CRF in the inertial frame. The torque is held constant over each step
(t_k, t_{k+1}].

Discretisation (implicit midpoint, exact for the piecewise-constant torque, second order for the
gyroscopic term)::

    w_m         = (omega_k + omega_{k+1}) / 2
    omega_{k+1} = omega_k + dt J^-1 (tau_k - w_m x J w_m)
    q_{k+1}     = q_k exp(0.5 w_m dt)

The implicit equation is solved by Picard (fixed-point) iteration over a block of steps at once:
the rates of the whole block follow from a cumulative sum of the increments, the gyroscopic term
is re-evaluated, and so on to convergence; the attitude then follows from the running product of
the step rotations (:class:`.attitude_scan.AttitudeScan`, whose association is fixed by the step
index, so any cutting of a run into calls gives the same bits). For one step this is the plain fixed-point
iteration of the streaming simulator, for n steps the vectorised batch solution: both converge to
the same discrete trajectory. A block that does not converge (large rates) is split in halves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from taiji2_model.frames import (
    apply_matrix,
    apply_matrix_rows,
    cross,
    cross_rows,
    quat_from_rotvec,
)
from taiji2_sim_pkg.core.attitude_scan import AttitudeScan

__all__ = ["AttitudeSteps", "gyroscopic_torque_n_m", "propagate_attitude"]

# Numerical (not physical) controls of the fixed-point solve.
_RATE_RTOL = 8.0 * np.finfo(np.float64).eps  # converged when the iterate moves by rounding only
_STALL_RTOL = 1e-13  # accepted if the iteration stops contracting at rounding level
_MAX_PICARD_ITERATIONS = 40
#: Blocks shorter than this are solved in (n, 3) layout (fewer numpy calls), longer ones
#: component-first; both do the same floating-point operations (bitwise equal results).
_FEW_STEPS = 64


@dataclass(frozen=True)
class AttitudeSteps:
    """Result of propagating n steps.

    Attributes
    ----------
    quat_xyzw : numpy.ndarray
        (n, 4) attitude at t_{k+1}.
    omega_rad_s : numpy.ndarray
        (n, 3) body rate at t_{k+1} [rad/s].
    omega_mid_rad_s : numpy.ndarray
        (n, 3) midpoint rate ``(omega_k + omega_{k+1}) / 2`` [rad/s].
    omega_dot_rad_s2 : numpy.ndarray
        (n, 3) mean angular acceleration over the step, ``J^-1 (tau_k - w_m x J w_m)``, which equals
        ``(omega_{k+1} - omega_k) / dt`` without the cancellation of the difference [rad s^-2].
    """

    quat_xyzw: np.ndarray
    omega_rad_s: np.ndarray
    omega_mid_rad_s: np.ndarray
    omega_dot_rad_s2: np.ndarray


def gyroscopic_torque_n_m(omega_rad_s: ArrayLike, inertia_kg_m2: ArrayLike) -> np.ndarray:
    """``omega x (J omega)`` [N m] for (..., 3) rates [rad/s] and a (3, 3) inertia [kg m^2]."""
    omega = np.asarray(omega_rad_s, dtype=np.float64)
    return cross(omega, apply_matrix(inertia_kg_m2, omega))


def _solve_block(omega_start: np.ndarray, torque: np.ndarray, inertia: np.ndarray,
                 inertia_inv: np.ndarray, dt_s: float) -> tuple[np.ndarray, ...] | None:
    """Picard iteration over one block; None if it does not converge (the caller splits it)."""
    if torque.shape[0] < _FEW_STEPS:
        return _solve_block_vectors(omega_start, torque, inertia, inertia_inv, dt_s)
    return _solve_block_rows(omega_start, torque, inertia, inertia_inv, dt_s)


def _solve_block_vectors(omega_start: np.ndarray, torque: np.ndarray, inertia: np.ndarray,
                         inertia_inv: np.ndarray, dt_s: float) -> tuple[np.ndarray, ...] | None:
    """:func:`_solve_block` in (n, 3) layout: fewest numpy calls, for a streaming step."""
    count = torque.shape[0]
    stacked = np.empty((count + 1, 3))
    stacked[0] = omega_start
    gyroscopic = np.zeros((count, 3))
    previous = None
    previous_change = np.inf
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(_MAX_PICARD_ITERATIONS):
            omega_dot = apply_matrix(inertia_inv, torque - gyroscopic)
            stacked[1:] = dt_s * omega_dot
            omega = np.cumsum(stacked, axis=0)  # omega_{k+1} = omega_k + dt omega_dot_k
            omega_mid = 0.5 * (omega[:-1] + omega[1:])
            gyroscopic = cross(omega_mid, apply_matrix(inertia, omega_mid))
            if previous is not None:
                change = float(np.max(np.abs(omega[1:] - previous)))
                scale = float(np.max(np.abs(omega)))
                if change <= _RATE_RTOL * scale:
                    return omega[1:], omega_mid, omega_dot
                if not change < previous_change:
                    # stalled at rounding level: converged; otherwise diverging: give up early
                    return (omega[1:], omega_mid, omega_dot) if change <= _STALL_RTOL * scale else None
                previous_change = change
            previous = omega[1:]
    return None


def _solve_block_rows(omega_start: np.ndarray, torque: np.ndarray, inertia: np.ndarray,
                      inertia_inv: np.ndarray, dt_s: float) -> tuple[np.ndarray, ...] | None:
    """:func:`_solve_block` for many steps.

    The iterates are component-first (3, n), so that every operation runs over contiguous rows;
    each element sees the same operations in the same order as in (n, 3) layout (bitwise equal).
    """
    count = torque.shape[0]
    # every buffer of the iteration in one allocation (one large block is mapped in huge pages,
    # several medium ones page by page), reused by every iteration; two for the rates (this
    # iterate and the previous one), rows of count + 1 so that the cumulative sum has its start
    block = np.empty((9, 3, count + 1))
    stacked, omega, previous = block[0], block[1], block[2]
    torque_rows, omega_dot, omega_mid, moment, work, gyroscopic = (rows[:, :count] for rows in block[3:])
    np.copyto(torque_rows, torque.T)
    stacked[:, 0] = omega_start
    scratch = np.empty(count)
    previous_change = np.inf
    scale_bound = np.inf  # an upper bound of max |omega| of the previous iterate
    with np.errstate(over="ignore", invalid="ignore"):
        for iteration in range(_MAX_PICARD_ITERATIONS):
            # the first iterate has no gyroscopic term: torque - 0 is the torque
            net_torque = np.subtract(torque_rows, gyroscopic, out=work) if iteration else torque_rows
            apply_matrix_rows(inertia_inv, net_torque, out=omega_dot, scratch=scratch)
            np.multiply(dt_s, omega_dot, out=stacked[:, 1:])
            np.cumsum(stacked, axis=1, out=omega)  # omega_{k+1} = omega_k + dt omega_dot_k
            np.add(omega[:, :-1], omega[:, 1:], out=omega_mid)
            omega_mid *= 0.5
            if iteration:
                np.subtract(omega[:, 1:], previous[:, 1:], out=work)
                change = max(float(work.max()), -float(work.min()))  # max |.| without |.|
                # max |omega| moves by at most the change (same first column), so while the iteration
                # contracts and the change exceeds the tolerance of that bound, neither test below can
                # pass and the reduction for the scale is skipped
                scale_bound += change
                if change < previous_change and change > _RATE_RTOL * scale_bound:
                    previous_change = change
                else:
                    scale = max(float(omega.max()), -float(omega.min()))
                    scale_bound = scale
                    if change <= _RATE_RTOL * scale:
                        return _rows_to_vectors(omega[:, 1:], omega_mid, omega_dot)
                    if not change < previous_change:
                        # stalled at rounding level: converged; otherwise diverging: give up early
                        return (_rows_to_vectors(omega[:, 1:], omega_mid, omega_dot)
                                if change <= _STALL_RTOL * scale else None)
                    previous_change = change
            else:
                scale_bound = max(float(omega.max()), -float(omega.min()))
            # the gyroscopic term of this iterate, for the next one (not needed once converged)
            apply_matrix_rows(inertia, omega_mid, out=moment, scratch=scratch)
            cross_rows(omega_mid, moment, out=gyroscopic, scratch=scratch)
            omega, previous = previous, omega
    return None


def _rows_to_vectors(*rows: np.ndarray) -> tuple[np.ndarray, ...]:
    # (n, 3) C-ordered, as before: consumers' reductions (e.g. means over sub-steps) sum in memory order;
    # one allocation for all of them (see _solve_block_rows)
    out = np.empty((len(rows), rows[0].shape[1], 3))
    for target, source in zip(out, rows, strict=True):
        for axis in range(3):  # per component: one long loop each, not a loop of three per step
            target[:, axis] = source[axis]
    return tuple(out)


def _solve_rates(omega_start: np.ndarray, torque: np.ndarray, inertia: np.ndarray,
                 inertia_inv: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    solution = _solve_block(omega_start, torque, inertia, inertia_inv, dt_s)
    if solution is not None:
        return solution
    count = torque.shape[0]
    if count == 1:
        raise RuntimeError("attitude step did not converge: rate or time step too large for the "
                           "implicit midpoint fixed-point iteration")
    half = count // 2

    def part(matrix: np.ndarray, sl: slice) -> np.ndarray:
        return matrix if matrix.ndim == 2 else matrix[sl]

    first, second = slice(0, half), slice(half, count)
    head = _solve_rates(omega_start, torque[first], part(inertia, first), part(inertia_inv, first), dt_s)
    tail = _solve_rates(head[0][-1], torque[second], part(inertia, second), part(inertia_inv, second),
                        dt_s)
    omega, omega_mid, omega_dot = (np.concatenate(pair, axis=0) for pair in zip(head, tail, strict=True))
    return omega, omega_mid, omega_dot


def propagate_attitude(quat_xyzw: ArrayLike | AttitudeScan, omega_rad_s: ArrayLike, torque_n_m: ArrayLike,
                       inertia_kg_m2: ArrayLike, dt_s: float,
                       inertia_inv_kg_m2: ArrayLike | None = None) -> AttitudeSteps:
    """Propagate the attitude over n steps of constant torque.

    Parameters
    ----------
    quat_xyzw : array_like or AttitudeScan
        (4,) attitude at t_0 (step 0 of a new scan), or the scan of the run so far, which this call
        continues (and advances).
    omega_rad_s : array_like
        (3,) body rate at t_0 [rad/s].
    torque_n_m : array_like
        (n, 3) torque applied over each step (t_k, t_{k+1}], CRF [N m].
    inertia_kg_m2 : array_like
        (3, 3) inertia, or (n, 3, 3) per step (an effect may vary it) [kg m^2].
    dt_s : float
        Step [s].
    inertia_inv_kg_m2 : array_like, optional
        Precomputed inverse of ``inertia_kg_m2`` [kg^-1 m^-2] (saves the inversion per call).

    Returns
    -------
    AttitudeSteps
        States at t_1 .. t_n and the step means.
    """
    torque = np.asarray(torque_n_m, dtype=np.float64).reshape(-1, 3)
    inertia = np.asarray(inertia_kg_m2, dtype=np.float64)
    inertia_inv = np.linalg.inv(inertia) if inertia_inv_kg_m2 is None else np.asarray(inertia_inv_kg_m2)
    omega, omega_mid, omega_dot = _solve_rates(np.asarray(omega_rad_s, dtype=np.float64), torque,
                                               inertia, inertia_inv, dt_s)
    increments = quat_from_rotvec(np.multiply(omega_mid, dt_s))
    # q_{k+1} = q_0 increment_0 ... increment_k, associated by step index (not by call)
    scan = quat_xyzw if isinstance(quat_xyzw, AttitudeScan) else AttitudeScan(quat_xyzw)
    quat = scan.extend(increments)
    return AttitudeSteps(quat, omega, omega_mid, omega_dot)
