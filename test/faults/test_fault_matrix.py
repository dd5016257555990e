"""Fault-injection matrix: the running graph survives a stalled node, a killed-and-restarted node,
wrong-type peers and a flooded raw topic; the estimates stay within their sigma of a fault-free run;
the bag holds everything up to the fault; /diagnostics names the fault.

One graph per fault type, the nodes faulted in turn (bounded CI time). With TAIJI2_FAULT_REPORT set,
each cell's measured loss is appended to that file as one JSON line (docs/faults.md is written from it).
"""

from __future__ import annotations

import json
import os
import subprocess
import textwrap

import numpy as np
import pytest
from fault_graph import DURATION_S, ESTIMATE_TOPICS, ESTIMATORS, NODES, RAW_TOPICS, SEED, Graph, bag_stamps

from taiji2_runtime.ros import rclpy

from support import PYTHON, cpu_bound_processes, python_subprocess_env

STALL_S = 5.0


def _report(fault: str, node: str, **measured: object) -> None:
    path = os.environ.get("TAIJI2_FAULT_REPORT")
    if path:
        with open(path, "a") as out:
            out.write(json.dumps({"fault": fault, "node": node, **measured}) + "\n")


#: the c.m.-offset estimate of a faulted run against the truth, in its own sigma (see _assert_within_sigma)
TRUTH_Z_MAX = 4.0


@pytest.fixture
def graph_context():
    ctx = rclpy.context.Context()
    rclpy.init(args=["fault-matrix"], context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope="module")
def reference():
    """Final estimates of the fault-free run (same layout, seed and duration), from the batch core.

    The node graph in lock-step is lossless and equals the batch simulator (test/nodes/test_sim_graph.py),
    and the bulk estimators equal the node path within 1e-6 sigma (test/estimator/test_bulk_irregular.py),
    so this is the fault-free graph's answer without running a sixth graph."""
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.pipeline import calibrate
    from taiji2_model.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    # unclipped, as the graph flies it: the paper's square wave takes 15 % of the linear readouts beyond the
    # range, and the estimators model no saturation (d_x 8 sigma off the truth at 600 s with it)
    config = load_config("type1", overrides={"maneuver.duration_s": DURATION_S, "grs.readout_saturation": False})
    out = simulate_batch(config, SEED, maneuver_torque_commands(config))
    result = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, InstrumentModel.from_layout(config))
    estimates = {}
    for kind, estimate in (("scale_factors", result.scale_factors), ("com_offset", result.com_offsets)):
        sigma = np.sqrt(np.diag(estimate.covariance))
        for g in (1, 2):
            block = slice(3 * (g - 1), 3 * g)
            estimates[f"/taiji2/estimates/grs{g}/{kind}"] = (estimate.values[block], sigma[block], len(out.t_s), 0)
    for g, sensor in enumerate(config.grs.sensors, start=1):
        estimates[f"truth/grs{g}/com_offset"] = np.asarray(sensor.com_offset_m, dtype=float)
    return estimates


