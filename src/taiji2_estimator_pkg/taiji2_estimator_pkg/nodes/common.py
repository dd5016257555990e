"""Glue shared by the estimator nodes: parameters, raw-message checks, diagnostics, checkpoints.

No estimation logic lives here: that is in :mod:`taiji2_estimator_pkg.core`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_estimator_pkg.checkpoint import load_checkpoint, save_checkpoint
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.parameters import DEFAULTS, NODE_DEFAULTS
from taiji2_estimator_pkg.epochs import EpochAssembler
from taiji2_estimator_pkg.nodes.runtime_parameters import RUNTIME_CHECKS, accept_runtime_parameters
from taiji2_runtime import node_parameters
from taiji2_runtime.ros import messages, rclpy

GRS_FRAMES = {1: "tmrf1", 2: "tmrf2"}
METHODS = ("gls", "paper")
_NS = 1_000_000_000
#: a health tick (1 s period) this much later than due is reported as a pause of the process [s]
PAUSE_REPORTED_AFTER_S = 2.0
#: health reports (1 s apart) that keep a resume from a checkpoint at WARN once its data gap is known. It is
#: WARN from the restart until then, and named in every later report: /diagnostics is volatile, and a
#: subscriber that matches the restarted process late (discovery on a loaded machine) or joins later would
#: miss a single report
RESUME_WARN_REPORTS = 10


#: Core keys the nodes fix: both GRS are always estimated jointly (the two topics of the contract).
_FIXED = {"grs_ids": [1, 2]}

def declare_parameters(node: Any, node_name: str) -> dict[str, Any]:
    """Declare every parameter of ``node_name`` (core defaults + node glue); returns dotted-key values.

    The keys, meanings, units and defaults are documented in ``config/estimators.yaml``; the core's
    ``parameters.DEFAULTS`` and ``parameters.NODE_DEFAULTS`` tables are their single source in code.
    """
    table = {**DEFAULTS[node_name], **NODE_DEFAULTS[node_name]}
    values: dict[str, Any] = dict(_FIXED)
    for key, default in table.items():
        if key in _FIXED:
            continue
        values[key] = node.declare_parameter(key, default, node_parameters.descriptor(
            f"see config/estimators.yaml, {node_name}.{key} (default {default!r})",
            read_only=key not in RUNTIME_CHECKS)).value
    if values["method"] not in METHODS:
        raise ValueError(f"method: {values['method']!r} is not one of {', '.join(METHODS)}")
    return values


def instrument_from(values: dict[str, Any]) -> InstrumentModel:
    """The nominal instrument model named by the ``layout`` parameter (built-in name or YAML path)."""
    return InstrumentModel.from_layout(values["layout"])


def time_ns(time: Any) -> int:
    """A builtin_interfaces/Time in ns."""
    return int(time.sec) * _NS + int(time.nanosec)


def set_time(time: Any, t_ns: int) -> None:
    time.sec, time.nanosec = divmod(int(t_ns), _NS)


def stamp_ns(header: Any) -> int:
    return time_ns(header.stamp)


def set_stamp(header: Any, t_ns: int) -> None:
    set_time(header.stamp, t_ns)


def raw_qos() -> Any:
    """Reliable keep-all: every raw sample the publisher sends is delivered."""
    return rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)


def estimate_qos() -> Any:
    """Publishers of estimates: reliable, transient local, keep-last 1. A late joiner (``ros2 topic echo
    --once``, a plot, a c.m.-offset estimator restarted after the scale-factor estimator's last estimate)
    gets the latest estimate, not the history from the first (undetermined, NaN) one. Volatile subscribers
    (recorders, ``ros2 topic echo``) match it as well."""
    return rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_LAST, depth=1,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE,
                                durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)


def estimate_subscription_qos() -> Any:
    """Subscriptions to estimates: reliable, transient local (the latest estimate on joining), keep-all (every
    estimate published after that is taken, none replaced in the reader's queue while a callback runs)."""
    return rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                reliability=rclpy.qos.ReliabilityPolicy.RELIABLE,
                                durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)


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


def new_rejections(now: dict[str, dict[str, int]], before: dict[str, dict[str, int]]) -> dict[str, int]:
    """``{"stream reason": n}`` of the rejections counted since ``before``."""
    fresh = {}
    for stream, reasons in now.items():
        for reason, n in reasons.items():
            delta = int(n) - int(before.get(stream, {}).get(reason, 0))
            if delta > 0:
                fresh[f"{stream} {reason}"] = delta
    return fresh


def health(nis_mean: float, determined: bool, starved: bool, fresh_rejections: dict[str, int],
           lost: dict[str, tuple[int, float]] | None = None) -> tuple[str, str]:
    """(level, message) of an estimator: WARN when starved, rejecting input, missing input, or inconsistent.

    ``lost``: stream -> (missing samples, fraction of the grid stamps) of the streams above the warning
    fraction."""
    if starved:
        return "WARN", "starved: no raw data recently"
    if fresh_rejections:
        listed = ", ".join(f"{what} x{n}" for what, n in sorted(fresh_rejections.items()))
        return "WARN", f"rejected input: {listed}"
    if lost:
        listed = ", ".join(f"{s} {n} samples ({100 * f:.2g} %)" for s, (n, f) in sorted(lost.items()))
        return "WARN", f"missing input: {listed}"
    if not determined:
        return "OK", "collecting data (estimate not yet determined)"
    if np.isfinite(nis_mean) and not 0.5 < nis_mean < 2.0:
        return "WARN", f"inconsistent: mean NIS per dof {nis_mean:.2f} (about 1 expected)"
    return "OK", "consistent"


class EstimatorNode(rclpy.node.Node):
    """What both estimator nodes share: parameters, epoch alignment, rejection counts, health
    diagnostics and checkpoint files. Subclasses build ``self.estimator`` and implement
    ``streams()``, ``_process(epoch)``, ``_checkpoint_payload()`` and ``_restore_payload(state)``."""

    def __init__(self, node_name: str, **node_kwargs: Any) -> None:
        super().__init__(node_name, **node_kwargs)
        self.p = declare_parameters(self, node_name)
        accept_runtime_parameters(self, self.p)
        self.instrument = instrument_from(self.p)
        self.assembler = EpochAssembler(self.streams(), self.p["max_stream_lag_s"], self.instrument.dt_s,
                                        min_silence_s=self.p["max_stream_silence_s"])
        self.node_rejections = RejectionCounts()
        self.reported_rejections: dict[str, dict[str, int]] = {}
        self.last_data_wall = time.monotonic()
        self.last_checkpoint_ns = -1
        self.last_t_ns = -1  # stamp of the last epoch processed
        self.last_publish_ns = -1  # data time of the last published estimate
        self.last_estimate: Any = None
        self.resumed_from_ns: int | None = None  # data time of the checkpoint this process resumed from
        #: stamp of the first sample beyond the checkpoint after the resume - checkpoint time [s] (samples
        #: at or before the checkpoint, e.g. a restarted simulator's rerun, are refused and counted instead)
        self.data_gap_s: float | None = None
        self.resume_warn_left = RESUME_WARN_REPORTS
        self.last_health_wall = time.monotonic()
        self.diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
        self.create_timer(1.0, self.publish_health, clock=steady)
        self.create_timer(0.5, self._end_of_data_tick, clock=steady)

    # -- input -----------------------------------------------------------------------------------
    def add_sample(self, stream: str, t_ns: int, payload: Any) -> None:
        self.last_data_wall = time.monotonic()
        if self.resumed_from_ns is not None and self.data_gap_s is None and t_ns > self.resumed_from_ns:
            self.data_gap_s = (t_ns - self.resumed_from_ns) / 1e9
            self.get_logger().info(f"first data beyond the checkpoint at t = {t_ns / 1e9:.1f} s: data gap "
                                   f"{self.data_gap_s:.1f} s")
        if self.assembler.first_ns < 0:
            self.get_logger().info(f"first raw sample received: {stream} at t = {t_ns / 1e9:.1f} s (missing samples "
                                   "are counted from here; samples published before this node subscribed are not)")
        for epoch in self.assembler.add(stream, t_ns, payload):
            self._process_epoch(epoch)
        self._checkpoint_if_due()

    def _end_of_data_tick(self) -> None:
        # wall time decides only *when* an epoch goes on without a stopped stream and the last estimate goes
        # out, never which samples the epochs hold
        for epoch in self.assembler.release_stopped():
            self._process_epoch(epoch)
        self._checkpoint_if_due()
        self._publish_at_end_of_data()

    def _process_epoch(self, epoch: Any) -> None:
        """:meth:`_process`, after starting a new segment where the source restarted."""
        if epoch.after_restart:
            start = getattr(self.estimator, "start_new_segment", None)
            if start is not None:
                start()
                self.get_logger().info(f"every raw stream went back in time (a restarted source): the data from "
                                       f"t = {epoch.t_ns / 1e9:.1f} s on start a new segment")
            else:
                self.get_logger().warn(f"every raw stream went back in time (a restarted source): method "
                                       f"{self.p['method']} joins the data from t = {epoch.t_ns / 1e9:.1f} s "
                                       "to the run before (use method gls to keep them apart)")
        self._process(epoch)

    def _publish_at_end_of_data(self) -> None:
        """Data stopped (end of a run, or a pause): publish the estimate of the last epoch, once.

        Estimates go out at the first epoch of each publish period, so without this a run ending
        inside a period (a 6421.8-s run with 1-s periods) would never publish its last epochs.
        """
        if not self.unpublished():
            return
        if time.monotonic() - self.last_data_wall < self.p["max_stream_silence_s"]:
            return
        self.publish_estimate(self.last_t_ns)

    def unpublished(self) -> bool:
        """Epochs newer than the last published estimate."""
        return self.last_t_ns > self.last_publish_ns

    def streams(self) -> Sequence[str]:
        """The raw streams this estimator aligns (may depend on ``self.p``)."""
        raise NotImplementedError

    def _process(self, epoch: Any) -> None:
        """Feed one epoch to the estimator (sets ``last_t_ns``), publishing and checkpointing on schedule."""
        raise NotImplementedError

    def publish_estimate(self, t_ns: int) -> None:
        """Publish the estimate of the data up to ``t_ns`` (sets ``last_publish_ns``)."""
        raise NotImplementedError

    # -- checkpoints -----------------------------------------------------------------------------
    def resume(self) -> int | None:
        """Load ``checkpoint_file`` if it exists; returns its data time [ns] (None: fresh start)."""
        path = self.p["checkpoint_file"]
        state = load_checkpoint(path) if path else None
        if state is None:
            return None
        if state.get("method") != self.p["method"]:
            raise ValueError(f"checkpoint_file {path}: written by method {state.get('method')!r}, "
                             f"not {self.p['method']!r}")
        self._restore_payload(state)
        self.assembler.load_state_dict(state["assembler"])
        self.node_rejections.counts = state["node_rejections"]
        self.get_logger().info(f"resumed from checkpoint {path} at t = {state['t_ns'] / 1e9:.1f} s")
        self.resumed_from_ns = int(state["t_ns"])
        return int(state["t_ns"])

    def save_checkpoint(self, t_ns: int) -> None:
        path = self.p["checkpoint_file"]
        if path:
            save_checkpoint(path, {"method": self.p["method"], "t_ns": t_ns, "assembler": self.assembler.state_dict(),
                                   "node_rejections": self.node_rejections.counts, **self._checkpoint_payload()})
            self.last_checkpoint_ns = t_ns

    def _checkpoint_if_due(self) -> None:
        """Save a checkpoint if one is due. Only between messages, never inside a batch of released epochs: the
        assembler's state counts an epoch released once it leaves it, so a checkpoint taken in the middle of
        a batch would lose the rest of the batch on a restart."""
        if self.last_t_ns >= 0 and self.checkpoint_due(self.last_t_ns):
            self.save_checkpoint(self.last_t_ns)

    def checkpoint_due(self, t_ns: int) -> bool:
        return self.last_checkpoint_ns < 0 or t_ns - self.last_checkpoint_ns >= self.p["checkpoint_period_s"] * 1e9

    def _checkpoint_payload(self) -> dict[str, Any]:
        raise NotImplementedError

    def _restore_payload(self, state: dict[str, Any]) -> None:
        raise NotImplementedError

    # -- health ----------------------------------------------------------------------------------
    def rejection_counts(self) -> dict[str, dict[str, int]]:
        """Every rejection so far: node-level checks, epoch alignment and the core's validation and gating."""
        alignment = {f"{s}:{r}": n for s, reasons in self.assembler.refused.items() for r, n in reasons.items()}
        core = self.last_estimate.rejected if self.last_estimate is not None else {}
        return self.node_rejections.merged(core, {"epoch_alignment": alignment} if alignment else {})

    def _with_resume(self, level: str, text: str) -> tuple[str, str]:
        """(level, message) with this process's resume from a checkpoint named, if it resumed from one.

        WARN from the restart until the first data beyond the checkpoint (``no data beyond it yet``: a
        restarted estimator that gets no new data says so, not only that it is starved) and for
        :data:`RESUME_WARN_REPORTS` reports after it (``data gap``); named in every report after that,
        at the level of the other conditions. Other conditions stay named in the same message."""
        if self.resumed_from_ns is None:
            return level, text
        note = f"resumed from checkpoint at t = {self.resumed_from_ns / 1e9:.1f} s after a restart; " + (
            "no data beyond it yet" if self.data_gap_s is None else
            f"data gap {self.data_gap_s:.1f} s (samples published meanwhile are lost to this estimate)")
        if self.data_gap_s is not None and self.resume_warn_left <= 0:
            return level, f"{text}; {note}"
        if self.data_gap_s is not None:
            self.resume_warn_left -= 1
        return "WARN", note if level == "OK" else f"{text}; {note}"

    def lost_streams(self, missing: dict[str, int]) -> dict[str, tuple[int, float]]:
        """Streams whose missing samples exceed ``missing_warn_fraction`` of the grid stamps so far."""
        grid = max(self.assembler.grid_stamps(), 1)
        return {s: (n, n / grid) for s, n in missing.items() if n and n / grid > self.p["missing_warn_fraction"]}

    def latency_s(self, t_ns: int) -> float:
        """Publication time minus the stamp ``t_ns`` on the graph's clock [s]; NaN off sim time (the
        node's wall clock and the data's stamps need not share an epoch)."""
        if not self.get_parameter("use_sim_time").value:
            return float("nan")
        return (self.get_clock().now().nanoseconds - int(t_ns)) / 1e9

    def samples_missing(self) -> int:
        """Missing samples summed over the raw streams (for the estimate messages)."""
        return int(sum(self.assembler.missing().values()))

    def health_values(self) -> dict[str, Any]:
        """Values of this estimator's own in its ``/diagnostics`` status (added to the shared ones)."""
        return {}

    def publish_health(self, waiting_for: str | None = None) -> None:
        """``/diagnostics``: OK, or WARN when starved, rejecting input (named), or inconsistent."""
        estimate = self.last_estimate
        counts = self.rejection_counts()
        starved = time.monotonic() - self.last_data_wall > self.p["starved_after_s"]
        fresh = new_rejections(counts, self.reported_rejections)
        self.reported_rejections = counts
        missing = self.assembler.missing()
        level, text = health(estimate.nis_mean if estimate else float("nan"),
                             bool(estimate and estimate.determined), starved, fresh, self.lost_streams(missing))
        now = time.monotonic()
        # the health timer ticks every second: a much longer gap means this process was not run
        # (SIGSTOP, or a starved CPU) and its input queued up meanwhile
        paused_s = now - self.last_health_wall - 1.0
        self.last_health_wall = now
        if paused_s > PAUSE_REPORTED_AFTER_S:
            level, text = "WARN", f"paused: not scheduled for {paused_s:.1f} s (stopped or starved of CPU)"
        if waiting_for and level == "OK":
            text = f"waiting for {waiting_for}"
        level, text = self._with_resume(level, text)
        status = diagnostic(self.get_name(), level, text, {
            "method": self.p["method"], "samples_used": int(estimate.n_samples) if estimate else 0,
            "rejected": counts, "nis_mean": None if estimate is None else estimate.nis_mean,
            "last_stamp_s": None if estimate is None else estimate.t_s, "paused_s": max(paused_s, 0.0),
            "resumed_from_s": None if self.resumed_from_ns is None else self.resumed_from_ns / 1e9,
            "data_gap_s": self.data_gap_s, "missing": missing,
            "first_stamp_s": None if self.assembler.first_ns < 0 else self.assembler.first_ns / 1e9,
            **self.health_values()})
        array = messages.diagnostic_msgs.DiagnosticArray(status=[status])
        set_stamp(array.header, round(estimate.t_s * 1e9) if estimate is not None and np.isfinite(estimate.t_s) else 0)
        self.diag_pub.publish(array)
