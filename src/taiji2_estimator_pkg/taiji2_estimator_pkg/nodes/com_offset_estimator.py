"""com_offset_estimator: running estimates of the c.m. offsets d_1, d_2 (CRF, m) and of d_1 - d_2.

Subscribes to the raw GRS voltage topics (and the star tracker, for the paper method), to the
scale-factor estimates of both GRS (their joint covariance is propagated into d) and to the
filtered body rate of the scale-factor estimator. ``method: gls`` (default) uses the calibrated GRS
angular acceleration in A~ and the common spacecraft acceleration seen by both GRS
(:mod:`taiji2_estimator_pkg.core.com_offset`); ``method: paper`` runs the paper's filter over the
data received so far every ``paper_batch_period_s``. Publishes ``/taiji2/estimates/grsN/com_offset``,
``/taiji2/estimates/com_offset_difference`` (grs_id 0: d_1 - d_2) and ``/diagnostics``.
Parameters: ``config/estimators.yaml``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.com_offset.gls import ComOffsetEstimator
from taiji2_estimator_pkg.core.com_offset.paper import PaperComOffsetFilter
from taiji2_estimator_pkg.core.parameters import com_offset_options, paper_com_offset_options
from taiji2_estimator_pkg.epochs import Epoch
from taiji2_estimator_pkg.nodes import common
from taiji2_estimator_pkg.scale_factor_wait import ScaleFactorHistory, ScaleFactorWait
from taiji2_model.contract import (
    ANGULAR_RATE_ESTIMATE_TOPIC,
    COM_OFFSET_DIFFERENCE_TOPIC,
    COM_OFFSET_ESTIMATE_TOPIC_OF,
    GRS_TOPIC_OF,
    SCALE_FACTOR_ESTIMATE_TOPIC_OF,
    STAR_TRACKER_TOPIC,
)
from taiji2_runtime.batched import create_batched_subscription
from taiji2_runtime.entry import run_node
from taiji2_runtime.ros import messages
from taiji2_runtime.threads import limit_blas_threads

GRS_IDS = (1, 2)
STREAMS = ("grs1", "grs2")
STREAMS_PAPER = ("star_tracker", "grs1", "grs2")  # the paper method builds A~ from the star tracker


class ComOffsetEstimatorNode(common.EstimatorNode):
    """Estimates d_1, d_2 in CRF from the GRS linear readouts and the calibrated scale factors."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("com_offset_estimator", **node_kwargs)
        self.paper = self.p["method"] == "paper"
        # the body rate enters only omega x (omega x d), ~1e-14 m s^-2 at calibration rates; without it
        # a replayed bag reproduces the live estimate exactly, independent of message timing
        self.use_rate = self.p["use_rate_estimate"]
        self.estimator = (PaperComOffsetFilter(self.instrument, GRS_IDS, paper_com_offset_options(self.p))
                          if self.paper else ComOffsetEstimator(self.instrument, GRS_IDS, com_offset_options(self.p)))
        #: ScaleFactorEstimate messages waiting for the other GRS's of the same stamp: GRS id -> stamp [ns] -> msg
        self.scale_factor_msgs: dict[int, dict[int, Any]] = {g: {} for g in GRS_IDS}
        # the scale factors in use (G, covariance) and their stamp: those of the data up to the epoch processed
        # (of the newest data at the end of data); the ones received are in scale_factor_history
        self.scale_factors: tuple[np.ndarray, np.ndarray] | None = None
        self.scale_factors_ns = -1
        self.scale_factor_history = ScaleFactorHistory()
        self.omega = np.full(3, np.nan)
        self.history: list[tuple[float, np.ndarray | None, np.ndarray]] = []  # paper method only
        self.published_scale_factors_ns = -1  # stamp of the scale factors the last published estimate used
        self.waiting = ScaleFactorWait()  # epochs held until the scale factors of their period have come
        self.last_scale_factors_wall = time.monotonic()
        self.last_nis = float("nan")
        self.ungated_stale = 0  # epochs not gated: no scale factors of their own publish period
        resumed = self.resume()
        if resumed is not None:
            self.last_t_ns = resumed

        t = messages.taiji2_msgs
        qos = common.raw_qos()
        for gid in GRS_IDS:
            # raw streams: up to 16 queued messages per callback (rclpy takes one per wait-set pass otherwise)
            create_batched_subscription(self, t.GrsVoltages, GRS_TOPIC_OF[gid],
                                        lambda m, g=gid: self._on_grs(m, g), qos)
            self.create_subscription(t.ScaleFactorEstimate, SCALE_FACTOR_ESTIMATE_TOPIC_OF[gid],
                                     self._on_scale_factors, common.estimate_subscription_qos())
        if self.paper:
            create_batched_subscription(self, t.StarTracker, STAR_TRACKER_TOPIC, self._on_star_tracker, qos)
        if self.use_rate:
            self.create_subscription(messages.geometry_msgs.Vector3Stamped, ANGULAR_RATE_ESTIMATE_TOPIC, self._on_rate,
                                     qos)
        self.pubs = {g: self.create_publisher(t.ComOffsetEstimate, COM_OFFSET_ESTIMATE_TOPIC_OF[g],
                                              common.estimate_qos()) for g in GRS_IDS}
        self.diff_pub = self.create_publisher(t.ComOffsetEstimate, COM_OFFSET_DIFFERENCE_TOPIC,
                                              common.estimate_qos())
        self.get_logger().info(f"method {self.p['method']}, nominal model {self.p['layout']}")

    def streams(self) -> Sequence[str]:
        return STREAMS_PAPER if self.p["method"] == "paper" else STREAMS

    # -- checkpoints ---------------------------------------------------------------------------
    def _checkpoint_payload(self) -> dict[str, Any]:
        # the epochs waiting for their scale factors are released by the assembler, not yet estimated: left out,
        # they would be lost on a restart (the assembler refuses their samples when a rerun sends them again)
        waiting = {"waiting": [epoch.state_dict() for epoch in self.waiting.pending]}
        return {"history": self.history, **waiting} if self.paper else {"estimator": self.estimator.state_dict(),
                                                                         **waiting}

    def _restore_payload(self, state: dict[str, Any]) -> None:
        if self.paper:
            self.history = [(t, q, v) for t, q, v in state["history"]]
        else:
            self.estimator.load_state_dict(state["estimator"])
        self.waiting.pending.extend(Epoch.from_state_dict(e) for e in state.get("waiting", []))

    # -- input ---------------------------------------------------------------------------------
    def _on_scale_factors(self, msg: Any) -> None:
        """Pair the two GRS's estimates by stamp, whichever comes first: in a burst one topic's messages can
        arrive several stamps ahead of the other's (taking only a pair that happened to arrive together, G
        stayed at one stamp while the data moved 100 s on)."""
        if msg.grs_id not in GRS_IDS:
            self.node_rejections.add("scale_factors", "grs_id_mismatch")
            return
        self.last_scale_factors_wall = time.monotonic()
        gid, t_ns = int(msg.grs_id), common.stamp_ns(msg.header)
        other_gid = GRS_IDS[1] if gid == GRS_IDS[0] else GRS_IDS[0]
        other = self.scale_factor_msgs[other_gid]
        for stale in [s for s in other if s < t_ns]:  # each topic comes in stamp order: never paired now
            del other[stale]
        if t_ns not in other:
            self.scale_factor_msgs[gid][t_ns] = msg
            return
        pair = {gid: msg, other_gid: other.pop(t_ns)}
        # d moves with G but is published on the data's schedule (_process) and, after the last data, with the
        # newest G (unpublished): publishing at each newer G as well sent two estimates a period (~1 ms of CPU each)
        self._take_scale_factors([pair[g] for g in GRS_IDS])
        # estimated (or not yet determined) through this time: the epochs of its period may go on, with this G
        for epoch in self.waiting.scale_factors_through(t_ns, *self._wait_bounds_ns()):
            super()._process_epoch(epoch)
        self._checkpoint_if_due()

    def _take_scale_factors(self, msgs: list[Any]) -> None:
        """G and its joint covariance from the pair of ScaleFactorEstimate messages of one stamp, once determined,
        into the history."""
        g = np.concatenate([np.asarray(m.scale_factors, dtype=np.float64) for m in msgs])
        if not np.all(np.isfinite(g)):
            return  # the scale-factor estimator is not determined yet
        cov = np.zeros((6, 6))
        cov[:3, :3] = np.reshape(msgs[0].covariance, (3, 3))
        cov[3:, 3:] = np.reshape(msgs[1].covariance, (3, 3))
        cov[:3, 3:] = np.reshape(msgs[0].cross_covariance, (3, 3))
        cov[3:, :3] = cov[:3, 3:].T
        self.scale_factor_history.add(common.stamp_ns(msgs[0].header), g, cov)

    def _use_scale_factors(self, entry: tuple[int, np.ndarray, np.ndarray] | None) -> None:
        """Use the scale factors of ``entry`` ((stamp, G, covariance); None: keep those in use)."""
        if entry is not None:
            self.scale_factors_ns, g, cov = entry
            self.scale_factors = (g, cov)

    def _on_rate(self, msg: Any) -> None:
        self.omega = np.array([msg.vector.x, msg.vector.y, msg.vector.z], dtype=np.float64)

    def _on_star_tracker(self, msg: Any) -> None:
        self.add_sample("star_tracker", common.stamp_ns(msg.header), common.star_tracker_quaternion(msg))

    def _on_grs(self, msg: Any, grs_id: int) -> None:
        problem = common.grs_message_problem(msg, grs_id)
        if problem is not None:
            self.node_rejections.add(f"grs{grs_id}", problem)
            self.get_logger().warn(f"rejected GrsVoltages on {GRS_TOPIC_OF[grs_id]}: {problem}",
                                   throttle_duration_sec=10.0)
            return
        self.add_sample(f"grs{grs_id}", common.stamp_ns(msg.header), common.grs_voltages(msg))

    def _process_epoch(self, epoch: Any) -> None:
        """Hold the epoch until the scale factors of its publish period have come (:mod:`~taiji2_estimator_pkg.
        scale_factor_wait`), then on as in every estimator."""
        for ready in self.waiting.add(epoch, *self._wait_bounds_ns()):
            super()._process_epoch(ready)

    def _wait_bounds_ns(self) -> tuple[int, int]:
        return self._period_ns(), int(self.p["max_scale_factor_lag_s"] * 1e9)

    def _end_of_data_tick(self) -> None:
        # a scale-factor estimator that stopped publishing must not hold the data forever
        if self.waiting.pending and time.monotonic() - self.last_scale_factors_wall > self.p["scale_factor_wait_s"]:
            held = self.waiting.release_all()
            self.get_logger().warn(f"no scale factors for {self.p['scale_factor_wait_s']:g} s: {len(held)} epochs "
                                   f"from t = {held[0].t_ns / 1e9:.1f} s go on with the scale factors of "
                                   f"{self.scale_factors_ns / 1e9:.1f} s", throttle_duration_sec=10.0)
            for epoch in held:
                super()._process_epoch(epoch)
        super()._end_of_data_tick()

    def _process(self, epoch: Any) -> None:
        voltages = {g: epoch.samples[f"grs{g}"] for g in GRS_IDS if f"grs{g}" in epoch.samples}
        self.last_t_ns = epoch.t_ns
        self._use_scale_factors(self.scale_factor_history.through(epoch.t_ns))
        if self.paper:
            v = np.full((2, 6), np.nan)
            for g, values in voltages.items():
                v[g - 1] = values
            self.history.append((epoch.t_ns / 1e9, epoch.samples.get("star_tracker"), v))
        else:
            try:
                report = self.estimator.update(epoch.t_ns / 1e9, voltages,
                                               self.omega if np.all(np.isfinite(self.omega)) else None,
                                               scale_factors=self._gate_scale_factors(epoch.t_ns))
            except Exception as exc:  # never crash the graph on one epoch; keep what is estimated
                self.node_rejections.add("epoch", f"error:{type(exc).__name__}")
                self.get_logger().error(f"epoch {epoch.t_ns / 1e9:.1f} s skipped: {exc}", throttle_duration_sec=10.0)
                return
            if np.isfinite(report.nis):
                self.last_nis = float(report.nis)
            for stream, reason in report.rejections:
                self.get_logger().warn(f"rejected {stream} at t = {epoch.t_ns / 1e9:.1f} s: {reason} (NIS "
                                       f"{report.nis:.4g}, scale factors of {self.scale_factors_ns / 1e9:.1f} s)",
                                       throttle_duration_sec=10.0)
        if self._stamp_due(epoch.t_ns):
            self._publish(epoch.t_ns)

    def _period_ns(self) -> int:
        return int((self.p["paper_batch_period_s"] if self.paper else self.p["publish_period_s"]) * 1e9)

    def _stamp_due(self, t_ns: int) -> bool:
        """Whether the estimate of the data through ``t_ns`` is due: one per publish period of the data."""
        period_ns = self._period_ns()
        return self.last_publish_ns < 0 or t_ns // period_ns > self.last_publish_ns // period_ns

    def unpublished(self) -> bool:
        """Data or scale factors newer than those of the last published estimate (published at the end of data:
        a G that arrives after the last GRS sample changes d without moving its stamp)."""
        newest = self.scale_factor_history.newest()
        return super().unpublished() or (self.last_t_ns >= 0 and newest is not None
                                         and newest[0] > self.published_scale_factors_ns)

    def _gate_scale_factors(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The scale factors for the pre-fit gate of the epoch at ``t_ns``: those in use if they are of the epoch's
        own publish period (the G offline gates it with), else None (not gated; counted and logged).

        An older G gates falsely: a full-speed replay whose raw data ran far ahead gated an epoch at 413 s with
        G of 115 s (NIS 40.7); and under load the scale-factor estimator's keep-last-1 writer can replace an
        estimate the c.m.-offset node has not yet read, so that epochs waited for a later pair and were gated
        with one a few periods old (66 false rejections in 1 of 6 replays beside two CPU-bound processes, with
        an 80 %-of-the-span freshness rule). Ungated, an epoch can only let an outlier through: the post-fit
        gate of ``taiji2 calibrate`` still removes it offline."""
        if self.scale_factors is None:
            return None
        period_ns = self._period_ns()
        if self.scale_factors_ns >= t_ns // period_ns * period_ns:
            return self.scale_factors
        self.ungated_stale += 1
        self.get_logger().info(f"epoch at {t_ns / 1e9:.1f} s not gated: the newest scale factors of its data are of "
                               f"{self.scale_factors_ns / 1e9:.1f} s ({self.ungated_stale} epochs so far)",
                               throttle_duration_sec=10.0)
        return None

    # -- output --------------------------------------------------------------------------------
    def _current_estimate(self) -> ComOffsetEstimate | None:
        if self.scale_factors is None:
            return None
        if not self.paper:
            return self.estimator.estimate(self.scale_factors)
        if len(self.history) < 2:
            return None
        t = np.array([h[0] for h in self.history])
        q = np.array([h[1] if h[1] is not None else np.full(4, np.nan) for h in self.history])
        v = np.array([h[2] for h in self.history])
        g, _ = self.scale_factors
        return self.estimator.process_batch(t, q, v, {1: g[:3], 2: g[3:]})

    def publish_estimate(self, t_ns: int) -> None:
        """At the end of the data: publish d from the GRS data up to ``t_ns`` with the newest scale factors
        (which may be of data after ``t_ns``: the final d uses the final G, as ``taiji2 calibrate``)."""
        self._use_scale_factors(self.scale_factor_history.newest())
        self._publish(t_ns)

    def _publish(self, t_ns: int) -> None:
        """Publish d from the GRS data up to ``t_ns`` (the stamp) and the scale factors in use (their stamp in
        ``scale_factors_stamp``)."""
        try:
            estimate = self._current_estimate()
        except Exception as exc:  # keep the last estimate rather than crash
            self.node_rejections.add("estimate", f"error:{type(exc).__name__}")
            self.get_logger().error(f"estimate at {t_ns / 1e9:.1f} s failed: {exc}", throttle_duration_sec=10.0)
            return
        self.last_publish_ns = t_ns
        if estimate is None:
            return
        self.last_estimate = estimate
        self.published_scale_factors_ns = self.scale_factors_ns
        rejected = common.total(self.rejection_counts())
        t = messages.taiji2_msgs
        for gid in GRS_IDS:
            d, cov = estimate.of(gid)
            self.pubs[gid].publish(self._message(t, gid, t_ns, d, cov, estimate, rejected))
        diff, diff_cov = estimate.difference()
        self.diff_pub.publish(self._message(t, 0, t_ns, diff, diff_cov, estimate, rejected))

    def _message(self, t: Any, gid: int, t_ns: int, d: np.ndarray, cov: np.ndarray, estimate: ComOffsetEstimate,
                 rejected: int) -> Any:
        msg = t.ComOffsetEstimate(grs_id=gid, method=estimate.method)
        common.set_stamp(msg.header, t_ns)
        msg.header.frame_id = "crf"
        common.set_time(msg.scale_factors_stamp, self.scale_factors_ns)
        msg.offset.x, msg.offset.y, msg.offset.z = (float(v) for v in d)
        msg.covariance = [float(v) for v in np.asarray(cov).ravel()]
        msg.samples_used = int(estimate.n_samples)
        msg.samples_rejected = int(rejected)
        msg.samples_missing = self.samples_missing()
        msg.latency_s = self.latency_s(t_ns)
        msg.nis = self.last_nis
        msg.nis_mean = float(estimate.nis_mean)
        return msg

    def health_values(self) -> dict[str, Any]:
        newest = self.scale_factor_history.newest()
        return {"scale_factors_received_through_s": None if newest is None else newest[0] / 1e9,
                "epochs_waiting_for_scale_factors": len(self.waiting.pending),
                "epochs_without_their_scale_factors": self.waiting.released_early}

    def publish_health(self, waiting_for: str | None = None) -> None:
        super().publish_health(None if self.scale_factor_history.newest() is not None
                               else "the scale-factor estimates")

    def destroy_node(self) -> None:
        try:
            for epoch in self.assembler.flush():
                self._process_epoch(epoch)
            for epoch in self.waiting.release_all():
                super()._process_epoch(epoch)
            if self.last_t_ns >= 0 and self.context.ok():
                self.publish_estimate(self.last_t_ns)
            if self.last_t_ns >= 0:
                self.save_checkpoint(self.last_t_ns)
        finally:
            super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    limit_blas_threads()  # one BLAS thread (docs/threads.md)
    return run_node(ComOffsetEstimatorNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