def _assert_within_sigma(graph: Graph, reference: dict) -> dict[str, float]:
    """Every final estimate agrees with the fault-free one; returns the largest |gap| / bound per topic.

    Scale factors: 1 sigma of the fault-free estimate when the fault lost no data (same data, the estimate
    may differ only by a few samples' worth, far below sigma). When samples were lost the faulted estimate
    uses a subset of the fault-free run's data, so (for an efficient estimator on nested data) their
    difference has variance sigma_fault^2 - sigma_free^2: 3 standard deviations of it bound a correct
    estimate with 0.3 % false alarms per component, while a corrupted estimate (bad samples taken in,
    a wrong restored state) lands far outside.

    C.m. offsets: against the truth, |estimate - truth| <= TRUTH_Z_MAX sigma_fault (6e-5 false alarms per
    component). The nested bound does not hold for them: a stopped or killed commander makes the simulator
    fly the last command meanwhile (``commander late``), so the faulted run's maneuver differs from the
    reference's, and the c.m.-offset estimator adapts its readout noise R to the data it has
    (docs/estimators.md); measured 1.04-1.6 of the nested bound over kill runs, while the same data with
    windows of up to 100 s removed offline stay within 0.6 of it. A corrupted state lands at 6 and more."""
    gaps = {}
    for topic in ESTIMATE_TOPICS:
        value, sigma, _, _ = graph.estimates()[topic]
        ref_value, ref_sigma, _, _ = reference[topic]
        assert np.all(np.isfinite(sigma)), f"{topic}: estimate not determined"
        if topic.endswith("com_offset"):
            truth = reference["truth" + topic.removeprefix("/taiji2/estimates")]
            gap = np.abs(value - truth) / (TRUTH_Z_MAX * sigma)
            assert np.all(gap <= 1.0), (f"{topic}: |estimate - truth| / ({TRUTH_Z_MAX} sigma) = {gap}; estimate "
                                        f"{value}, fault-free {ref_value}, truth {truth}, sigma {sigma}")
        else:
            bound = np.maximum(ref_sigma, 3.0 * np.sqrt(np.maximum(sigma**2 - ref_sigma**2, 0.0)))
            gap = np.abs(value - ref_value) / bound
            assert np.all(gap <= 1.0), (f"{topic}: |estimate - fault-free| / bound = {gap}; sigma {sigma} vs "
                                        f"{ref_sigma}")
        gaps[topic] = float(gap.max())
    return gaps


def _samples(graph: Graph) -> dict[str, tuple[int, int]]:
    return {t: (e[2], e[3]) for t, e in graph.estimates().items()}


def _assert_clean_stop(graph: Graph, *, killed: str | None = None) -> None:
    assert graph.dead() == [], f"died: {graph.dead()}; see {graph.root}"
    codes = graph.stop()
    assert set(codes.values()) == {0}, f"exit codes at SIGINT: {codes}; see {graph.root}"


#: what /diagnostics must say once a stalled node continues (the recorder's stall only holds the run)
EXPECTED_AFTER_STALL = {"spacecraft_sim": "paused", "maneuver_commander": "commander late",
                        "scale_factor_estimator": "paused", "com_offset_estimator": "paused"}


@pytest.mark.long  # CI time: test_each_node_killed_and_restarted and test_slow_peer.py cover dead and slow peers
def test_each_node_stopped_for_5_s_then_continued(graph_context, tmp_path, reference):
    graph = Graph(tmp_path, graph_context)
    graph.start()
    named = {}
    try:
        for k, name in enumerate(NODES):
            graph.wait_for_progress(50.0 + 100.0 * k)  # the stalls spread over the run
            seen = len(graph.diagnostics)
            graph.stall(name, STALL_S)
            # the resumed nodes' next health reports: the expected one (reports are periodic, and a
            # loaded machine delays them), else 3 s of them
            token = EXPECTED_AFTER_STALL.get(name)
            if token is None:
                graph.spin_for(3.0)
            else:
                graph.spin_until(lambda t=token, s0=seen: any(t in d.message for d in graph.diagnostics[s0:]
                                                              if d.level > 0), 60.0,
                                 f"{token!r} after stalling {name}")
            named[name] = sorted({d.message for d in graph.diagnostics[seen:] if d.level > 0})
        graph.wait_for_end()
        gaps = _assert_within_sigma(graph, reference)
        samples = _samples(graph)
        for name in NODES:
            _report("SIGSTOP 5 s", name, samples=samples, max_gap_over_bound=max(gaps.values()), named=named[name])
        for name in ESTIMATORS:  # a paused estimator names its own pause once continued
            own = {d.message for d in graph.diagnostics if d.name == name and d.level > 0}
            assert any("paused" in m for m in own), (name, own)
        assert any("commander late" in m for m in named["maneuver_commander"]), named["maneuver_commander"]
    finally:
        _assert_clean_stop(graph)
    # every raw sample of the run is in the bag, once, in order
    stamps = bag_stamps(graph.bags[0])
    expected = list(range(100_000_000, round(graph.duration_s * 1e9) + 1, 100_000_000))
    for topic in RAW_TOPICS:
        assert stamps[topic] == expected, f"{topic}: {len(stamps[topic])} of {len(expected)} samples in the bag"


