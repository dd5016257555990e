"""Simulator configuration: YAML layouts, overrides and validation (schema in :mod:`.config_schema`).

Every physical value the simulator uses comes from here; the built-in layouts ``type1`` and
``type2`` are YAML files (``src/taiji2_sim_pkg/config/<name>.yaml`` in the source tree,
``share/taiji2_sim_pkg/config`` once installed) whose keys are documented in the files.

Bad input raises :class:`ConfigError`, whose message names the offending parameter by its dotted
path, e.g. ``"spacecraft.inertia_kg_m2: not symmetric positive definite"``.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from taiji2_model.config_schema import (
    _VECTOR_NOISE_KEYS,
    _VECTOR_NOISE_UNITS,
    NOISE_SOURCE_NAMES,
    ConfigError,
    GrsAssemblyConfig,
    GrsConfig,
    GrsVoltageNoiseConfig,
    ManeuverConfig,
    NoiseConfig,
    SimConfig,
    SpacecraftConfig,
    SrpNoiseConfig,
    StarTrackerNoiseConfig,
    ThrusterConfig,
    TimingConfig,
    VectorNoiseConfig,
    _freeze,
)
from taiji2_model.grs import linear_scale_factors_from_angular
from taiji2_model.package_files import config_dirs
from taiji2_model.timing import GRS_STAMP_CONVENTIONS, grs_stamp_offset_s

__all__ = [
    "NOISE_SOURCE_NAMES",
    "ConfigError",
    "GrsAssemblyConfig",
    "GrsConfig",
    "GrsVoltageNoiseConfig",
    "ManeuverConfig",
    "NoiseConfig",
    "SimConfig",
    "SpacecraftConfig",
    "SrpNoiseConfig",
    "StarTrackerNoiseConfig",
    "ThrusterConfig",
    "TimingConfig",
    "VectorNoiseConfig",
    "builtin_layouts",
    "load_config",
]

_PACKAGE = "taiji2_model"
_CONFIG_DIR_ENV = "TAIJI2_SIM_CONFIG_DIR"
_LAYOUT_SECTIONS = {"sample_rate_hz", "spacecraft", "grs", "maneuver", "thrusters", "noise"}
#: libyaml's safe loader where PyYAML was built with it (5x faster: every layout lookup parses the
#: config directory), else the pure-Python one; both accept the same YAML
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# Numerical (not physical) tolerances of the validation.
_SYMMETRY_RTOL = 1e-12  # relative asymmetry of J accepted as rounding
_UNIT_NORM_TOL = 1e-6  # |q| - 1 accepted (and then normalised) for the initial attitude


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------


def _config_dirs() -> list[Path]:
    """Candidate directories holding the built-in layout files, most specific first."""
    env_dir = os.environ.get(_CONFIG_DIR_ENV)
    return ([Path(env_dir)] if env_dir else []) + config_dirs(_PACKAGE)


def _is_layout_file(path: Path) -> bool:
    """A layout file is a YAML mapping with the top-level sections of a simulator config; the same
    directory also holds node parameter files, which are not layouts."""
    try:
        with open(path, encoding="utf-8") as stream:
            content = yaml.load(stream, Loader=_YAML_LOADER)
    except (OSError, yaml.YAMLError):
        return False
    return isinstance(content, dict) and _LAYOUT_SECTIONS <= set(content)


def builtin_layouts() -> dict[str, Path]:
    """Built-in layouts found on this installation.

    Returns
    -------
    dict of str to pathlib.Path
        Layout name (file stem, e.g. ``"type1"``) to its YAML file; the first directory of
        :func:`_config_dirs` that holds a layout wins. Other YAML files there (node parameters)
        are skipped.
    """
    layouts: dict[str, Path] = {}
    for directory in _config_dirs():
        if directory.is_dir():
            for path in sorted(directory.glob("*.yaml")):
                if _is_layout_file(path):
                    layouts.setdefault(path.stem, path)
            if layouts:
                break
    return layouts


def load_config(
    source: str | os.PathLike[str] | Mapping[str, Any],
    overrides: Mapping[str, Any] | None = None,
) -> SimConfig:
    """Load, override and validate a configuration.

    Parameters
    ----------
    source : str, path-like or mapping
        Built-in layout name (``"type1"``, ``"type2"``), path to a YAML file, or an already
        parsed nested mapping (e.g. the output of :meth:`SimConfig.to_dict`).
    overrides : mapping of str to object, optional
        Dotted key to new value, e.g. ``{"noise.star_tracker.enabled": False,
        "maneuver.duration_s": 3600.0, "grs.sensors.0.com_offset_m": [0, 0.18, 0]}``.
        List elements are addressed by their index.

    Returns
    -------
    SimConfig
        The validated configuration.

    Raises
    ------
    ConfigError
        Unknown layout, unreadable file, missing or unknown key, bad override key, or a value that
        is not physical (the message names the parameter).
    """
    raw: Any
    if isinstance(source, Mapping):
        raw = copy.deepcopy(dict(source))
        default_name = str(raw.get("layout", "custom"))
    else:
        path = Path(source)
        layouts = builtin_layouts()
        if str(source) in layouts:
            path = layouts[str(source)]
        elif not (path.suffix in (".yaml", ".yml") or path.exists()):
            known = ", ".join(sorted(layouts)) or "none found"
            raise ConfigError("layout", f"unknown layout {str(source)!r} (built-in: {known})")
        try:
            with open(path, encoding="utf-8") as stream:
                raw = yaml.load(stream, Loader=_YAML_LOADER)
        except OSError as error:
            raise ConfigError("layout", f"cannot read {str(path)!r}: {error}") from error
        except yaml.YAMLError as error:
            raise ConfigError("layout", f"{str(path)!r} is not valid YAML: {error}") from error
        default_name = path.stem
    if not isinstance(raw, dict):
        raise ConfigError("<root>", "configuration must be a mapping")
    for key, value in (overrides or {}).items():
        _apply_override(raw, key, value)
    return _parse(raw, default_name)


def _apply_override(raw: dict[str, Any], dotted_key: str, value: Any) -> None:
    parts = dotted_key.split(".")
    node: Any = raw
    for depth, part in enumerate(parts):
        here = ".".join(parts[: depth + 1])
        last = depth == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise ConfigError(here, "override addresses a list element that does not exist")
            if last:
                node[int(part)] = value
            else:
                node = node[int(part)]
        elif isinstance(node, dict):
            if part not in node:
                raise ConfigError(here, "override key does not exist in the configuration")
            if last:
                node[part] = value
            else:
                node = node[part]
        else:
            raise ConfigError(here, "override descends into a scalar value")


# --------------------------------------------------------------------------------------------
# Parsing and validation
# --------------------------------------------------------------------------------------------


class _Section:
    """A mapping being parsed: tracks its dotted path and which keys were consumed."""

    def __init__(self, raw: Any, path: str) -> None:
        if not isinstance(raw, dict):
            raise ConfigError(path, "must be a mapping")
        self.raw = raw
        self.path = path
        self.used: set[str] = set()

    def name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def get(self, key: str) -> Any:
        if key not in self.raw:
            raise ConfigError(self.name(key), "missing key")
        self.used.add(key)
        return self.raw[key]

    def optional(self, key: str) -> Any:
        self.used.add(key)
        return self.raw.get(key)

    def section(self, key: str) -> _Section:
        return _Section(self.get(key), self.name(key))

    def finish(self) -> None:
        unknown = sorted(set(self.raw) - self.used)
        if unknown:
            raise ConfigError(self.name(str(unknown[0])), "unknown key")

    # typed getters ---------------------------------------------------------------------------
    def number(self, key: str, *, positive: bool = False, non_negative: bool = False) -> float:
        return _number(self.get(key), self.name(key), positive=positive, non_negative=non_negative)

    def array(self, key: str, shape: tuple[int, ...], *, non_negative: bool = False,
              positive: bool = False, broadcast: bool = False) -> np.ndarray:
        return _array(self.get(key), self.name(key), shape, non_negative=non_negative,
                      positive=positive, broadcast=broadcast)

    def flag(self, key: str) -> bool:
        value = self.get(key)
        if not isinstance(value, bool):
            raise ConfigError(self.name(key), f"must be true or false, got {value!r}")
        return value


def _number(value: Any, name: str, *, positive: bool = False, non_negative: bool = False) -> float:
    if isinstance(value, bool):
        raise ConfigError(name, f"must be a number, got {value!r}")
    try:
        number = float(value)  # also accepts "1e-9", which YAML 1.1 reads as a string
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ConfigError(name, f"must be finite, got {number!r}")
    if positive and not number > 0.0:
        raise ConfigError(name, f"must be > 0, got {number!r}")
    if non_negative and number < 0.0:
        raise ConfigError(name, f"must be >= 0, got {number!r}")
    return number


def _array(value: Any, name: str, shape: tuple[int, ...], *, non_negative: bool = False,
           positive: bool = False, broadcast: bool = False) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be numeric with shape {shape}, got {value!r}") from None
    if broadcast and array.ndim == 0:
        array = np.full(shape, float(array))
    if array.shape != shape:
        raise ConfigError(name, f"wrong shape {array.shape}, expected {shape}")
    if not np.all(np.isfinite(array)):
        raise ConfigError(name, "must be finite")
    if positive and not np.all(array > 0.0):
        raise ConfigError(name, f"must be > 0, got {array.tolist()}")
    if non_negative and np.any(array < 0.0):
        raise ConfigError(name, f"must be >= 0, got {array.tolist()}")
    return _freeze(array)


def _inertia(section: _Section) -> np.ndarray:
    name = section.name("inertia_kg_m2")
    inertia = _array(section.get("inertia_kg_m2"), name, (3, 3))
    scale = float(np.max(np.abs(inertia)))
    if scale == 0.0 or np.max(np.abs(inertia - inertia.T)) > _SYMMETRY_RTOL * scale:
        raise ConfigError(name, "not symmetric positive definite (not symmetric)")
    try:
        np.linalg.cholesky(inertia)
    except np.linalg.LinAlgError:
        raise ConfigError(name, "not symmetric positive definite (not positive definite)") from None
    # also the physical triangle inequalities of principal moments
    moments = np.linalg.eigvalsh(inertia)
    if moments[2] > moments[0] + moments[1]:
        raise ConfigError(name, "principal moments violate the triangle inequality J3 <= J1 + J2")
    return _freeze(0.5 * (inertia + inertia.T))


def _parse_spacecraft(section: _Section) -> SpacecraftConfig:
    mass_kg = section.number("mass_kg", positive=True)
    inertia = _inertia(section)
    quat = np.array(section.array("initial_attitude_xyzw", (4,)))
    norm = float(np.linalg.norm(quat))
    if abs(norm - 1.0) > _UNIT_NORM_TOL:
        raise ConfigError(section.name("initial_attitude_xyzw"), f"must be a unit quaternion, |q| = {norm}")
    rate = section.array("initial_rate_rad_s", (3,))
    section.finish()
    return SpacecraftConfig(mass_kg, inertia, _freeze(quat / norm), rate)


def _parse_grs(section: _Section) -> GrsAssemblyConfig:
    alpha_deg = section.number("alpha_deg")
    range_m_s2 = section.number("range_m_s2", positive=True)
    saturation = section.optional("readout_saturation")
    if saturation is None:
        saturation = True
    elif not isinstance(saturation, bool):
        raise ConfigError(section.name("readout_saturation"), f"must be true or false, got {saturation!r}")
    tm_mass_kg = section.number("tm_mass_kg", positive=True)
    tm_side_m = section.number("tm_side_m", positive=True)
    lever_arm_m = section.number("electrode_lever_arm_m", positive=True)
    ratio_m = tm_side_m**2 / (6.0 * lever_arm_m)
    raw_sensors = section.get("sensors")
    name = section.name("sensors")
    if not isinstance(raw_sensors, list) or len(raw_sensors) != 2:
        raise ConfigError(name, "must be a list of exactly two GRS (GRS1, GRS2)")
    sensors = []
    for index, raw in enumerate(raw_sensors):
        sensor = _Section(raw, f"{name}.{index}")
        grs_id = sensor.get("grs_id")
        if grs_id != index + 1 or isinstance(grs_id, bool):
            raise ConfigError(sensor.name("grs_id"), f"must be {index + 1} (GRS1 first, GRS2 second)")
        com_offset_m = sensor.array("com_offset_m", (3,))
        angular = sensor.array("angular_scale_factors", (3,), positive=True)
        linear_raw = sensor.optional("linear_scale_factors")
        if linear_raw is None:
            # the paper's consistent linear conversion: G_Px, G_Py, G_Pz = r (G_Ppsi, G_Pphi, G_Ptheta)
            linear = _freeze(linear_scale_factors_from_angular(angular, ratio_m))
        else:
            linear = _array(linear_raw, sensor.name("linear_scale_factors"), (3,), positive=True)
        sensor.finish()
        sensors.append(GrsConfig(index + 1, com_offset_m, angular, linear))
    section.finish()
    return GrsAssemblyConfig(alpha_deg, range_m_s2, tm_mass_kg, tm_side_m, lever_arm_m,
                             (sensors[0], sensors[1]), saturation)


def _parse_maneuver(section: _Section) -> ManeuverConfig:
    result = ManeuverConfig(
        period_s=section.number("period_s", positive=True),
        amplitude_n_m=section.array("amplitude_n_m", (3,), broadcast=True),
        phase_s=section.array("phase_s", (3,), broadcast=True),
        start_s=section.number("start_s"),
        duration_s=section.number("duration_s", non_negative=True),
    )
    section.finish()
    return result


def _parse_thrusters(section: _Section) -> ThrusterConfig:
    lever_arm_m = section.number("lever_arm_m", positive=True)
    min_thrust_n = section.number("min_thrust_n", non_negative=True)
    max_thrust_n = section.number("max_thrust_n", positive=True)
    if max_thrust_n <= min_thrust_n:
        raise ConfigError(section.name("max_thrust_n"), f"must exceed min_thrust_n = {min_thrust_n}")
    section.finish()
    return ThrusterConfig(lever_arm_m, min_thrust_n, max_thrust_n)


def _parse_noise(section: _Section) -> NoiseConfig:
    sources: dict[str, Any] = {}
    for source_name, unit in _VECTOR_NOISE_UNITS.items():
        sub = section.section(source_name)
        enabled = sub.flag("enabled")
        asd = sub.array(_VECTOR_NOISE_KEYS[unit], (3,), non_negative=True, broadcast=True)
        sub.finish()
        sources[source_name] = VectorNoiseConfig(enabled, asd, unit)
    sub = section.section("srp")
    sources["srp"] = SrpNoiseConfig(
        enabled=sub.flag("enabled"),
        asd_at_f_ref_m_s2_rthz=sub.number("asd_at_f_ref_m_s2_rthz", non_negative=True),
        f_ref_hz=sub.number("f_ref_hz", positive=True),
        f_corner_hz=sub.number("f_corner_hz", positive=True),
    )
    sub.finish()
    sub = section.section("grs_voltage")
    sources["grs_voltage"] = GrsVoltageNoiseConfig(
        enabled=sub.flag("enabled"),
        linear_equivalent_asd_m_s2_rthz=sub.number("linear_equivalent_asd_m_s2_rthz", non_negative=True),
    )
    sub.finish()
    sub = section.section("star_tracker")
    sources["star_tracker"] = StarTrackerNoiseConfig(
        enabled=sub.flag("enabled"),
        sigma_rad=sub.array("sigma_rad", (3,), non_negative=True, broadcast=True),
    )
    sub.finish()
    section.finish()
    return NoiseConfig(**sources)


def _parse_timing(root: _Section, dt_s: float) -> TimingConfig:
    if root.optional("timing") is None:
        return TimingConfig()
    section = root.section("timing")
    stamp = section.optional("grs_stamp")
    if stamp is None:
        grs_stamp = 0.0
    elif isinstance(stamp, str) and stamp in GRS_STAMP_CONVENTIONS:
        grs_stamp = grs_stamp_offset_s(stamp, dt_s)
    else:
        try:
            grs_stamp = _number(stamp, section.name("grs_stamp"))
        except ConfigError as error:
            raise ConfigError(section.name("grs_stamp"), f"must be one of {', '.join(GRS_STAMP_CONVENTIONS)} or "
                                                         f"a number of seconds, got {stamp!r}") from error

    def seconds(key: str, non_negative: bool = False) -> float:
        value = section.optional(key)
        return 0.0 if value is None else _number(value, section.name(key), non_negative=non_negative)

    timing = TimingConfig(grs_stamp, seconds("star_tracker_stamp_offset_s"), seconds("actuation_latency_s"),
                          seconds("thruster_time_constant_s", non_negative=True))
    section.finish()
    return timing


def _parse(raw: dict[str, Any], default_name: str) -> SimConfig:
    root = _Section(raw, "")
    layout = root.optional("layout")
    layout_name = default_name if layout is None else str(layout)
    sample_rate_hz = root.number("sample_rate_hz", positive=True)
    config = SimConfig(
        layout=layout_name,
        sample_rate_hz=sample_rate_hz,
        spacecraft=_parse_spacecraft(root.section("spacecraft")),
        grs=_parse_grs(root.section("grs")),
        maneuver=_parse_maneuver(root.section("maneuver")),
        thrusters=_parse_thrusters(root.section("thrusters")),
        noise=_parse_noise(root.section("noise")),
        timing=_parse_timing(root, 1.0 / sample_rate_hz),
        effects=_parse_effects(root),
    )
    root.finish()
    return config


def _parse_effects(root: _Section) -> tuple[dict[str, Any], ...]:
    """The ``effects`` section of an extended nominal model: catalog effects, validated."""
    raw = root.optional("effects")
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ConfigError("effects", "must be a list of {name: ..., <parameters>} mappings")
    from taiji2_model.effect_catalog import effects_from_config  # the catalog builds on this module

    try:
        effects_from_config(raw)
    except ValueError as error:
        raise ConfigError("effects", str(error)) from error
    return tuple(copy.deepcopy(dict(entry)) for entry in raw)
