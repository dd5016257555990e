"""Estimator parameters: the documented YAML file (``config/estimators.yaml``) to option objects.

The file is a ROS 2 parameters file (``<node>: ros__parameters: {...}``, nested mappings meaning
dotted names); :func:`load_parameters` returns the flat dotted-key dict of one node section with
the defaults filled in, and the ``*_options`` functions build the core's option dataclasses.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from taiji2_estimator_pkg.core.com_offset.model import ComOffsetOptions
from taiji2_estimator_pkg.core.com_offset.paper import PaperComOffsetOptions
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorOptions
from taiji2_estimator_pkg.core.scale_factor.paper import PaperScaleFactorOptions
from taiji2_estimator_pkg.core.validation import ValidationOptions

__all__ = [
    "DEFAULTS",
    "NODE_DEFAULTS",
    "com_offset_options",
    "default_parameters_file",
    "flatten",
    "load_parameters",
    "paper_com_offset_options",
    "paper_scale_factor_options",
    "scale_factor_options",
    "validation_options",
]

_VALIDATION = {
    "validation.grid_tolerance": 0.05,
    "validation.quaternion_norm_tolerance": 1e-6,
    "validation.sign_flip_policy": "correct",
    "validation.max_rate_rad_s": 1e-3,
    "validation.saturation_v": 10.0,
}

DEFAULTS: dict[str, dict[str, Any]] = {
    "scale_factor_estimator": {
        "layout": "type1", "method": "gls", "grs_ids": [1, 2], "gate_probability": 1e-6, "gate_refresh_s": 1.0,
        "max_bridged_gap_s": 10.0, "gap_acceleration_sigma_rad_s2": 1e-9, "snap_tolerance": 1e-10,
        "determination_margin": 20.0, "paper.window": 2001, "paper.polyorder": 2,
        "paper.initial_sigma_fraction": 0.1, "paper.gate_probability": 0.0, **_VALIDATION,
        "checkpoint_file": "", "checkpoint_period_s": 10.0,
    },
    "com_offset_estimator": {
        "layout": "type1", "method": "gls", "grs_ids": [1, 2], "detrend": "linear", "trend_time_scale_s": 1000.0,
        "joint": True, "adapt_noise": True, "gate_probability": 1e-6, "gate_refresh_s": 1.0, "snap_tolerance": 1e-10,
        "determination_margin": 20.0, "paper.window": 2001,
        "paper.polyorder": 2, "paper.initial_sigma_m": 0.01, "paper.detrend_sigma": 1e-6,
        "paper.gate_probability": 0.0, **_VALIDATION, "checkpoint_file": "", "checkpoint_period_s": 10.0,
    },
}
"""Default of every parameter of the estimation core, per node (dotted keys)."""

NODE_DEFAULTS: dict[str, dict[str, Any]] = {
    "scale_factor_estimator": {"publish_period_s": 1.0, "max_stream_lag_s": 10.0, "max_stream_silence_s": 2.0,
                               "starved_after_s": 5.0, "missing_warn_fraction": 0.001},
    "com_offset_estimator": {"publish_period_s": 1.0, "max_stream_lag_s": 10.0, "max_stream_silence_s": 2.0,
                             "starved_after_s": 5.0, "missing_warn_fraction": 0.001,
                             "use_rate_estimate": False, "paper_batch_period_s": 600.0,
                             "scale_factor_wait_s": 30.0, "max_scale_factor_lag_s": 3600.0},
}
"""Defaults of the keys only the ROS nodes read (publishing, stream alignment, diagnostics), per node."""


def default_parameters_file() -> Path | None:
    """``config/estimators.yaml`` of the source tree or of an installation, if found."""
    from taiji2_model.package_files import config_dirs

    candidates = [directory / "estimators.yaml" for directory in config_dirs("taiji2_estimator_pkg")]
    return next((c for c in candidates if c.is_file()), None)


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mapping to dotted keys (lists are values)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def load_parameters(node: str, source: str | os.PathLike[str] | Mapping[str, Any] | None = None,
                    overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Flat parameters of one node: defaults, then the file's section, then overrides.

    Parameters
    ----------
    node : str
        ``"scale_factor_estimator"`` or ``"com_offset_estimator"``.
    source : path or mapping, optional
        Parameters file (default: :func:`default_parameters_file`) or an already parsed mapping.
    overrides : mapping, optional
        Dotted keys.

    Returns
    -------
    dict
        Dotted key to value.

    Raises
    ------
    ValueError
        Unknown node or unknown key (names the key).
    """
    if node not in DEFAULTS:
        raise ValueError(f"node: one of {sorted(DEFAULTS)}, got {node!r}")
    params = dict(DEFAULTS[node])
    raw: Any = source
    if raw is None:
        path = default_parameters_file()
        raw = {} if path is None else yaml.safe_load(path.read_text(encoding="utf-8"))
    elif not isinstance(raw, Mapping):
        raw = yaml.safe_load(Path(raw).read_text(encoding="utf-8"))
    section = (raw or {}).get(node, {}) or {}
    section = section.get("ros__parameters", section) or {}
    for key, value in {**flatten(section), **dict(overrides or {})}.items():
        if key in NODE_DEFAULTS.get(node, {}):
            continue  # node glue, not the core
        if key not in params:
            raise ValueError(f"{node}.{key}: unknown parameter")
        params[key] = value
    return params