#: killed in turn, one graph (bounded CI time). The recorder first: its restart must find most of the run
#: still to record, however far it trailed the graph. The simulator last: a restarted one runs its seed again
#: from t = 0 and the commander follows its clock back; the estimators refuse the rerun's stamps up to where
#: their own data ended and take it up from there as a new segment (every raw stream went back in time), since
#: the rerun need not be the same trajectory (it is not after the commander's outage: the simulator stepped on
#: with the last command then). An estimator restarted after the first run ended gets its missing data only so
VICTIMS = ["recorder", "maneuver_commander", "scale_factor_estimator", "com_offset_estimator", "spacecraft_sim"]


@pytest.mark.parametrize("hogs", [0, pytest.param(2, marks=pytest.mark.long)], ids=["idle", "beside_2_cpu_hogs"])
def test_each_node_killed_and_restarted(graph_context, tmp_path, reference, hogs):
    """Also beside two CPU-bound processes (issue 25: a restarted estimator never reported its resume on a busy
    machine): every wait in it is bounded by the graph's simulated progress, so load only slows it. That case is
    marked long (its hogs slowed the suite's other worker for 80 s of CI); the suite is run beside two CPU-bound
    processes before a change is submitted, which loads this case the same way."""
    with cpu_bound_processes(hogs):
        _kill_and_restart_each_node(graph_context, tmp_path, reference)


