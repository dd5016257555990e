"""GRS readouts of a block of steps, computed into the simulator's output arrays.

The formulas are those of :mod:`.grs` (coupling ``omega_dot x d + w_m x (w_m x d)``, ``C_i``
rotations, readout noise, voltage conversion), evaluated component by component for all GRS at
once (per-GRS matrices and offsets broadcast over a sensor axis) and written straight into the
run's (n, sensors, width) arrays: the readout noise is drawn into the arrays that it is added to,
and no per-sensor temporary is copied. Every output element gets the floating-point operations of
the plain formulas in the same order (``a + b`` and ``b + a`` are the same sum), so the results are
bitwise those of :func:`.grs.coupling_acceleration_m_s2`, :func:`.frames.apply_matrix` and
:func:`.grs.voltages_from_accelerations`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from taiji2_model.effects import Effect
from taiji2_model.frames import apply_matrix_components, matrix_pattern

__all__ = ["GRS_FIELDS", "GrsConstants", "grs_readouts_into"]

#: Per-GRS output arrays of a block and their widths.
GRS_FIELDS = (("angular_true", 3), ("linear_true", 3), ("linear_maneuver", 3), ("angular_meas", 3),
              ("linear_meas", 3), ("angular_sf", 3), ("linear_sf", 3), ("com_offset", 3), ("voltages", 6))

#: Electrode axis x, y, z of each angular readout in the voltage differences: psi, phi, theta.
_DIFFERENCE_ANGLE = (2, 0, 1)


@dataclass(frozen=True)
class GrsConstants:
    """The configured per-GRS quantities, stacked over the sensors (leading axis: sensor).

    Attributes
    ----------
    grs_ids : tuple of int
        Sensor ids (1, 2).
    crf_to_tmrf : numpy.ndarray
        (sensors, 3, 3) C_i.
    com_offset_m : numpy.ndarray
        (sensors, 3) d_i, CRF [m].
    angular_scale_factors : numpy.ndarray
        (sensors, 3) [rad s^-2 V^-1].
    linear_scale_factors : numpy.ndarray
        (sensors, 3) [m s^-2 V^-1].
    """

    grs_ids: tuple[int, ...]
    crf_to_tmrf: np.ndarray
    com_offset_m: np.ndarray
    angular_scale_factors: np.ndarray
    linear_scale_factors: np.ndarray

    @property
    def crf_to_tmrf_pattern(self) -> tuple[list[list[bool]], list[list[bool]]]:
        """:func:`.frames.matrix_pattern` of all C_i."""
        return matrix_pattern(self.crf_to_tmrf)


def _cross_components(a: Sequence[np.ndarray], b: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """``a x b`` by components (the expressions of :func:`.frames.cross`)."""
    ax, ay, az = a
    bx, by, bz = b
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


def _sensor_major(value: np.ndarray) -> np.ndarray:
    """A hook's (3,) or (m, 3) value of one sensor as (1, 1, 3) or (1, m, 3) (see below)."""
    value = np.asarray(value, dtype=np.float64)
    return value.reshape(1, 1, 3) if value.ndim == 1 else value[None]


