"""The nominal model extended with known effects: the corrected calibration and the extended layout.

Once the diagnosis has named effects, "how far the gap shrinks" ends in the parameters the user
calibrates: the nominal model is extended with the named effects at their fitted values (timing
conventions folded into the model's timing, exactly; physical effects as fixed channel changes,
exact where the signature has an exact or series form, first order otherwise, from their onset on)
and G and d are re-calibrated under it (:func:`corrected_calibration`). The same extension is
written as a layout (:func:`extended_layout`: the nominal layout with its ``timing`` section
updated and an ``effects`` section), which ``taiji2 diagnose --config`` reads back
(:func:`extend_model`): the named effects are then part of the nominal model, and the gap they
closed is no gap.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, candidate_catalog
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.record import RecordSettings, calibrate
from taiji2_model.effect_catalog import GravityGradient

__all__ = ["corrected_calibration", "extend_model", "extended_layout", "fixed_from_specs"]

_AXES = "xyz"
TIMING_CONVENTION = {  # timing family -> (delay, star-tracker offset, lag) per unit of its magnitude
    "actuation_delay": (1.0, 0.0, 0.0),
    "thruster_response": (0.0, 0.0, 1.0),
    "grs_time_offset": (1.0, -1.0, 0.0),
    "time_offset": (0.0, 1.0, 0.0),
}
"""How a timing effect present from the start changes the reduced timing (D, e, T) (docs/interfaces.md)."""

Fixed = tuple[Candidate, np.ndarray, float | None, float | None]
"""(variant, values, onset [s] or None, drift reference time [s] or None)."""


def _onset(spec: Mapping[str, Any]) -> float | None:
    onset = float(spec.get("onset_s", 0.0) or 0.0)
    return onset if onset > 0.0 else None


def fixed_from_specs(specs: Sequence[Mapping[str, Any]], model: NominalModel, settings: RecordSettings
                     ) -> tuple[NominalModel, list[Fixed]]:
    """The model's timing with the timing effects present from the start, and the fixed variants of
    the other catalog effects (``effects`` section of a layout).

    The star-tracker low-frequency noise is a noise, not a channel change: it is not modelled here
    (its extra spectrum would be a change of the whitening).
    """
    catalog, _ = candidate_catalog(None, settings.orbit_period_s, settings.suspension_hz, settings.damping,
                                   settings.st_corner_hz, model)
    by_key = {c.key: c for c in catalog}
    delay, st_offset, lag = model.delay_s, model.st_offset_s, model.time_constant_s
    fixed: list[Fixed] = []

    def add(key: str, values: Sequence[float], onset: float | None, t_ref: float | None = None) -> None:
        if any(v != 0.0 for v in values):
            fixed.append((by_key[key], np.asarray(values, dtype=np.float64), onset, t_ref))

    for spec in specs:
        if not spec.get("enabled", True):
            continue
        name, onset = str(spec["name"]), _onset(spec)
        if name in TIMING_CONVENTION and onset is None:
            value = float(spec.get("offset_s", spec.get("delay_s", spec.get("time_constant_s", 0.0))))
            d_delay, d_st, d_lag = TIMING_CONVENTION[name]
            delay, st_offset, lag = delay + d_delay * value, st_offset + d_st * value, lag + d_lag * value
        elif name in TIMING_CONVENTION:
            value = float(spec.get("offset_s", spec.get("delay_s", spec.get("time_constant_s", 0.0))))
            add(name, [value], onset)
        elif name == "scale_factor_drift":
            add(f"scale_factor_drift[grs{spec.get('grs', 1)}.{spec.get('axis', 'x')}]", [spec.get("rate_per_s", 0.0)],
                onset, float(spec.get("t_ref_s", 0.0)))
        elif name == "cross_coupling":
            grs = spec.get("grs", 1)
            for axis, value in zip(_AXES, np.broadcast_to(spec.get("misalignment_rad", 0.0), 3), strict=True):
                add(f"cross_coupling[grs{grs}.misalign_{axis}]", [float(value)], onset)
            for axis, value in zip(_AXES, np.broadcast_to(spec.get("imbalance", 0.0), 3), strict=True):
                add(f"cross_coupling[grs{grs}.imbalance_{axis}]", [float(value)], onset)
        elif name == "thruster_torque_gain":
            gain = spec.get("gain", 0.0)
            vector = np.zeros(3)
            if spec.get("axis") is not None:
                vector[_AXES.index(spec["axis"])] = float(gain)
            else:
                vector[:] = np.broadcast_to(gain, 3)
            for axis, value in zip(_AXES, vector, strict=True):
                add(f"thruster_torque_gain[{axis}]", [value], onset)
        elif name == "com_drift":
            which = int(spec.get("grs", 0))
            label = "both" if which == 0 else f"grs{which}"
            for axis, value in zip(_AXES, np.broadcast_to(spec.get("rate_m_s", 0.0), 3), strict=True):
                add(f"com_drift[{label}.{axis}]", [float(value)], onset, float(spec.get("t_ref_s", 0.0)))
        elif name == "readout_nonlinearity":
            add(f"readout_nonlinearity[grs{spec.get('grs', 1)}.{spec.get('readout', 'x')}]", [spec.get("k", 0.0)],
                onset)
        elif name == "inertia_error":
            for axis, value in zip(_AXES, np.broadcast_to(spec.get("relative", 0.0), 3), strict=True):
                add(f"inertia_error[{axis}]", [float(value)], onset)
            for pair, value in zip(("xy", "xz", "yz"), np.broadcast_to(spec.get("products_kg_m2", 0.0), 3),
                                   strict=True):
                add(f"inertia_error[{pair}]", [float(value)], onset)
        elif name == "gravity_gradient":
            params = {k: spec[k] for k in ("orbit_period_s", "orbit_normal", "phase_rad", "scale") if k in spec}
            effect = GravityGradient(**params)
            tau_0, tau_c, tau_s = effect.harmonic_coefficients_n_m(model.inertia_kg_m2)
            two_phase = 2.0 * effect.phase_rad
            for axis in range(3):
                cos_n_m = tau_c[axis] * math.cos(two_phase) + tau_s[axis] * math.sin(two_phase)
                sin_n_m = -tau_c[axis] * math.sin(two_phase) + tau_s[axis] * math.cos(two_phase)
                add(f"gravity_gradient[{_AXES[axis]}]", [cos_n_m, sin_n_m, tau_0[axis]], onset)
        elif name == "tm_stiffness":
            add(f"tm_stiffness[grs{spec.get('grs', 1)}.{spec.get('axis', 'x')}]", [spec.get("stiffness_s2", 0.0)],
                onset)
        elif name == "thruster_force_leakage":
            matrix = np.broadcast_to(np.asarray(spec.get("leakage_per_m", 0.0), dtype=np.float64), (3, 3))
            for c in range(3):
                for k in range(3):
                    add(f"thruster_force_leakage[F{_AXES[c]}.T{_AXES[k]}]", [float(matrix[c, k])], onset)
    return replace(model, delay_s=delay, st_offset_s=st_offset, time_constant_s=lag), fixed


def extend_model(model: NominalModel, settings: RecordSettings) -> tuple[NominalModel, list[Fixed]]:
    """The model with its layout's ``effects`` section applied (timing folded in, the rest fixed)."""
    if not model.effects:
        return model, []
    return fixed_from_specs(model.effects, model, settings)