def _probability(value: Any) -> float | None:
    number = float(value) if value is not None else 0.0
    return None if number <= 0.0 else number


def validation_options(params: Mapping[str, Any], sample_rate_hz: float = 10.0,
                       star_tracker_sigma_rad: float = 9.696273622190719e-7) -> ValidationOptions:
    """:class:`ValidationOptions` from flat parameters."""
    saturation = params["validation.saturation_v"]
    return ValidationOptions(
        sample_rate_hz=sample_rate_hz,
        grid_tolerance=float(params["validation.grid_tolerance"]),
        quaternion_norm_tolerance=float(params["validation.quaternion_norm_tolerance"]),
        sign_flip_policy=str(params["validation.sign_flip_policy"]),
        max_rate_rad_s=float(params["validation.max_rate_rad_s"]),
        star_tracker_sigma_rad=star_tracker_sigma_rad,
        saturation_v=None if not saturation or float(saturation) <= 0.0 else float(saturation),
        grs_ids=tuple(int(g) for g in params["grs_ids"]),
    )


def scale_factor_options(params: Mapping[str, Any]) -> ScaleFactorOptions:
    """:class:`ScaleFactorOptions` from flat ``scale_factor_estimator`` parameters."""
    return ScaleFactorOptions(
        gate_probability=_probability(params["gate_probability"]),
        gate_refresh_s=float(params["gate_refresh_s"]),
        max_bridged_gap_s=float(params["max_bridged_gap_s"]),
        gap_acceleration_sigma_rad_s2=float(params["gap_acceleration_sigma_rad_s2"]),
        snap_tolerance=float(params["snap_tolerance"]),
        determination_margin=float(params["determination_margin"]),
        validation=validation_options(params),
    )


def paper_scale_factor_options(params: Mapping[str, Any]) -> PaperScaleFactorOptions:
    """:class:`PaperScaleFactorOptions` from flat ``scale_factor_estimator`` parameters."""
    return PaperScaleFactorOptions(
        window=int(params["paper.window"]), polyorder=int(params["paper.polyorder"]),
        initial_sigma_fraction=float(params["paper.initial_sigma_fraction"]),
        gate_probability=_probability(params["paper.gate_probability"]), validation=validation_options(params))


def com_offset_options(params: Mapping[str, Any]) -> ComOffsetOptions:
    """:class:`ComOffsetOptions` from flat ``com_offset_estimator`` parameters."""
    return ComOffsetOptions(
        detrend=str(params["detrend"]), trend_time_scale_s=float(params["trend_time_scale_s"]),
        joint=bool(params["joint"]), adapt_noise=bool(params["adapt_noise"]),
        gate_probability=_probability(params["gate_probability"]), gate_refresh_s=float(params["gate_refresh_s"]),
        snap_tolerance=float(params["snap_tolerance"]),
        determination_margin=float(params["determination_margin"]), validation=validation_options(params))


def paper_com_offset_options(params: Mapping[str, Any]) -> PaperComOffsetOptions:
    """:class:`PaperComOffsetOptions` from flat ``com_offset_estimator`` parameters."""
    return PaperComOffsetOptions(
        window=int(params["paper.window"]), polyorder=int(params["paper.polyorder"]),
        initial_sigma_m=float(params["paper.initial_sigma_m"]), detrend_sigma=float(params["paper.detrend_sigma"]),
        gate_probability=_probability(params["paper.gate_probability"]), validation=validation_options(params))
