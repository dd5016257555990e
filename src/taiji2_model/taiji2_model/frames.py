"""Reference frames and quaternion algebra.

Conventions (interfaces.md): quaternions are Hamilton, stored ``x y z w``; the attitude q is the
orientation of the CRF in the inertial frame, ``v_inertial = q v_crf q*`` and
``q_dot = 0.5 q (0, omega)`` with omega in CRF. A CRF vector v reads ``C_i v`` in TMRF_i.

All quaternion helpers are vectorised over leading axes and broadcast like numpy arithmetic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "apply_matrix",
    "apply_matrix_components",
    "apply_matrix_rows",
    "crf_to_tmrf",
    "cross",
    "cross_rows",
    "matrix_pattern",
    "quat_conjugate",
    "quat_from_rotvec",
    "quat_multiply",
    "quat_rotate",
    "rotvec_from_quat",
]


#: Below this many vectors the per-call cost of numpy dominates: the broadcasting forms are used
#: (bitwise the same results as the per-component passes).
_FEW_VECTORS = 64


def crf_to_tmrf(grs_id: int, alpha_rad: float) -> np.ndarray:
    """Rotation C_i taking CRF components to TMRF_i components.

    Parameters
    ----------
    grs_id : int
        1 or 2.
    alpha_rad : float
        Angle between the two telescope lines of sight [rad] (nominal pi/3).

    Returns
    -------
    numpy.ndarray
        (3, 3) ``C_1 = [[cos a/2, -sin a/2, 0], [sin a/2, cos a/2, 0], [0, 0, 1]]`` as printed in
        the paper, or ``C_2 = C_1^T``.
    """
    if grs_id not in (1, 2):
        raise ValueError(f"grs_id: must be 1 or 2, got {grs_id!r}")
    cos_half = math.cos(0.5 * alpha_rad)
    sin_half = math.sin(0.5 * alpha_rad)
    c_1 = np.array([[cos_half, -sin_half, 0.0], [sin_half, cos_half, 0.0], [0.0, 0.0, 1.0]])
    return c_1 if grs_id == 1 else c_1.T.copy()


def apply_matrix(matrix: ArrayLike, vectors: ArrayLike) -> np.ndarray:
    """Matrix times each vector, ``M v`` for rows v.

    Parameters
    ----------
    matrix : array_like
        (3, 3), or (n, 3, 3) with one matrix per row of ``vectors``.
    vectors : array_like
        (..., 3); with a (n, 3, 3) matrix, (n, 3).

    Returns
    -------
    numpy.ndarray
        (..., 3). Written out by components (no BLAS): the same rounding for any number of rows,
        which keeps one-step and many-step results identical, and no thread start-up cost. Each
        output component is one pass over the rows, ``(v_x M_i0 + v_y M_i1) + v_z M_i2``: 3-4x
        faster for many rows than broadcasting over the length-3 axis, and bitwise equal to it.
    """
    m = np.asarray(matrix, dtype=np.float64)
    v = np.asarray(vectors, dtype=np.float64)
    if v.size < _FEW_VECTORS * 3:  # a few vectors (a streaming step): fewer numpy calls
        vx, vy, vz = v[..., 0:1], v[..., 1:2], v[..., 2:3]
        return vx * m[..., :, 0] + vy * m[..., :, 1] + vz * m[..., :, 2]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    out = np.empty(np.broadcast_shapes(v.shape, m.shape[:-1]))
    for i in range(3):
        out[..., i] = vx * m[..., i, 0] + vy * m[..., i, 1] + vz * m[..., i, 2]
    return out


def apply_matrix_rows(matrix: np.ndarray, rows: np.ndarray, out: np.ndarray | None = None,
                      scratch: np.ndarray | None = None) -> np.ndarray:
    """:func:`apply_matrix` on component-first vectors: ``rows`` (3, n) -> (3, n), bitwise equal.

    ``matrix`` is (3, 3), or (n, 3, 3) with one matrix per column of ``rows``; ``out`` (3, n) and
    ``scratch`` (n,), when given, receive the result and the products (no allocation). A (3, 3)
    matrix goes through :func:`apply_matrix_components` (its zero entries skipped).
    """
    if out is None:
        out = np.empty((3, *np.broadcast_shapes(rows[0].shape, matrix.shape[:-2])))
    if scratch is None:
        scratch = np.empty(out.shape[1:])
    if matrix.ndim == 2:
        apply_matrix_components(matrix, (rows[0], rows[1], rows[2]), (out[0], out[1], out[2]), scratch)
        return out
    x, y, z = rows[0], rows[1], rows[2]
    for i in range(3):
        row = out[i]
        np.multiply(x, matrix[..., i, 0], out=row)
        row += np.multiply(y, matrix[..., i, 1], out=scratch)
        row += np.multiply(z, matrix[..., i, 2], out=scratch)
    return out


def matrix_pattern(matrix: ArrayLike) -> tuple[list[list[bool]], list[list[bool]]]:
    """Which entries of (..., 3, 3) matrices are non-zero in some matrix, and which are one in all.

    The argument ``pattern`` of :func:`apply_matrix_components`, for a matrix applied many times.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    leading = tuple(range(matrix.ndim - 2))
    return np.any(matrix != 0.0, axis=leading).tolist(), np.all(matrix == 1.0, axis=leading).tolist()