def _kill_and_restart_each_node(graph_context, tmp_path, reference):
    graph = Graph(tmp_path, graph_context)
    graph.start()
    kills: dict[str, tuple[float, float]] = {}
    try:
        for k, victim in enumerate(VICTIMS):
            # the kills spread over the simulated run. On the simulator's clock, not on the estimates'
            # progress: the simulator runs ahead of the estimators, and data it published while an
            # estimator was down are that estimator's (reported) gap, which it only takes up from the
            # simulator's rerun, so the estimates may never reach a later kill time before the last kill
            graph.wait_for_sim_time(60.0 + 100.0 * k)
            if victim == "recorder":  # the first kill: nothing lost yet, the estimates get there too
                graph.wait_for_progress(60.0)
            # every raw sample older than these estimates reached the recorder before it was killed, and
            # 2 s of wall time (4 journal periods) later it is in a closed journal file
            safe_s = graph.progress_s()
            if victim == "recorder":
                # what the recorder's bag lists as closed files just before the kill: the recorder keeps
                # up (its closed journals reach the estimates' progress within a bounded wall time) ...
                listed = graph.wait_for_bag(graph.bags[0], safe_s)
            else:
                graph.spin_for(2.0)
            kills[victim] = (safe_s, graph.progress_s())
            graph.kill_and_restart(victim)
            graph.wait_until_restarted(victim)
        graph.wait_for_end()
        for victim in ESTIMATORS:  # each restarted estimator names its resume, from its restart on ...
            resumed = [d for d in graph.named("resumed from checkpoint") if d.name == victim]
            assert resumed, (victim, [d.message for d in graph.diagnostics if d.name == victim][-20:],
                             graph.log_tails())
            # ... and its data gap once data beyond its checkpoint arrived. The estimates may reach the end
            # before that: an estimator that had published the end before its kill (a busy machine: the
            # simulator and the estimators ran ahead of the test) takes up its data beyond the checkpoint
            # from the restarted simulator's rerun, so the wait is bounded by simulated progress
            graph.spin_until(lambda v=victim: [d for d in graph.named("resumed from checkpoint", "data gap")
                                               if d.name == v], 60.0, f"{victim} to name its data gap",
                             while_moving=True)
        graph.wait_for_end()  # again: a restarted estimator may have published its restored (earlier) estimate
        gaps = _assert_within_sigma(graph, reference)
        samples = _samples(graph)
        for victim, (_, killed_at_s) in kills.items():
            lost_s = 0.0
            if victim in ESTIMATORS:
                lost_s = max(d.values["data_gap_s"] for d in graph.named("resumed from checkpoint", "data gap")
                             if d.name == victim)
            if victim == "spacecraft_sim":
                # the rerun's stamps up to what the estimators had are refused as out of order, counted and
                # named; the commander commands again from the restarted clock (the run reached its end)
                # (when the estimators already had the whole run, the rerun is refused after wait_for_end)
                graph.spin_until(lambda: graph.named("rejected input", "out_of_order_stamp"), 60.0,
                                 "the estimators to name the rerun's repeated stamps", while_moving=True)
                # (the commander's 'clock went back' line is in its log only once it flushes, at its stop)
            _report("SIGKILL + restart", victim, killed_at_s=killed_at_s, samples=samples, lost_s=lost_s,
                    max_gap_over_bound=max(gaps.values()))
    finally:
        _assert_clean_stop(graph)
    safe_s, killed_at_s = kills["recorder"]
    first = bag_stamps(graph.bags[0])  # ... the killed recorder's bag stays readable ...
    for topic in RAW_TOPICS:
        got = first[topic]
        # ... and holds every sample from the start up to at least what it listed before the kill (a
        # SIGKILL loses only the open journal, never a file the metadata listed)
        assert got == list(range(got[0], got[-1] + 1, 100_000_000)) and got[0] == 100_000_000, topic
        assert got[-1] >= listed[topic] >= safe_s * 1e9, (topic, got[-1] / 1e9, safe_s, killed_at_s)
    # ... and the restarted one records on to the end of the run: the end of the first run where the simulator
    # reached it before its kill (its rerun from t = 0 then follows, as far as it got before the graph was
    # stopped: a few seconds of it on a busy machine), else the end of the rerun, which the estimates needed
    second = bag_stamps(graph.bags[1])
    for topic in RAW_TOPICS:
        assert max(second[topic]) == round(graph.duration_s * 1e9), (topic, max(second[topic]) / 1e9, graph.root)


WRONG_PEER = textwrap.dedent("""
    import sys, time
    from taiji2_runtime.ros import rclpy, messages
    rclpy.init(args=["wrong-peer"])
    node = rclpy.create_node("fault_wrong_peer")
    q = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                             reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
    t = messages.taiji2_msgs
    topics = sys.argv[1:]
    strings = [node.create_publisher(messages.std_msgs.String, tp, q) for tp in topics]
    # right type, wrong content: GRS voltages on the star-tracker's neighbours with a foreign frame,
    # and a flood at 100x the 10-Hz rate with stamps the stream already passed
    # a DDS participant has one type per topic: the right-type flood comes from a second participant
    flood_context = rclpy.context.Context()
    rclpy.init(args=["flood-peer"], context=flood_context)
    flood_node = rclpy.create_node("fault_flood_peer", context=flood_context)
    grs = flood_node.create_publisher(t.GrsVoltages, "/taiji2/grs1/voltages", q)
    # malformed CDR: a truncated GrsVoltages payload handed to Cyclone DDS below the rclpy API
    from cyclonedds._clayer import ddspy_write
    from cyclonedds.pub import DataWriter
    raw = DataWriter(flood_context.participant(), flood_context.topic("rt/taiji2/grs2/voltages", t.GrsVoltages))
    malformed = refused = 0
    # the String writers match no reader (DDS matches type names): they must merely not disturb the graph
    while grs.get_subscription_count() < 3:
        time.sleep(0.05)  # matched (GRS1: both estimators and the recorder): nothing sent is lost to discovery
    k, start = 0, time.monotonic()
    while rclpy.ok() and time.monotonic() - start < float(FLOOD_S):
        for pub in strings:
            pub.publish(messages.std_msgs.String(data="not a sample"))
        msg = t.GrsVoltages(grs_id=1)
        msg.header.frame_id = "tmrf1"
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 1_000_000, 1_000_000_000)
        grs.publish(msg)
        malformed += 1
        refused += ddspy_write(raw._ref, b"\\x00\\x01\\x00\\x00" + b"\\xff" * 7 + b"\\x00") < 0
        k += 1
        time.sleep(0.001)
    print(malformed, refused, flush=True)
    print(k, flush=True)
""")


