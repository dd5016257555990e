"""Estimator nodes: parameters file, bad input (rejected, counted, WARN, estimate continues), restart resume."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from taiji2_apps.cli.experiment_link import estimate_stamps_ns
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.parameters import flatten
from taiji2_estimator_pkg.core.scale_factor import ScaleFactorEstimator
from taiji2_estimator_pkg.nodes.com_offset_estimator import ComOffsetEstimatorNode
from taiji2_estimator_pkg.nodes.scale_factor_estimator import ScaleFactorEstimatorNode
from taiji2_model.config import load_config
from taiji2_runtime.ros import RUNTIME, messages, rclpy
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

from support import REPO, spin_until

PARAMS_FILE = REPO / "src" / "taiji2_estimator_pkg" / "config" / "estimators.yaml"
N = 3000  # 300 s at 10 Hz


@pytest.fixture(scope="module")
def experiment():
    config = load_config("type1", overrides={"maneuver.duration_s": N / 10})
    return simulate_batch(config, 21, maneuver_torque_commands(config, N))


class _Feeder:
    """Publishes raw contract messages and collects estimates and diagnostics."""

    def __init__(self, context):
        self.node = rclpy.node.Node("feeder", context=context)
        t = messages.taiji2_msgs
        qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        self.star = self.node.create_publisher(t.StarTracker, "/taiji2/star_tracker", qos)
        self.grs = {g: self.node.create_publisher(t.GrsVoltages, f"/taiji2/grs{g}/voltages", qos) for g in (1, 2)}
        self.estimates: list = []
        self.node.create_subscription(t.ScaleFactorEstimate, "/taiji2/estimates/grs1/scale_factors",
                                      self.estimates.append, qos)
        self.diagnostics: list = []
        self.node.create_subscription(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics",
                                      lambda m: self.diagnostics.extend(m.status), 100)

    def star_tracker(self, t_s, q):
        m = messages.taiji2_msgs.StarTracker()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(round(t_s * 1e9), 10**9)
        m.header.frame_id = "crf"
        m.attitude.x, m.attitude.y, m.attitude.z, m.attitude.w = (float(v) for v in q)
        self.star.publish(m)

    def voltages(self, t_s, grs_id, v, *, topic_id=None, frame=None):
        m = messages.taiji2_msgs.GrsVoltages(grs_id=grs_id)
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(round(t_s * 1e9), 10**9)
        m.header.frame_id = frame or f"tmrf{grs_id}"
        m.vx1, m.vx2, m.vy1, m.vy2, m.vz1, m.vz2 = (float(x) for x in v)
        self.grs[topic_id or grs_id].publish(m)


def test_params_file_and_node_declarations_are_one_source(context):
    node = ScaleFactorEstimatorNode(context=context, cli_args=["--ros-args", "--params-file", str(PARAMS_FILE)])
    documented = flatten(yaml.safe_load(PARAMS_FILE.read_text())["scale_factor_estimator"]["ros__parameters"])
    documented.pop("grs_ids")  # offline API only (documented so)
    for key, value in documented.items():
        assert node.has_parameter(key), key
        assert node.get_parameter(key).value == value, key


def _feed(feeder, executor, out, indices, corrupt=None):
    for k in indices:
        q, v = out.st_quat_xyzw[k], out.voltages_v[k]
        if corrupt is None or not corrupt(feeder, k, out.t_s[k], q, v):
            feeder.star_tracker(out.t_s[k], q)
            feeder.voltages(out.t_s[k], 1, v[0])
            feeder.voltages(out.t_s[k], 2, v[1])
        if k % 100 == 0:
            executor.spin_once(timeout_sec=0.0)


def test_lost_samples_are_counted_per_stream_and_reported_on_diagnostics_and_in_the_estimates(context, executor,
                                                                                            experiment):
    """A node that joins at 34 s and then loses 250 GRS2 samples and 10 star-tracker samples (a
    replay whose QoS dropped them) counts them per stream from its first sample, WARNs naming them,
    and says how many in every estimate message."""
    out = experiment
    node = ScaleFactorEstimatorNode(context=context)
    feeder = _Feeder(context)
    executor.add_node(node)
    executor.add_node(feeder.node)
    assert spin_until(executor, lambda: feeder.star.get_subscription_count() >= 1)

    def lose(f, k, t, q, v):
        if 1000 <= k < 1250:
            f.star_tracker(t, q)
            f.voltages(t, 1, v[0])
            return True
        if 2000 <= k < 2010:
            f.voltages(t, 1, v[0])
            f.voltages(t, 2, v[1])
            return True
        return False

    _feed(feeder, executor, out, range(340, N), lose)
    last_ns = round(out.t_s[-1] * 1e9)
    assert spin_until(executor, lambda: feeder.estimates and feeder.estimates[-1].header.stamp.sec
                      * 10**9 + feeder.estimates[-1].header.stamp.nanosec == last_ns, timeout_s=60)
    assert feeder.estimates[-1].samples_missing == 260
    assert node.assembler.missing() == {"star_tracker": 10, "grs1": 0, "grs2": 250}
    assert node.assembler.first_ns == round(out.t_s[340] * 1e9)

    def last_status():
        mine = [s for s in feeder.diagnostics if s.name == "scale_factor_estimator"]
        return mine[-1] if mine else None

    assert spin_until(executor, lambda: last_status() is not None and "missing input" in last_status().message
                      and json.loads({kv.key: kv.value for kv in last_status().values}["missing"])["grs2"] == 250,
                      timeout_s=10)
    assert last_status().level == messages.diagnostic_msgs.DiagnosticStatus.WARN
    assert "grs2 250 samples" in last_status().message


def test_bad_inputs_are_rejected_counted_and_reported_while_the_estimate_goes_on(context, executor, experiment):
    out = experiment
    node = ScaleFactorEstimatorNode(context=context)
    feeder = _Feeder(context)
    executor.add_node(node)
    executor.add_node(feeder.node)
    assert spin_until(executor, lambda: feeder.star.get_subscription_count() >= 1)

    def corrupt(f, k, t, q, v):
        if k == 500:   # NaN voltage
            f.star_tracker(t, q)
            f.voltages(t, 1, np.full(6, np.nan))
            f.voltages(t, 2, v[1])
            return True
        if k == 600:   # a GRS2 message on the GRS1 topic, and a wrong frame
            f.star_tracker(t, q)
            f.voltages(t, 2, v[1], topic_id=1)
            f.voltages(t, 2, v[1], frame="base_link")
            return True
        if 700 <= k < 750:  # star-tracker dropout
            f.voltages(t, 1, v[0])
            f.voltages(t, 2, v[1])
            return True
        if k == 800:   # non-unit quaternion
            f.star_tracker(t, 1.5 * q)
            f.voltages(t, 1, v[0])
            f.voltages(t, 2, v[1])
            return True
        if k == 900:   # duplicate stamp
            for _ in range(2):
                f.star_tracker(t, q)
                f.voltages(t, 1, v[0])
                f.voltages(t, 2, v[1])
            return True
        return False

    _feed(feeder, executor, out, range(N), corrupt)
    last_ns = round(out.t_s[-1] * 1e9)
    assert spin_until(executor, lambda: node.last_publish_ns >= last_ns, timeout_s=60)
    warn_level = messages.diagnostic_msgs.DiagnosticStatus.WARN
    expected = ("grs_id_mismatch", "frame_id_mismatch", "duplicate_stamp")

    def rejected_in(status):
        return json.loads({kv.key: kv.value for kv in status.values}["rejected"])

    def statuses():
        return [s for s in feeder.diagnostics if s.name == "scale_factor_estimator"]

    # a WARN names the rejections as they happen (how many statuses that takes depends on the
    # machine's speed against the 1-s health timer); the cumulative counts then hold every reason
    assert spin_until(executor, lambda: any(s.level == warn_level for s in statuses())
                      and all(r in json.dumps(rejected_in(statuses()[-1])) for r in expected), timeout_s=5)
    rejected = rejected_in(statuses()[-1])
    assert "grs1" in rejected and "star_tracker" in rejected  # NaN voltage, non-unit quaternion
    estimate = node.estimator.estimate()
    assert estimate.determined and np.all(np.isfinite(estimate.values))
    assert estimate.n_samples >= N - 60  # everything else was used


def test_a_restarted_node_resumes_from_its_checkpoint(context, executor, experiment, tmp_path):
    out = experiment
    checkpoint = Path(tmp_path) / "sf.json"
    args = ["--ros-args", "-p", f"checkpoint_file:={checkpoint}", "-p", "checkpoint_period_s:=10.0"]
    feeder = _Feeder(context)
    executor.add_node(feeder.node)
    first = ScaleFactorEstimatorNode(context=context, cli_args=args)
    executor.add_node(first)
    assert spin_until(executor, lambda: feeder.star.get_subscription_count() >= 1)
    half = N // 2
    _feed(feeder, executor, out, range(half))
    half_ns = round(out.t_s[half - 1] * 1e9)
    assert spin_until(executor, lambda: first.assembler.released_ns >= half_ns, timeout_s=60)
    first.destroy_node()  # the node goes down (checkpoint written at shutdown)
    assert checkpoint.exists()
    second = ScaleFactorEstimatorNode(context=context, cli_args=args)
    executor.add_node(second)
    assert spin_until(executor, lambda: feeder.star.get_subscription_count() >= 1)
    _feed(feeder, executor, out, range(half, N))
    last_ns = round(out.t_s[-1] * 1e9)
    assert spin_until(executor, lambda: second.last_publish_ns >= last_ns, timeout_s=60)
    resumed = second.estimator.estimate()
    reference = ScaleFactorEstimator(InstrumentModel.from_layout("type1"), (1, 2)).process_batch(
        out.t_s, out.st_quat_xyzw, out.voltages_v)
    assert resumed.n_samples == reference.n_samples  # nothing lost, nothing counted twice
    np.testing.assert_allclose(resumed.values, reference.values, rtol=1e-9)


def test_a_restarted_node_reports_its_resume_with_its_state_also_without_new_data_and_to_a_late_subscriber(
        context, executor, experiment, tmp_path):
    # /diagnostics is volatile: a restarted estimator that named its resume in one report only, once data
    # beyond its checkpoint arrived, said nothing to a subscriber that matched it later (discovery on a
    # loaded machine: the fault matrix's monitor) and, with no new data (the run over), only "starved"
    out = experiment
    checkpoint = Path(tmp_path) / "sf.json"
    args = ["--ros-args", "-p", f"checkpoint_file:={checkpoint}"]
    feeder = _Feeder(context)
    executor.add_node(feeder.node)
    first = ScaleFactorEstimatorNode(context=context, cli_args=args)
    executor.add_node(first)
    assert spin_until(executor, lambda: feeder.star.get_subscription_count() >= 1)
    third = N // 3
    _feed(feeder, executor, out, range(third))
    third_ns = round(out.t_s[third - 1] * 1e9)
    assert spin_until(executor, lambda: first.assembler.released_ns >= third_ns, timeout_s=60)
    first.destroy_node()  # checkpoint written at shutdown, at the last epoch
    checkpoint_s = first.last_t_ns / 1e9
    restored = first.estimator.estimate().n_samples
    feeder.estimates.clear()
    second = ScaleFactorEstimatorNode(context=context, cli_args=args)
    executor.add_node(second)
    warn = messages.diagnostic_msgs.DiagnosticStatus.WARN

    def reports(statuses, *words):
        return [s for s in statuses if s.name == "scale_factor_estimator" and s.level == warn
                and all(w in s.message for w in words)]

    def samples_used(status):
        return json.loads({kv.key: kv.value for kv in status.values}["samples_used"])

    # no data yet: the resume is named with the restored state, and the restored estimate is published (latched)
    resumed = f"resumed from checkpoint at t = {checkpoint_s:.1f} s"
    assert spin_until(executor, lambda: reports(feeder.diagnostics, resumed, "no data beyond it yet"), timeout_s=10)
    assert samples_used(reports(feeder.diagnostics, resumed)[-1]) == restored
    assert spin_until(executor, lambda: feeder.estimates, timeout_s=10)
    assert feeder.estimates[-1].samples_used == restored
    assert feeder.estimates[-1].header.stamp.sec + feeder.estimates[-1].header.stamp.nanosec / 1e9 == checkpoint_s
    # data beyond the checkpoint (none lost here): the data gap is named, and still to a subscriber that
    # matches the restarted node after its first report of it
    _feed(feeder, executor, out, range(third, N))
    assert spin_until(executor, lambda: reports(feeder.diagnostics, resumed, "data gap 0.1 s"), timeout_s=60)
    late: list = []
    listener = rclpy.node.Node("late_listener", context=context)
    listener.create_subscription(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics",
                                 lambda m: late.extend(m.status), 100)
    executor.add_node(listener)
    assert spin_until(executor, lambda: reports(late, resumed, "data gap 0.1 s"), timeout_s=10)


@pytest.mark.xfail(RUNTIME == "rclpy", strict=False,
                   reason="known: under real rclpy the c.m.-offset node's d stamps are not one per publish period "
                          "(first at period 110, one repeated); reproduced on 2868f38 too, cause not found (open)")
def test_a_run_ending_inside_a_publish_period_publishes_its_last_epoch(context, executor, experiment):
    # data stop at 299.6 s, inside the 1-s publish period that began at 299.0 s: once the data have
    # been silent for max_stream_silence_s, both estimators publish the estimate of the last epoch
    out = experiment
    last = N - 5
    args = ["--ros-args", "-p", "max_stream_silence_s:=0.5"]
    sf_node = ScaleFactorEstimatorNode(context=context, cli_args=args)
    co_node = ComOffsetEstimatorNode(context=context, cli_args=args)
    feeder = _Feeder(context)
    d_estimates: list = []
    feeder.node.create_subscription(messages.taiji2_msgs.ComOffsetEstimate, "/taiji2/estimates/grs1/com_offset",
                                    d_estimates.append, 100)
    for node in (sf_node, co_node, feeder.node):
        executor.add_node(node)
    assert spin_until(executor, lambda: feeder.grs[1].get_subscription_count() >= 2)
    _feed(feeder, executor, out, range(last + 1))
    last_ns = round(out.t_s[last] * 1e9)
    assert last_ns % 10**9 != 0  # not on a period boundary: the case the periodic publishing misses

    def stamp(msg) -> int:
        return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec

    # the last d: of the last GRS data with the last G (which may come after the last GRS sample)
    assert spin_until(executor, lambda: feeder.estimates and stamp(feeder.estimates[-1]) == last_ns
                      and d_estimates and estimate_stamps_ns(d_estimates[-1]) == (last_ns, last_ns), timeout_s=60)
    assert feeder.estimates[-1].samples_used == last + 1  # every epoch is in it
    assert d_estimates[-1].samples_used == last + 1
    # at most one d per publish period of its data, before those at the end of data: publishing at each newer G
    # too sent up to two d a period (here, fed faster than real time, G arrives in bursts: before, 208 d with
    # stamps in 30 periods, 6-8 d in most of them; one each now)
    periods = [stamp(m) // 10**9 for m in d_estimates if stamp(m) < last_ns]
    assert len(periods) >= 10 and all(a < b for a, b in itertools.pairwise(periods)), periods
    # each d says which data it rests on: its stamp is that of its last GRS sample (samples_used counts the
    # epochs up to it) and scale_factors_stamp that of a G the scale-factor estimator published. (Stamped
    # min(data, G) before: here G lags, and d stamped with G's time had used GRS data beyond it.)
    t_ns = np.round(out.t_s[:last + 1] * 1e9).astype(np.int64)
    g_stamps = {stamp(m) for m in feeder.estimates}
    for m in d_estimates:
        data_ns, g_ns = estimate_stamps_ns(m)
        assert m.samples_used == np.count_nonzero(t_ns <= data_ns), (data_ns, m.samples_used)
        assert g_ns in g_stamps, g_ns
        # and G is that of the same publish period as the data, as offline, however the feed runs ahead of the
        # scale-factor estimator (the epochs wait for it; without the wait G lagged by up to 180 s here)
        assert g_ns // 10**9 == data_ns // 10**9, (data_ns, g_ns)


def test_the_epochs_waiting_for_their_scale_factors_are_in_the_checkpoint(context, tmp_path):
    """A c.m.-offset node killed while epochs wait for their scale factors (a restarted scale-factor estimator
    catching up) resumes with them: they were released by the assembler, so a rerun's samples of them are
    refused, and before they were in no checkpoint (the node's estimate then stalled for good)."""
    from taiji2_estimator_pkg.epochs import Epoch

    checkpoint = Path(tmp_path) / "co.json"
    args = ["--ros-args", "-p", f"checkpoint_file:={checkpoint}"]
    first = ComOffsetEstimatorNode(context=context, cli_args=args)
    try:
        first.waiting.through_ns = 0  # scale factors of the data through t = 0 s have come: later epochs wait
        held = [Epoch(k * 100_000_000, {"grs1": np.full(6, 1e-3 * k), "grs2": np.full(6, -1e-3 * k)},
                      {"grs1": k * 100_000_000, "grs2": k * 100_000_000}, index=k) for k in range(11, 31)]
        for epoch in held:
            first._process_epoch(epoch)
        assert list(first.waiting.pending) == held and first.last_t_ns < 0  # none estimated yet
        first.save_checkpoint(1_000_000_000)
        killed = checkpoint.read_bytes()  # then SIGKILL: the checkpoint as it was (no shutdown, nothing flushed)
    finally:
        first.destroy_node()
    checkpoint.write_bytes(killed)
    second = ComOffsetEstimatorNode(context=context, cli_args=args)
    try:
        restored = list(second.waiting.pending)
        assert [e.t_ns for e in restored] == [e.t_ns for e in held]
        for a, b in zip(restored, held, strict=True):
            assert a.stamps == b.stamps and all(np.array_equal(a.samples[s], b.samples[s]) for s in b.samples)
    finally:
        second.destroy_node()
