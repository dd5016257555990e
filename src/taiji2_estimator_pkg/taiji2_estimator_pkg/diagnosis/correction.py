"""Raw data corrected for the known effects of an extended layout, for estimators that do not model them.

``taiji2 calibrate BAG --config FILE`` runs the paper's estimators, which read the star tracker and
the GRS voltages only. A layout written by ``taiji2 diagnose --write-config`` (``effects`` section,
docs/diagnosis.md section 6a) names effects those estimators do not model; this module removes the
ones they see from the raw arrays, by inverting the simulator's own definitions
(:mod:`taiji2_model.effect_catalog`) with the layout's nominal scale factors (the corrections
are small, so the nominal values suffice):

- ``cross_coupling`` imbalance (electrode gains 1 +- eta: divided out, exact) and misalignment
  (``a = m + eps x m``, first order in eps), ``scale_factor_drift`` (voltages times
  ``1 + rate (max(t, onset) - t_ref)``, exact), ``readout_nonlinearity`` (``a = (sqrt(1 + 4 k m) - 1) / (2 k)``,
  exact), ``tm_stiffness`` (``a = m + k H(s) m``, first order in k), each from its onset on;
- ``time_offset`` (and the layout's star-tracker offset against the GRS, ``timing``): the
  star-tracker readout rotated forward by ``offset x omega``, omega the body rate from the
  calibrated GRS angular acceleration (integrated, its constant fitted to the star tracker).

Effects on the dynamics (torque gain, inertia, gravity gradient, actuation timing) do not enter
these estimators; a c.m. drift, a thruster force leakage and the star-tracker noise are not
corrected (listed as such).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.signal import lfilter

from taiji2_model.config import SimConfig
from taiji2_model.effect_catalog import ANGULAR_READOUTS, LINEAR_READOUTS, suspension_filter
from taiji2_model.frames import (
    crf_to_tmrf,
    cross,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    rotvec_from_quat,
)

__all__ = ["correct_raw"]

_PAIR_COLUMNS = {"x": (0, 1), "y": (2, 3), "z": (4, 5)}
_NO_EFFECT = ("thruster_torque_gain", "inertia_error", "gravity_gradient", "actuation_delay", "thruster_response",
              "grs_time_offset")


def _on(t: np.ndarray, spec: Mapping[str, Any]) -> np.ndarray:
    onset = float(spec.get("onset_s", 0.0) or 0.0)
    return np.ones(t.shape, dtype=bool) if onset <= 0.0 else t >= onset


def _to_acc(volts: np.ndarray, g_ang: np.ndarray, g_lin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    first, second = volts[:, 0::2], volts[:, 1::2]
    return (first - second)[:, [1, 2, 0]] * g_ang, (first + second) * g_lin


def _to_volts(angular: np.ndarray, linear: np.ndarray, g_ang: np.ndarray, g_lin: np.ndarray) -> np.ndarray:
    diff = (angular / g_ang)[:, [2, 0, 1]]  # back to the pairs x, y, z
    total = linear / g_lin
    out = np.empty((angular.shape[0], 6))
    out[:, 0::2] = 0.5 * (total + diff)
    out[:, 1::2] = 0.5 * (total - diff)
    return out


def correct_raw(t_s: np.ndarray, quat_xyzw: np.ndarray, voltages_v: np.ndarray, config: SimConfig,
                grs_ids: Sequence[int] = (1, 2)) -> tuple[np.ndarray, np.ndarray, dict[str, list[str]]]:
    """Star-tracker and GRS arrays with the layout's known effects removed.

    Parameters
    ----------
    t_s : numpy.ndarray
        (n,) sample times [s] (the simulation clock of the effects' onsets).
    quat_xyzw : numpy.ndarray
        (n, 4) star-tracker attitude (NaN rows: missing).
    voltages_v : numpy.ndarray
        (n, len(grs_ids), 6) GRS voltages.
    config : SimConfig
        The extended layout (``effects`` section, ``timing``).
    grs_ids : sequence of int
        GRS in the columns of ``voltages_v``.

    Returns
    -------
    quat_xyzw, voltages_v : numpy.ndarray
        Corrected copies.
    report : dict
        ``corrected``, ``no_effect_on_these_estimators`` and ``not_corrected`` effect names.
    """
    t = np.asarray(t_s, dtype=np.float64)
    volts = np.array(voltages_v, dtype=np.float64)
    quat = np.array(quat_xyzw, dtype=np.float64)
    report: dict[str, list[str]] = {"corrected": [], "no_effect_on_these_estimators": [], "not_corrected": []}
    sensors = {s.grs_id: s for s in config.grs.sensors}
    specs = [dict(e) for e in config.effects if e.get("enabled", True)]
    for spec in specs:
        name = spec["name"]
        if name in _NO_EFFECT:
            report["no_effect_on_these_estimators"].append(name)
        elif name in ("com_drift", "thruster_force_leakage", "star_tracker_lowfreq_noise"):
            report["not_corrected"].append(name)
    for column, grs in enumerate(grs_ids):
        mine = [s for s in specs if int(s.get("grs", 1)) == grs and s["name"] in (
            "cross_coupling", "scale_factor_drift", "readout_nonlinearity", "tm_stiffness")]
        if not mine:
            continue
        v = volts[:, column]
        for spec in reversed(mine):  # voltage-side first: the imbalance, then the scale factor drift
            on = _on(t, spec)
            if spec["name"] == "cross_coupling" and np.any(spec.get("imbalance", 0.0)):
                eta = np.broadcast_to(np.asarray(spec.get("imbalance", 0.0), dtype=np.float64), 3)
                gains = np.ones(6)
                gains[0::2], gains[1::2] = 1.0 + eta, 1.0 - eta
                v = np.where(on[:, None], v / gains, v)
            elif spec["name"] == "scale_factor_drift":
                clock = t if float(spec.get("onset_s", 0.0) or 0.0) <= 0.0 else np.maximum(t, spec["onset_s"])
                factor = 1.0 + float(spec.get("rate_per_s", 0.0)) * (clock - float(spec.get("t_ref_s", 0.0)))
                columns = _PAIR_COLUMNS[spec.get("axis", "x")]
                v = v.copy()
                v[:, columns] = v[:, columns] * factor[:, None]
        sensor = sensors[grs]
        g_ang = np.asarray(sensor.angular_scale_factors, dtype=np.float64)
        g_lin = np.asarray(sensor.linear_scale_factors, dtype=np.float64)
        angular, linear = _to_acc(v, g_ang, g_lin)
        for spec in reversed(mine):  # acceleration-side, last applied first
            on = _on(t, spec)[:, None]
            if spec["name"] == "cross_coupling" and np.any(spec.get("misalignment_rad", 0.0)):
                eps = np.broadcast_to(np.asarray(spec.get("misalignment_rad", 0.0), dtype=np.float64), 3)
                angular = angular + on * cross(eps, angular)
                linear = linear + on * cross(eps, linear)
            elif spec["name"] == "readout_nonlinearity" and float(spec.get("k", 0.0)) != 0.0:
                k = float(spec["k"])
                readout = spec.get("readout", "x")
                target, index = ((angular, ANGULAR_READOUTS.index(readout)) if readout in ANGULAR_READOUTS
                                 else (linear, LINEAR_READOUTS.index(readout)))
                m = target[:, index]
                exact = (np.sqrt(np.maximum(1.0 + 4.0 * k * m, 0.0)) - 1.0) / (2.0 * k)
                target[:, index] = np.where(on[:, 0], exact, m)
            elif spec["name"] == "tm_stiffness" and float(spec.get("stiffness_s2", 0.0)) != 0.0:
                index = LINEAR_READOUTS.index(spec.get("axis", "x"))
                b, a = suspension_filter(float(spec.get("suspension_hz", 0.01)), float(spec.get("damping", 0.7)),
                                         config.sample_rate_hz)
                finite = np.nan_to_num(linear[:, index])
                linear[:, index] = linear[:, index] + on[:, 0] * float(spec["stiffness_s2"]) * lfilter(b, a, finite)
        volts[:, column] = _to_volts(angular, linear, g_ang, g_lin)
        report["corrected"] += [s["name"] for s in mine]
    offsets = [(float(s.get("offset_s", 0.0)), _on(t, s)) for s in specs if s["name"] == "time_offset"]
    _, st_offset, _ = config.timing.reduced
    if st_offset:
        offsets.append((st_offset, np.ones(t.shape, dtype=bool)))
    if offsets:
        omega = _body_rate(t, quat, volts, config, grs_ids)
        rotation = sum(np.where(on[:, None], offset * omega, 0.0) for offset, on in offsets)
        quat = quat_multiply(quat, quat_from_rotvec(rotation))
        report["corrected"] += ["time_offset"] * sum(1 for s in specs if s["name"] == "time_offset")
    return quat, volts, report


def _body_rate(t: np.ndarray, quat: np.ndarray, volts: np.ndarray, config: SimConfig, grs_ids: Sequence[int]
               ) -> np.ndarray:
    """(n, 3) body rate [rad/s]: the mean calibrated GRS angular acceleration (CRF) integrated, its
    initial value fitted to the star-tracker increments (NaN rows: skipped in the fit, rate held)."""
    dt = 1.0 / config.sample_rate_hz
    sensors = {s.grs_id: s for s in config.grs.sensors}
    crf = []
    for column, grs in enumerate(grs_ids):
        sensor = sensors[grs]
        angular, _ = _to_acc(volts[:, column], np.asarray(sensor.angular_scale_factors), np.ones(3))
        crf.append(angular @ crf_to_tmrf(grs, config.grs.alpha_rad))  # TMRF -> CRF: C^T a (row form)
    m = np.nan_to_num(np.mean(crf, axis=0))
    integrated = dt * np.cumsum(m, axis=0)
    inc = np.full((t.shape[0], 3), np.nan)
    inc[1:] = rotvec_from_quat(quat_multiply(quat_conjugate(quat[:-1]), quat[1:]))
    mid = 0.5 * (integrated[1:] + integrated[:-1])
    residual = inc[1:] / dt - mid
    good = np.all(np.isfinite(residual), axis=1)
    start = np.mean(residual[good], axis=0) if np.any(good) else np.zeros(3)
    return start + integrated