def test_wrong_type_peers_and_a_flooded_raw_topic(graph_context, tmp_path, reference):
    graph = Graph(tmp_path, graph_context)
    graph.start()
    peer = None
    try:
        graph.wait_for_progress(100.0)
        peer = subprocess.Popen([PYTHON, "-c", WRONG_PEER.replace("FLOOD_S", "5.0"), *RAW_TOPICS],
                                env=python_subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        out, err = peer.communicate(timeout=60)
        graph.wait_for_end()
        gaps = _assert_within_sigma(graph, reference)
        samples = _samples(graph)
        lines = out.strip().splitlines()
        flooded = int(lines[-1]) if lines else 0
        malformed, refused = map(int, lines[-2].split()) if len(lines) > 1 else (0, 0)
        assert graph.named("rejected input"), [d.message for d in graph.diagnostics if d.level > 0][:20]
        # Cyclone DDS validates CDR when a sample is written (and again when one is received): a
        # truncated payload never reaches the wire, so the graph cannot be fed one by a DDS peer
        assert malformed > 0 and refused == malformed, (malformed, refused, err[-500:])
        _report("wrong type + malformed CDR + flood 100x", "raw topics", flood_samples=flooded,
                malformed_cdr_refused_by_dds=refused, samples=samples,
                max_gap_over_bound=max(gaps.values()), peer_stderr=err[-300:])
    finally:
        _assert_clean_stop(graph)


# the writer's full-storage behaviour is tested without a graph (test/bag/test_writer.py, both storages); this
# graph case (~40 s) is left out of CI for its 20-min limit: pytest -m long
@pytest.mark.long
def test_recorder_on_a_storage_that_fills_up(graph_context, tmp_path, reference):
    # 1.5 MB per file: the recorder's open segment hits it a few times in the run (the graph's
    # messages make ~6 MB), and each journal (0.5 s of wall time) stays far below it
    graph = Graph(tmp_path, graph_context, recorder_file_size_limit=1_500_000)
    graph.start()
    try:
        graph.wait_for_end()
        graph.spin_for(1.0)  # the recorder's last status
        gaps = _assert_within_sigma(graph, reference)  # the estimators did not notice
        failed = graph.named("bag storage failed")
        assert failed, [d.message for d in graph.diagnostics if d.level > 0][:20]
    finally:
        _assert_clean_stop(graph)
    stamps = bag_stamps(graph.bags[0])  # the bag opens: every file it lists is complete
    log = graph.log("recorder")
    dropped = int(log.split(" messages received but not recorded: bag storage failed")[0].rsplit(None, 1)[-1])
    total = sum(len(v) for v in stamps.values())
    expected = list(range(100_000_000, round(graph.duration_s * 1e9) + 1, 100_000_000))
    for topic in RAW_TOPICS:
        got = stamps[topic]
        assert got == sorted(set(got)) and got[0] == expected[0], f"{topic}: in order, from the first sample"
        assert set(got) <= set(expected), topic
    lost = {t: len(expected) - len(stamps[t]) for t in RAW_TOPICS}
    assert 0 < sum(lost.values()) <= dropped, (lost, dropped)  # every raw sample lost was counted as dropped
    _report("storage full (1.5 MB file limit)", "recorder", raw_samples_in_bag=total, raw_samples_lost=lost,
            dropped_messages_counted=dropped, failures=len(failed), max_gap_over_bound=max(gaps.values()))