def named_extension(reports: Sequence[Any], candidates: Mapping[str, Candidate], onsets: Mapping[str, float],
                    t_mid_s: float, model: NominalModel, families: Sequence[Mapping[str, Any]] = ()
                    ) -> tuple[tuple[float, float, float], list[Fixed], list[dict[str, Any]]]:
    """The named effects as a model extension: timing changes (D, e, T), fixed variants and catalog specs.

    A family named as one candidate (``families``: the standing entries of the verdict's
    ``families``) enters with every variant at the family fit's values, the variants selection did
    not take included: the calibration is corrected for the whole effect, not for its stack.
    """
    timing = [0.0, 0.0, 0.0]
    fixed: list[Fixed] = []
    specs: list[dict[str, Any]] = []
    values_of: dict[str, np.ndarray] = {}
    for family in families:
        magnitudes = iter(family["magnitudes"])
        for key in family["variants"]:
            values_of[key] = np.array([next(magnitudes) for _ in candidates[key].params], dtype=np.float64)
    # a step-only parameter of an effect from the start is not reported (Candidate.step_params): zero
    entries = [(report.key, np.array([report.parameters.get(p, {"value": 0.0})["value"]
                                      for p in candidates[report.key].params], dtype=np.float64))
               for report in reports if report.accepted and report.key in candidates and report.key not in values_of]
    for key, values in [*entries, *values_of.items()]:
        candidate = candidates[key]
        onset = onsets.get(key)
        if candidate.name in TIMING_CONVENTION and onset is None:
            for i, unit in enumerate(TIMING_CONVENTION[candidate.name]):
                timing[i] += unit * float(values[0])
            specs.append({"timing": candidate.name, "value": float(values[0])})
            continue
        t_ref = t_mid_s if candidate.onset_kind == "ramp" else None
        fixed.append((candidate, values, onset, t_ref))
        spec = dict(candidate.inject(values, model))
        if onset is not None:
            spec["onset_s"] = float(onset)
        if t_ref is not None:
            spec["t_ref_s"] = float(t_ref)
        specs.append(spec)
    return (timing[0], timing[1], timing[2]), fixed, specs


