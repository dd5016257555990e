"""scale_factor_estimator: running estimates of the angular scale factors of both GRS.

Subscribes to the raw star-tracker and GRS voltage topics only, puts them into epochs by the one rule of
:mod:`taiji2_estimator_pkg.epochs` (the star tracker at its own constant offset from the GRS, modelled),
feeds :mod:`taiji2_estimator_pkg.core.scale_factor` (``method: gls`` the default two-stage filter
with honest covariance, or ``method: paper``), and publishes per GRS
``/taiji2/estimates/grsN/scale_factors`` (with the cross-covariance of the joint estimate), the
filtered body rate on ``/taiji2/estimates/angular_rate`` for the c.m.-offset estimator, and
``/diagnostics``. Bad input is rejected, counted and reported; the estimate goes on from good data.
Parameters: ``config/estimators.yaml``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.parameters import paper_scale_factor_options, scale_factor_options
from taiji2_estimator_pkg.core.scale_factor.gls import ScaleFactorEstimator
from taiji2_estimator_pkg.core.scale_factor.paper import PaperScaleFactorFilter
from taiji2_estimator_pkg.nodes import common
from taiji2_model.contract import (
    ANGULAR_RATE_ESTIMATE_TOPIC,
    GRS_TOPIC_OF,
    SCALE_FACTOR_ESTIMATE_TOPIC_OF,
    STAR_TRACKER_TOPIC,
)
from taiji2_runtime.batched import create_batched_subscription
from taiji2_runtime.entry import run_node
from taiji2_runtime.ros import messages
from taiji2_runtime.threads import limit_blas_threads

GRS_IDS = (1, 2)
STREAMS = ("star_tracker", "grs1", "grs2")


def make_scale_factor_estimator(instrument: Any, params: dict[str, Any], star_tracker_offset_s: float = 0.0) -> Any:
    """The core estimator for ``params["method"]`` (both GRS jointly).

    ``star_tracker_offset_s``: time of each star-tracker readout after its epoch's GRS instant [s]
    (:meth:`taiji2_estimator_pkg.epochs.EpochAssembler.offset_s`), modelled by ``gls``; the paper's
    method takes the readouts at the epoch instants.
    """
    if params["method"] == "paper":
        return PaperScaleFactorFilter(instrument, GRS_IDS, paper_scale_factor_options(params))
    return ScaleFactorEstimator(instrument, GRS_IDS, replace(scale_factor_options(params),
                                                             star_tracker_offset_s=float(star_tracker_offset_s)))


class ScaleFactorEstimatorNode(common.EstimatorNode):
    """Estimates (G_Pphi, G_Ptheta, G_Ppsi) of GRS1 and GRS2 from the star tracker and the voltages."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("scale_factor_estimator", **node_kwargs)
        self.estimator = make_scale_factor_estimator(self.instrument, self.p)
        #: the star tracker's offset the estimator models [s], fixed at the first epoch holding a readout
        self.star_tracker_offset_s = 0.0
        self._offset_fixed = False
        self.last_nis = float("nan")
        resumed = self.resume()

        t = messages.taiji2_msgs
        qos = common.raw_qos()
        # raw streams: up to 16 queued messages per callback (rclpy takes one per wait-set pass otherwise)
        create_batched_subscription(self, t.StarTracker, STAR_TRACKER_TOPIC, self._on_star_tracker, qos)
        for gid in GRS_IDS:
            create_batched_subscription(self, t.GrsVoltages, GRS_TOPIC_OF[gid],
                                        lambda m, g=gid: self._on_grs(m, g), qos)
        self.estimate_pubs = {g: self.create_publisher(t.ScaleFactorEstimate,
                                                       SCALE_FACTOR_ESTIMATE_TOPIC_OF[g],
                                                       common.estimate_qos())
                              for g in GRS_IDS}
        self.rate_pub = self.create_publisher(messages.geometry_msgs.Vector3Stamped, ANGULAR_RATE_ESTIMATE_TOPIC, qos)
        if resumed is not None:
            # the restored estimate, latched: the killed process's estimates went with it, and a restart after
            # the run's end gets no data that would publish one (health reports its samples from now on)
            self.last_t_ns = resumed
            self.publish_estimate(resumed)
        self.get_logger().info(f"method {self.p['method']}, nominal model {self.p['layout']}, publishing every "
                               f"{self.p['publish_period_s']} s of data")

    def streams(self) -> Sequence[str]:
        return STREAMS

    # -- checkpoints ---------------------------------------------------------------------------
    def _checkpoint_payload(self) -> dict[str, Any]:
        return {"estimator": self.estimator.state_dict(), "star_tracker_offset_s": self.star_tracker_offset_s}

    def _restore_payload(self, state: dict[str, Any]) -> None:
        if "star_tracker_offset_s" in state:
            self.star_tracker_offset_s = float(state["star_tracker_offset_s"])
            self._offset_fixed = True
            self.estimator = make_scale_factor_estimator(self.instrument, self.p, self.star_tracker_offset_s)
        self.estimator.load_state_dict(state["estimator"])

    def _fix_star_tracker_offset(self) -> None:
        """Model the star tracker's offset from the GRS instants (the epoch rule's slot), before its first readout.

        The estimator is rebuilt with it if it has not taken an epoch yet. A star tracker heard only after the
        estimator started (epochs of the GRS alone first) keeps the offset it was built with, and this is logged.
        """
        self._offset_fixed = True
        offset = self.assembler.offset_s("star_tracker")
        if offset == self.star_tracker_offset_s or self.p["method"] == "paper":
            return
        if self.last_t_ns < 0:
            self.estimator = make_scale_factor_estimator(self.instrument, self.p, offset)
            self.star_tracker_offset_s = offset
            self.get_logger().info(f"star tracker read {offset * 1e3:.1f} ms after the GRS instants: modelled")
        else:
            self.get_logger().warn(f"star tracker read {offset * 1e3:.1f} ms after the GRS instants, heard after the "
                                   f"estimator started: {self.star_tracker_offset_s * 1e3:.1f} ms modelled")

    # -- input -----------------------------------------------------------------------------------
    def _on_star_tracker(self, msg: Any) -> None:
        if msg.header.frame_id not in ("crf", ""):
            self.node_rejections.add("star_tracker", "frame_id_mismatch")
            return
        self.add_sample("star_tracker", common.stamp_ns(msg.header), common.star_tracker_quaternion(msg))

    def _on_grs(self, msg: Any, grs_id: int) -> None:
        problem = common.grs_message_problem(msg, grs_id)
        if problem is not None:
            self.node_rejections.add(f"grs{grs_id}", problem)
            self.get_logger().warn(f"rejected GrsVoltages on {GRS_TOPIC_OF[grs_id]}: {problem} "
                                   f"(grs_id {msg.grs_id}, frame_id {msg.header.frame_id!r})",
                                   throttle_duration_sec=10.0)
            return
        self.add_sample(f"grs{grs_id}", common.stamp_ns(msg.header), common.grs_voltages(msg))

    def _process(self, epoch: Any) -> None:
        if not self._offset_fixed and "star_tracker" in epoch.samples:
            self._fix_star_tracker_offset()
        voltages = {g: epoch.samples[f"grs{g}"] for g in GRS_IDS if f"grs{g}" in epoch.samples}
        self.last_t_ns = epoch.t_ns
        try:
            report = self.estimator.update(epoch.t_ns / 1e9, epoch.samples.get("star_tracker"), voltages)
        except Exception as exc:  # never crash the graph on one epoch; keep what is estimated
            self.node_rejections.add("epoch", f"error:{type(exc).__name__}")
            self.get_logger().error(f"epoch {epoch.t_ns / 1e9:.1f} s skipped: {exc}", throttle_duration_sec=10.0)
            return
        for stream, reason in report.rejections:
            self.get_logger().warn(f"rejected {stream} sample at t = {epoch.t_ns / 1e9:.1f} s: {reason}",
                                   throttle_duration_sec=10.0)
        if np.isfinite(report.nis):
            self.last_nis = float(report.nis)
        # publish at the first epoch of every publish period (stamps aligned to the period)
        period_ns = int(self.p["publish_period_s"] * 1e9)
        if self.last_publish_ns < 0 or epoch.t_ns // period_ns > self.last_publish_ns // period_ns:
            self.publish_estimate(epoch.t_ns)

    # -- output ----------------------------------------------------------------------------------
    def publish_estimate(self, t_ns: int) -> None:
        estimate = self.estimator.estimate()
        self.last_estimate = estimate
        self.last_publish_ns = t_ns
        rejected = common.total(self.rejection_counts())
        missing, latency = self.samples_missing(), self.latency_s(t_ns)
        t = messages.taiji2_msgs
        for index, gid in enumerate(GRS_IDS):
            msg = t.ScaleFactorEstimate(grs_id=gid, method=estimate.method)
            common.set_stamp(msg.header, t_ns)
            msg.header.frame_id = common.GRS_FRAMES[gid]
            block = slice(3 * index, 3 * index + 3)
            other = slice(3 * (1 - index), 3 * (1 - index) + 3)
            msg.scale_factors = [float(v) for v in estimate.values[block]]
            msg.covariance = [float(v) for v in estimate.covariance[block, block].ravel()]
            msg.cross_covariance = [float(v) for v in estimate.covariance[block, other].ravel()]
            msg.samples_used = int(estimate.n_samples)
            msg.samples_rejected = int(rejected)
            msg.samples_missing = missing
            msg.latency_s = latency
            msg.nis = self.last_nis
            msg.nis_mean = float(estimate.nis_mean)
            self.estimate_pubs[gid].publish(msg)
        rate = getattr(self.estimator, "rate_estimate", None)
        omega = rate() if rate is not None else np.full(3, np.nan)
        if np.all(np.isfinite(omega)):
            msg = messages.geometry_msgs.Vector3Stamped()
            common.set_stamp(msg.header, t_ns)
            msg.header.frame_id = "crf"
            msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in omega)
            self.rate_pub.publish(msg)

    def destroy_node(self) -> None:
        # end of data: process what is still waiting for a late stream, publish and checkpoint
        try:
            for epoch in self.assembler.flush():
                self._process(epoch)
            if self.last_t_ns >= 0 and self.context.ok():
                self.publish_estimate(self.last_t_ns)
            if self.last_t_ns >= 0:
                self.save_checkpoint(self.last_t_ns)
        finally:
            super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    limit_blas_threads()  # one BLAS thread (docs/threads.md)
    return run_node(ScaleFactorEstimatorNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
