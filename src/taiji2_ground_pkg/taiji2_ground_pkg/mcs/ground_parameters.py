"""What the ground computes, as Yamcs parameters: the running estimates of G and d of both GRS with their
sigma, the samples they miss, and the link's health, each a local parameter of the XTCE database (set
through Yamcs's API, archived, shown and checked for alarms like telemetry).

One place names them (:func:`parameter_specs`): the XTCE database declares them from it
(:func:`add_ground_parameters`) and the ground's Yamcs station sets them from it
(:func:`estimate_values`, :func:`reception_values`), so the two cannot drift apart.

Alarms (XTCE static alarm ranges, checked by Yamcs on every value):

* ``grs{g}_G_{axis}_rel_sigma`` (sigma / |G|): WARNING above the requirement, 0.3 %
  (:data:`~taiji2_estimator_pkg.report.SCALE_FACTOR_REQUIREMENT_REL`);
* ``grs{g}_d_{axis}_sigma`` [m]: WARNING above the requirement, 100 um
  (:data:`~taiji2_estimator_pkg.report.COM_OFFSET_REQUIREMENT_M`);
* ``ground_missing_fraction`` (samples declared lost / expected, all streams) and, per stream,
  ``link_{stream}_missing_fraction``: WARNING above 1 %, CRITICAL above 10 % (the deep-space link loses
  about 2 %: a warning an operator looks at, not a failure); each stream's duplicates, packets out of
  order and held (waiting for a gap to close) are counts without alarm;
* ``verdict_requirements_not_met``: the requirements the run's verdict finds not met (the one verdict
  evaluation of ``taiji2 experiment``, set once at the end of a run: :func:`verdict_values`): WARNING above 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from yamcs.pymdb import DataSource, FloatEncoding, FloatParameter, System, ThresholdAlarm

from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL
from taiji2_runtime.packets.definition import STREAMS

__all__ = ["MISSING_CRITICAL", "MISSING_WARNING", "ParameterSpec", "add_ground_parameters", "estimate_values",
           "parameter_specs", "reception_values", "verdict_values"]

#: the missing fraction of the ground's data that warns, and that is critical
MISSING_WARNING = 0.01
MISSING_CRITICAL = 0.10
_G_AXES = ("Pphi", "Ptheta", "Ppsi")
_D_AXES = ("x", "y", "z")
_STREAM_NAMES = frozenset(s.name for s in STREAMS)
#: the per-stream counts of the ground reception that are parameters (reception.GroundReception.counts)
_STREAM_COUNTS = {"received": "packets received (duplicates included)",
                  "duplicate": "packets received twice (the first kept)",
                  "out_of_order": "packets that arrived after a later count",
                  "missing": "samples declared lost", "held": "packets held, waiting for a gap to close"}


@dataclass(frozen=True)
class ParameterSpec:
    """One ground parameter: its XTCE name, units, description, and the value above which it warns (and is
    critical), if any."""

    name: str
    units: str | None
    description: str
    warning_high: float | None = None
    critical_high: float | None = None


def parameter_specs() -> tuple[ParameterSpec, ...]:
    """Every ground parameter, in display order."""
    specs = []
    for g in (1, 2):
        for axis in _G_AXES:
            specs.append(ParameterSpec(f"grs{g}_G_{axis}", "rad/s^2/V", f"GRS{g} scale factor G_{axis}"))
            specs.append(ParameterSpec(f"grs{g}_G_{axis}_rel_sigma", None,
                                       f"GRS{g} G_{axis}: 1-sigma / |G| (requirement {SCALE_FACTOR_REQUIREMENT_REL})",
                                       warning_high=SCALE_FACTOR_REQUIREMENT_REL))
        for axis in _D_AXES:
            specs.append(ParameterSpec(f"grs{g}_d_{axis}", "m", f"GRS{g} c.m. offset d_{axis} (CRF)"))
            specs.append(ParameterSpec(f"grs{g}_d_{axis}_sigma", "m",
                                       f"GRS{g} d_{axis}: 1-sigma (requirement {COM_OFFSET_REQUIREMENT_M} m)",
                                       warning_high=COM_OFFSET_REQUIREMENT_M))
        specs.append(ParameterSpec(f"grs{g}_samples_missing", None,
                                   f"raw samples the GRS{g} scale-factor estimate misses so far"))
    specs.append(ParameterSpec("ground_missing_fraction", None,
                               "samples the ground declared lost / samples expected, all streams",
                               warning_high=MISSING_WARNING, critical_high=MISSING_CRITICAL))
    for stream in STREAMS:
        specs.append(ParameterSpec(f"link_{stream.name}_missing_fraction", None,
                                   f"{stream.name}: samples declared lost / samples expected",
                                   warning_high=MISSING_WARNING, critical_high=MISSING_CRITICAL))
        for count, meaning in _STREAM_COUNTS.items():
            specs.append(ParameterSpec(f"link_{stream.name}_{count}", None, f"{stream.name}: {meaning}"))
    specs.append(ParameterSpec("ground_released_through_s", "s",
                               "onboard time through which the ground has released every stream"))
    specs.append(ParameterSpec("ground_time_s", "s", "the ground station's time at its last reception"))
    specs.append(ParameterSpec("verdict_requirements_met", None,
                               "requirements the last run's verdict finds met (G to 0.3 %, d to 100 um, 1 sigma, "
                               "both GRS; and the GRS linear range where known)"))
    specs.append(ParameterSpec("verdict_requirements_not_met", None,
                               "requirements the last run's verdict finds not met", warning_high=0.0))
    return tuple(specs)


def add_ground_parameters(system: System) -> None:
    """Declare every ground parameter as a local (API-set) float parameter of ``system``, with its alarm."""
    for spec in parameter_specs():
        alarm = None
        if spec.warning_high is not None:
            alarm = ThresholdAlarm(warning_high=spec.warning_high, warning_high_exclusive=True,
                                   critical_high=spec.critical_high, critical_high_exclusive=True)
        # an encoding although no packet carries them: XTCE readers (space-packet-parser) require one per type
        FloatParameter(system, spec.name, bits=64, data_source=DataSource.LOCAL, units=spec.units,
                       encoding=FloatEncoding(bits=64), short_description=spec.description, alarm=alarm)


def _finite(values: Mapping[str, float]) -> dict[str, float]:
    """Yamcs would archive a NaN as a value; an undetermined quantity is left out instead."""
    return {k: float(v) for k, v in values.items() if math.isfinite(v)}


def estimate_values(msg: Any) -> dict[str, float]:
    """The parameters of one ``ScaleFactorEstimate`` or ``ComOffsetEstimate`` message (by its fields)."""
    g = int(msg.grs_id)
    cov = list(msg.covariance)
    if hasattr(msg, "scale_factors"):
        values = {f"grs{g}_samples_missing": float(msg.samples_missing)}
        for i, axis in enumerate(_G_AXES):
            value, var = float(msg.scale_factors[i]), float(cov[4 * i])
            values[f"grs{g}_G_{axis}"] = value
            values[f"grs{g}_G_{axis}_rel_sigma"] = math.sqrt(var) / abs(value) if var >= 0 and value else math.nan
        return _finite(values)
    offset = (msg.offset.x, msg.offset.y, msg.offset.z)
    values = {}
    for i, axis in enumerate(_D_AXES):
        values[f"grs{g}_d_{axis}"] = float(offset[i])
        values[f"grs{g}_d_{axis}_sigma"] = math.sqrt(cov[4 * i]) if cov[4 * i] >= 0 else math.nan
    return _finite(values)


def reception_values(record: Mapping[str, Any]) -> dict[str, float]:
    """The link-health parameters of one ground reception record (``/ground/link/reception``)."""
    counts = record.get("counts", {})
    missing = sum(int(c.get("missing", 0)) for c in counts.values())
    expected = missing + sum(int(c.get("released", 0)) for c in counts.values())
    through = [v for v in record.get("released_through_s", {}).values() if v is not None]
    values = {"ground_missing_fraction": missing / expected if expected else math.nan,
              "ground_released_through_s": min(through) if through else math.nan,
              "ground_time_s": float(record.get("ground_time_s") or math.nan)}
    for name, c in counts.items():
        if name not in _STREAM_NAMES:
            continue  # not a parameter of the database
        lost, stream_expected = int(c.get("missing", 0)), int(c.get("missing", 0)) + int(c.get("released", 0))
        values[f"link_{name}_missing_fraction"] = lost / stream_expected if stream_expected else math.nan
        values.update({f"link_{name}_{k}": float(c.get(k, 0)) for k in _STREAM_COUNTS})
    return _finite(values)


def verdict_values(met: int, total: int) -> dict[str, float]:
    """The verdict parameters of a finished run: requirements met and not met (of ``total``)."""
    return {"verdict_requirements_met": float(met), "verdict_requirements_not_met": float(total - met)}
