"""Glue shared by the estimator nodes: parameters, raw-message checks, diagnostics, checkpoints.

No estimation logic lives here: that is in :mod:`taiji2_estimator_pkg.core`.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from taiji2_runtime.ros import messages, rclpy

from taiji2_estimator_pkg.core.instrument import InstrumentModel

STAR_TRACKER_TOPIC = "/taiji2/star_tracker"
GRS_TOPICS = {1: "/taiji2/grs1/voltages", 2: "/taiji2/grs2/voltages"}
GRS_FRAMES = {1: "tmrf1", 2: "tmrf2"}
RATE_TOPIC = "/taiji2/estimates/angular_rate"
METHODS = ("gls", "paper")
_NS = 1_000_000_000


def descriptor(description: str, *, low: float | None = None, high: float | None = None) -> Any:
    """ParameterDescriptor with an optional floating-point range."""
    rcl = messages.rcl_interfaces
    d = rcl.ParameterDescriptor(description=description)
    if low is not None:
        d.floating_point_range = [rcl.FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    return d


def declare_common(node: Any) -> dict[str, Any]:
    """Declare the parameters every estimator node has; returns their values."""
    dp = node.declare_parameter
    values = {
        "layout": dp("layout", "type1", descriptor(
            "nominal model: built-in layout (type1, type2) used when config_file is empty")).value,
        "config_file": dp("config_file", "", descriptor("nominal model: layout YAML (simulator config format)")).value,
        "method": dp("method", "gls", descriptor("estimation method: gls (default, honest covariance) | paper")).value,
        "gate_probability": dp("gate_probability", 1e-6, descriptor(
            "false-alarm probability of the chi-square outlier gate per update; 0 disables", low=0.0, high=0.5)).value,
        "publish_period_s": dp("publish_period_s", 1.0, descriptor(
            "publish the running estimate every this many seconds of data [s]", low=0.1, high=3600.0)).value,
        "checkpoint_file": dp("checkpoint_file", "", descriptor(
            "estimator state file: loaded at start if present (resume), written every checkpoint_period_s and at "
            "shutdown; empty disables")).value,
        "checkpoint_period_s": dp("checkpoint_period_s", 60.0, descriptor(
            "seconds of data between checkpoints [s]", low=1.0, high=86400.0)).value,
        "max_stream_silence_s": dp("max_stream_silence_s", 2.0, descriptor(
            "a raw stream silent this long (wall clock) no longer holds epochs back: they are processed "
            "without it (dropout) [s]", low=0.1, high=600.0)).value,
        "starved_after_s": dp("starved_after_s", 5.0, descriptor(
            "WARN 'starved' when no raw data arrived for this long (wall clock) [s]", low=0.5, high=3600.0)).value,
    }
    if values["method"] not in METHODS:
        raise ValueError(f"method: {values['method']!r} is not one of {', '.join(METHODS)}")
    return values


def instrument_from(values: dict[str, Any]) -> InstrumentModel:
    """The nominal instrument model named by the ``layout``/``config_file`` parameters."""
    return InstrumentModel.from_layout(values["config_file"] or values["layout"])


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


def set_stamp(header: Any, t_ns: int) -> None:
    header.stamp.sec, header.stamp.nanosec = divmod(int(t_ns), _NS)


def raw_qos() -> Any:
    """Reliable keep-all: every raw sample the publisher sends is delivered."""
    return rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)


def grs_message_problem(msg: Any, grs_id: int) -> str | None:
    """Why a GrsVoltages message does not belong on GRS ``grs_id``'s topic (None if it does)."""
    if int(msg.grs_id) != grs_id:
        return "grs_id_mismatch"
    if msg.header.frame_id != GRS_FRAMES[grs_id]:
        return "frame_id_mismatch"
    return None


def grs_voltages(msg: Any) -> np.ndarray:
    return np.array([msg.vx1, msg.vx2, msg.vy1, msg.vy2, msg.vz1, msg.vz2], dtype=np.float64)


def star_tracker_quaternion(msg: Any) -> np.ndarray:
    a = msg.attitude
    return np.array([a.x, a.y, a.z, a.w], dtype=np.float64)


class RejectionCounts:
    """Nested counts stream -> reason -> n (rejections at the node level)."""

    def __init__(self) -> None:
        self.counts: dict[str, dict[str, int]] = {}

    def add(self, stream: str, reason: str, n: int = 1) -> None:
        inner = self.counts.setdefault(stream, {})
        inner[reason] = inner.get(reason, 0) + n

    def merged(self, *others: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {k: dict(v) for k, v in self.counts.items()}
        for other in others:
            for stream, reasons in other.items():
                for reason, n in reasons.items():
                    out.setdefault(stream, {})[reason] = out.setdefault(stream, {}).get(reason, 0) + int(n)
        return out


def total(counts: dict[str, dict[str, int]]) -> int:
    return sum(sum(v.values()) for v in counts.values())


def diagnostic(name: str, level_name: str, message: str, values: dict[str, Any]) -> Any:
    """A DiagnosticStatus with ``level_name`` in OK/WARN/ERROR and JSON-encoded values."""
    d = messages.diagnostic_msgs
    status = d.DiagnosticStatus(name=name, message=message, hardware_id="taiji2_estimator")
    status.level = getattr(d.DiagnosticStatus, level_name)
    status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in values.items()]
    return status


def consistency_level(nis_mean: float, determined: bool, starved: bool, rejected: int, used: int) -> tuple[str, str]:
    """(level, message) of an estimator's health: WARN when inconsistent, starved or rejecting much."""
    if starved:
        return "WARN", "starved: no raw data recently"
    if not determined:
        return "OK", "collecting data (estimate not yet determined)"
    if np.isfinite(nis_mean) and not 0.5 < nis_mean < 2.0:
        return "WARN", f"inconsistent: mean NIS per dof {nis_mean:.2f} (about 1 expected)"
    if used and rejected > 0.01 * used:
        return "WARN", f"{rejected} inputs rejected ({100 * rejected / used:.1f} %)"
    return "OK", "consistent"