def corrected_calibration(inp: DiagnosisInput, model: NominalModel, settings: RecordSettings,
                          timing: tuple[float, float, float], fixed: Sequence[Fixed], nominal: Mapping[str, Any],
                          t_mid_s: float, iterations: int, progress: Callable[[str], None],
                          free: Sequence[Fixed] = ()) -> dict[str, Any]:
    """G and d re-calibrated under the model extended with the named effects, and their shift.

    The named physical effects (``free``) are re-fitted with G and d (:func:`.record.calibrate`),
    not held at their named values: an effect that aliases with G (an electrode imbalance of pair e
    moves G of its angular readout by ``eta d / r``, ``d / r`` ~ 6 on the Type-1 layout) held at a
    value off by its own sigma moves G by many of G's conditional sigmas, and the corrected G was
    then reported further from the truth than the nominal one. The joint fit gives the same G
    where the named values are the joint optimum, G's sigma marginal over the effects, and is
    relinearised at every iteration (no first-order error of a large effect left).

    Parameters
    ----------
    inp : DiagnosisInput
        The data.
    model : NominalModel
        The (nominal) model the diagnosis used.
    settings : RecordSettings
        Fit band, candidate settings.
    timing : tuple of float
        Changes of the reduced timing (D, e, T) [s] by the named timing effects present from the start.
    fixed : sequence of Fixed
        Effects held at their values (the layout's known effects, named timing effects with an onset).
    nominal : mapping
        The nominal calibration (``result.calibration``: ``g_angular``, ``com_offset_m``).
    t_mid_s : float
        Drift reference time [s].
    iterations : int
        Gauss-Newton iterations.
    progress : callable
        Progress messages.
    free : sequence of Fixed
        Named effects re-fitted with G and d (their values: the starting point).

    Returns
    -------
    dict
        ``g_angular``, ``g_angular_sigma_relative``, ``com_offset_m``, ``com_offset_sigma_m``,
        ``covariance`` (12 x 12 of the relative G (GRS1 phi, theta, psi, GRS2 ...) and d (GRS1 x, y,
        z, GRS2 ...), marginal over the re-fitted effects), ``g_shift_sigma`` (corrected / nominal - 1
        in corrected sigmas), ``d_shift_sigma``, ``timing`` (the extended model's reduced timing),
        ``chi2``, ``dof``, ``refitted`` (variant key, onset, re-fitted values and sigmas of ``free``),
        ``last_update_sigma`` (the Gauss-Newton's last largest update [sigma]), ``iterations`` (those run)
        and ``beyond_series_bound`` (free effects whose value left the range of their series form).
    """
    extended = replace(model, delay_s=model.delay_s + timing[0], st_offset_s=model.st_offset_s + timing[1],
                       time_constant_s=max(model.time_constant_s + timing[2], 0.0))
    info: dict[str, Any] = {}
    g, d, sigma_g, sigma_d = calibrate(inp, extended, settings, iterations, progress, fixed, t_mid_s, info, free)
    refitted = [{"variant": entry[0].key, "onset_s": entry[2], "values": values.tolist(), "sigmas": sigmas.tolist()}
                for entry, values, sigmas in zip(free, info.get("free_values", []), info.get("free_sigma", []),
                                                 strict=False)]
    g_nominal = np.asarray(nominal["g_angular"], dtype=np.float64)
    d_nominal = np.asarray(nominal["com_offset_m"], dtype=np.float64)
    return {
        "g_angular": g.tolist(), "g_angular_sigma_relative": sigma_g.tolist(),
        "com_offset_m": d.tolist(), "com_offset_sigma_m": sigma_d.tolist(),
        "covariance": np.asarray(info.get("cov", np.full((12, 12), np.nan))).tolist(),
        "covariance_order": [f"G.{grs}.{axis} (relative)" for grs in (1, 2) for axis in ("phi", "theta", "psi")]
        + [f"d.{grs}.{axis} [m]" for grs in (1, 2) for axis in _AXES],
        "g_shift_sigma": ((g / g_nominal - 1.0) / sigma_g).tolist(),
        "d_shift_sigma": ((d - d_nominal) / sigma_d).tolist(),
        "timing": {"delay_s": extended.delay_s, "st_offset_s": extended.st_offset_s,
                   "time_constant_s": extended.time_constant_s},
        "chi2": info.get("chi2"), "dof": info.get("dof"), "refitted": refitted,
        "last_update_sigma": info.get("last_update_sigma"), "iterations": info.get("iterations"),
        "beyond_series_bound": info.get("beyond_series_bound", []),
    }