def grs_readouts_into(out: dict[str, np.ndarray], tm_noise: np.ndarray, sensors: slice, constants: GrsConstants,
                      t_end: np.ndarray, omega_dot: np.ndarray, omega_mid: np.ndarray, a_sc: np.ndarray,
                      hooks: Sequence[Effect] = (),
                      pattern_of_all: tuple[list[list[bool]], list[list[bool]]] | None = None) -> None:
    """Readouts of the GRS ``sensors`` over a block of m steps, into ``out``.

    Parameters
    ----------
    out : dict of numpy.ndarray
        The block's output arrays by :data:`GRS_FIELDS` name, (m, sensors, width) views; on entry
        ``angular_meas``, ``linear_meas`` and ``voltages`` hold the block's scaled LFS rotational,
        LFS translational and voltage noise, on return the readouts. ``com_offset``,
        ``angular_sf`` and ``linear_sf`` may be left out (without hooks they are the constants).
    tm_noise : numpy.ndarray
        (m, sensors, 3) TM environment noise [m s^-2].
    sensors : slice
        Which sensors (all at once without hooks; one at a time with hooks, which are per GRS).
    constants : GrsConstants
        Configured per-GRS quantities (all sensors).
    t_end : numpy.ndarray
        (m,) sample times [s] (for the hooks).
    omega_dot, omega_mid, a_sc : numpy.ndarray
        (m, 3) mean angular acceleration [rad s^-2], midpoint rate [rad/s] and spacecraft
        acceleration [m s^-2], CRF.
    hooks : sequence of Effect
        Effects (in order); only with a single sensor.
    pattern_of_all : tuple, optional
        ``constants.crf_to_tmrf_pattern``, found once by the caller (a streaming step calls this
        for every sample); used when ``sensors`` are all of them.
    """
    grs_ids = constants.grs_ids[sensors]
    if hooks and len(grs_ids) != 1:
        raise ValueError(f"sensors: effects are applied one GRS at a time, got {len(grs_ids)} sensors")
    # Sensor-major (sensors, m) products: the long step axis innermost (numpy loops over the last
    # axis; a last axis of two sensors would cost a loop per step). Per-sensor quantities are
    # (sensors, 1 or m, 3), their components (sensors, 1 or m); CRF components are (1, m) rows.
    view = {key: array[:, sensors] for key, array in out.items()}
    com_offset = constants.com_offset_m[sensors][:, None, :]
    angular_sf = constants.angular_scale_factors[sensors][:, None, :]
    linear_sf = constants.linear_scale_factors[sensors][:, None, :]
    if hooks:
        grs_id = grs_ids[0]
        offset = constants.com_offset_m[sensors][0]
        for effect in hooks:
            offset = effect.com_offset_m(t_end, grs_id, offset)
        com_offset = _sensor_major(offset)
    if "com_offset" in view:
        view["com_offset"][...] = com_offset.transpose(1, 0, 2)

    rate_dot = [omega_dot[None, :, k] for k in range(3)]
    rate = [omega_mid[None, :, k] for k in range(3)]
    offset_xyz = [com_offset[..., k] for k in range(3)]
    rotation = _cross_components(rate_dot, offset_xyz)
    centripetal = _cross_components(rate, _cross_components(rate, offset_xyz))
    coupling = [r + c for r, c in zip(rotation, centripetal, strict=True)]
    total = [a_sc[None, :, k] + coupling[k] for k in range(3)]
    matrices = constants.crf_to_tmrf[sensors][:, None]  # (sensors, 1, 3, 3)
    pattern = pattern_of_all if len(grs_ids) == len(constants.grs_ids) else None
    scratch = np.empty((len(grs_ids), t_end.shape[0]))
    for key, components in (("angular_true", rate_dot), ("linear_maneuver", coupling), ("linear_true", total)):
        target = view[key]
        apply_matrix_components(matrices, components, [target[..., k].T for k in range(3)], scratch, pattern)

    angular_meas, linear_meas = view["angular_meas"], view["linear_meas"]
    angular_meas += view["angular_true"]  # noise + true: the sum true + noise
    linear_meas += view["linear_true"]
    linear_meas += tm_noise
    if hooks:
        angular, linear = angular_meas[:, 0], linear_meas[:, 0]
        angular_sf_i, linear_sf_i = angular_sf[0, 0], linear_sf[0, 0]
        for effect in hooks:
            angular, linear = effect.grs_accelerations(t_end, grs_id, angular, linear)
            angular_sf_i, linear_sf_i = effect.grs_scale_factors(t_end, grs_id, angular_sf_i, linear_sf_i)
        angular_meas[:, 0] = angular
        linear_meas[:, 0] = linear
        angular_sf, linear_sf = _sensor_major(angular_sf_i), _sensor_major(linear_sf_i)
    if "angular_sf" in view:
        view["angular_sf"][...] = angular_sf.transpose(1, 0, 2)
        view["linear_sf"][...] = linear_sf.transpose(1, 0, 2)

    # voltages: noise + 0.5 (sum +- difference) per electrode axis (voltages_from_accelerations)
    voltages = view["voltages"]
    for axis, angle in enumerate(_DIFFERENCE_ANGLE):
        difference = angular_meas[..., angle].T / angular_sf[..., angle]
        total_v = linear_meas[..., axis].T / linear_sf[..., axis]
        half = np.add(total_v, difference, out=scratch)
        half *= 0.5
        voltages[..., 2 * axis].T[...] += half
        half = np.subtract(total_v, difference, out=scratch)
        half *= 0.5
        voltages[..., 2 * axis + 1].T[...] += half
    if hooks:
        result = voltages[:, 0]
        for effect in hooks:
            result = effect.grs_voltages_v(t_end, grs_id, result)
        voltages[:, 0] = result