def apply_matrix_components(matrix: ArrayLike, components: Sequence[np.ndarray], out: Sequence[np.ndarray],
                            scratch: np.ndarray | None = None,
                            pattern: tuple[list[list[bool]], list[list[bool]]] | None = None) -> None:
    """:func:`apply_matrix` on vectors given by their components, written into given arrays.

    ``out[i] = (v_x M_i0 + v_y M_i1) + v_z M_i2``, the order of :func:`apply_matrix` (bitwise
    equal). ``matrix`` is (..., 3, 3): its leading axes (e.g. one matrix per sensor) broadcast with
    the components (e.g. (n, 1) against (2,) gives (n, 2)); ``out`` are three arrays (e.g. views
    of an output array) of the broadcast shape, ``scratch`` one more (allocated when needed). An
    entry that is zero in every matrix is skipped (adding ``v 0`` changes no finite sum), an entry
    one in every matrix is a copy (``v 1 = v``): a diagonal inertia costs 3 products instead of 9,
    a frame rotation about one axis 4. ``pattern``, :func:`matrix_pattern` of the matrix, saves
    finding the zero and unit entries again (a streaming step applies the same matrices each time).
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    used, units = matrix_pattern(matrix) if pattern is None else pattern
    for i, target in enumerate(out):
        first = True
        for j, values in enumerate(components):
            if not used[i][j]:
                continue
            coefficient, unit = matrix[..., i, j], units[i][j]
            if first:
                if unit:
                    np.copyto(target, values)
                else:
                    np.multiply(values, coefficient, out=target)
                first = False
            elif unit:
                target += values
            else:
                if scratch is None:
                    scratch = np.empty(target.shape)
                target += np.multiply(values, coefficient, out=scratch)
        if first:
            target.fill(0.0)


def cross(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Cross product ``a x b`` over the last axis (length 3), broadcasting leading axes.

    Written out by components into a preallocated array: several times faster than
    :func:`numpy.cross` or stacking for many short vectors, and bitwise equal to them.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    out[..., 0] = ay * bz - az * by
    out[..., 1] = az * bx - ax * bz
    out[..., 2] = ax * by - ay * bx
    return out


def cross_rows(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None,
               scratch: np.ndarray | None = None) -> np.ndarray:
    """:func:`cross` on component-first vectors: (3, n) x (3, n) -> (3, n), bitwise equal.

    ``out`` (3, n) and ``scratch`` (n,), when given, receive the result and the products.
    """
    if out is None:
        out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    if scratch is None:
        scratch = np.empty(out.shape[1:])
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(a[j], b[k], out=out[i])
        out[i] -= np.multiply(a[k], b[j], out=scratch)
    return out


def quat_multiply(q_a: ArrayLike, q_b: ArrayLike) -> np.ndarray:
    """Hamilton product ``q_a q_b`` (xyzw).

    Parameters
    ----------
    q_a, q_b : array_like
        (..., 4) quaternions; leading axes broadcast.

    Returns
    -------
    numpy.ndarray
        (..., 4) product; ``quat_rotate(q_a q_b, v) = quat_rotate(q_a, quat_rotate(q_b, v))``.
    """
    a = np.asarray(q_a, dtype=np.float64)
    b = np.asarray(q_b, dtype=np.float64)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    # the same expressions as _hamilton_product, on the last axis
    out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
    out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


def _hamilton_product(a: np.ndarray, b: np.ndarray, out: np.ndarray, scratch: np.ndarray | None = None) -> None:
    """Hamilton product on component-first arrays (4, ...); ``out`` may not alias a or b.

    The terms are added left to right as in :func:`quat_multiply` (bitwise equal); ``scratch``
    (one row, shaped like ``out[0]``) receives each product.
    """
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    t = np.empty(out.shape[1:]) if scratch is None else scratch
    for row, terms in ((0, ((aw, bx, 1), (ax, bw, 1), (ay, bz, 1), (az, by, -1))),
                       (1, ((aw, by, 1), (ax, bz, -1), (ay, bw, 1), (az, bx, 1))),
                       (2, ((aw, bz, 1), (ax, by, 1), (ay, bx, -1), (az, bw, 1))),
                       (3, ((aw, bw, 1), (ax, bx, -1), (ay, by, -1), (az, bz, -1)))):
        o = out[row]
        (p, q, _), *rest = terms
        np.multiply(p, q, out=o)
        for p, q, sign in rest:
            np.multiply(p, q, out=t)
            if sign > 0:
                o += t
            else:
                o -= t


def quat_conjugate(q: ArrayLike) -> np.ndarray:
    """Conjugate (inverse of a unit quaternion), (..., 4) xyzw."""
    conjugate = np.array(q, dtype=np.float64, copy=True)
    conjugate[..., :3] *= -1.0
    return conjugate


def quat_rotate(q: ArrayLike, v: ArrayLike) -> np.ndarray:
    """Rotate vectors: ``q v q*`` for unit q.

    Parameters
    ----------
    q : array_like
        (..., 4) unit quaternions xyzw.
    v : array_like
        (..., 3) vectors; leading axes broadcast with ``q``.

    Returns
    -------
    numpy.ndarray
        (..., 3); with q the attitude, maps CRF components to inertial components.
    """
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    vector = q[..., :3]
    # v' = v + w t + u x t with t = 2 u x v (unit q), cheaper than two products
    twice_cross = 2.0 * cross(vector, v)
    return v + q[..., 3:4] * twice_cross + cross(vector, twice_cross)


def quat_from_rotvec(rotvec_rad: ArrayLike, out: np.ndarray | None = None) -> np.ndarray:
    """Unit quaternion ``exp(rotvec / 2)`` of a rotation vector.

    Parameters
    ----------
    rotvec_rad : array_like
        (..., 3) rotation vector (axis times angle) [rad].
    out : numpy.ndarray, optional
        (..., 4) array that receives the result (e.g. a view of a larger array).

    Returns
    -------
    numpy.ndarray
        (..., 4) xyzw; exact to rounding also for angles down to zero (uses sinc).
    """
    rotvec = np.asarray(rotvec_rad, dtype=np.float64)
    if out is None:
        out = np.empty((*rotvec.shape[:-1], 4))
    x, y, z = rotvec[..., 0], rotvec[..., 1], rotvec[..., 2]
    # angle^2 = (x x + y y) + z z, the order of np.sum over the last axis; one buffer reused
    # throughout, so that a block of many steps allocates two arrays rather than ten
    angle = np.multiply(x, x, out=np.empty(rotvec.shape[:-1]))
    angle += np.multiply(y, y, out=out[..., 3])
    angle += np.multiply(z, z, out=out[..., 3])
    np.sqrt(angle, out=angle)
    half = np.multiply(angle, 0.5, out=angle)
    np.cos(half, out=out[..., 3])
    # sin(angle/2)/angle = 0.5 sinc(half/pi), numpy's normalised sinc written out with its exact
    # operations (pi (half / pi), zero replaced by eps, sin(y) / y): finite at 0
    scaled = np.divide(half, np.pi, out=half)
    scaled *= np.pi
    scaled[scaled == 0.0] = np.finfo(np.float64).eps
    scale = np.sin(scaled)
    scale /= scaled
    scale *= 0.5
    for axis in range(3):  # per component: one long loop each, not a loop of three per vector
        np.multiply(rotvec[..., axis], scale, out=out[..., axis])
    return out


def rotvec_from_quat(q: ArrayLike) -> np.ndarray:
    """Rotation vector (axis times angle, angle in [0, pi]) of a unit quaternion.

    Parameters
    ----------
    q : array_like
        (..., 4) unit quaternions xyzw; q and -q give the same result.

    Returns
    -------
    numpy.ndarray
        (..., 3) rotation vector [rad].
    """
    q = np.asarray(q, dtype=np.float64)
    sign = np.where(q[..., 3:4] < 0.0, -1.0, 1.0)
    vector = q[..., :3] * sign
    scalar = q[..., 3] * sign[..., 0]
    sine_norm = np.sqrt(np.sum(vector * vector, axis=-1))
    # atan2(s, w)/s -> 1/w as s -> 0, and atan2 keeps full relative accuracy for tiny s
    safe_norm = np.where(sine_norm > 0.0, sine_norm, 1.0)
    ratio = np.where(sine_norm > 0.0, np.arctan2(sine_norm, scalar) / safe_norm, 1.0 / scalar)
    return 2.0 * ratio[..., None] * vector