def extended_layout(layout: Mapping[str, Any], timing_effects: Sequence[Mapping[str, Any]],
                    effects: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The nominal layout (``SimConfig.to_dict()``) extended with the named effects.

    Timing effects present from the start go into its ``timing`` section (``actuation_delay`` ->
    ``actuation_latency_s``, ``thruster_response`` -> ``thruster_time_constant_s``,
    ``grs_time_offset`` -> ``grs_stamp``, ``time_offset`` -> ``star_tracker_stamp_offset_s``); the
    others, with their onsets, are appended to its ``effects`` section.
    """
    out = {key: value for key, value in layout.items()}
    timing = dict(out.get("timing") or {})
    keys = {"actuation_delay": "actuation_latency_s", "thruster_response": "thruster_time_constant_s",
            "grs_time_offset": "grs_stamp", "time_offset": "star_tracker_stamp_offset_s"}
    for item in timing_effects:
        key = keys[item["timing"]]
        timing[key] = float(timing.get(key, 0.0) or 0.0) + float(item["value"])
    if timing.get("thruster_time_constant_s", 0.0) < 0.0:
        timing["thruster_time_constant_s"] = 0.0
    out["timing"] = timing
    out["effects"] = [dict(e) for e in (out.get("effects") or [])] + [dict(e) for e in effects]
    return out
