"""An estimator's result does not depend on how fast the machine is (issue 27, row 2).

The epochs an estimator node forms are a function of the messages it received and their order,
never of wall time (``epochs.py``). These tests feed the scale-factor and c.m.-offset estimator
nodes the same 120 s of data (1) without pause, (2) with the publisher stalled in the middle of a
tick for longer than ``max_stream_silence_s`` - the mechanism by which an epoch once went out without
the late stream's sample - and (3) with two CPU-bound processes running beside them, and assert
bit-identical estimates. Waits are bounded by the estimates reaching the last stamp.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_estimator_nodes import _Feeder

from taiji2_apps.cli.experiment_link import estimate_stamps_ns
from taiji2_estimator_pkg.nodes.com_offset_estimator import ComOffsetEstimatorNode
from taiji2_estimator_pkg.nodes.scale_factor_estimator import ScaleFactorEstimatorNode
from taiji2_model.config import load_config
from taiji2_runtime.ros import messages
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

from support import cpu_bound_processes, spin_until

N = 1200  # 120 s at 10 Hz
STALL_AT = 705  # inside a 1-s publish period: only the end-of-data publish puts out an estimate of k - 1
ARGS = ["--ros-args", "-p", "max_stream_silence_s:=0.3"]


@pytest.fixture(scope="module")
def experiment():
    config = load_config("type1", overrides={"maneuver.duration_s": N / 10})
    return simulate_batch(config, 5, maneuver_torque_commands(config, N))


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def _run(context, executor, out, stall: bool) -> tuple[np.ndarray, np.ndarray, dict]:
    """Feed the run to both estimator nodes; (G estimate, d estimate, rejections) at the last stamp."""
    sf_node = ScaleFactorEstimatorNode(context=context, cli_args=ARGS)
    co_node = ComOffsetEstimatorNode(context=context, cli_args=ARGS)
    feeder = _Feeder(context)
    d_estimates: list = []
    feeder.node.create_subscription(messages.taiji2_msgs.ComOffsetEstimate, "/taiji2/estimates/grs1/com_offset",
                                    d_estimates.append, 100)
    for node in (sf_node, co_node, feeder.node):
        executor.add_node(node)
    assert spin_until(executor, lambda: feeder.grs[2].get_subscription_count() >= 2)
    for k in range(N):
        t, q, v = out.t_s[k], out.st_quat_xyzw[k], out.voltages_v[k]
        feeder.star_tracker(t, q)
        feeder.voltages(t, 1, v[0])
        if stall and k == STALL_AT:
            # the publisher is descheduled before its GRS2 message: wait until the estimators have
            # seen the silence (they publish the estimate of the last epoch processed, k - 1 - or,
            # had they released epoch k without GRS2, of k)
            previous = round(out.t_s[k - 1] * 1e9)
            assert previous % 10**9 != 0
            assert spin_until(executor, lambda p=previous: feeder.estimates and _stamp_ns(feeder.estimates[-1]) >= p,
                              timeout_s=60)
        feeder.voltages(t, 2, v[1])
        if k % 100 == 0:
            executor.spin_once(timeout_sec=0.0)
    last_ns = round(out.t_s[N - 1] * 1e9)
    # the last d: of the last GRS data with the last G
    assert spin_until(executor, lambda: feeder.estimates and _stamp_ns(feeder.estimates[-1]) == last_ns
                      and d_estimates and estimate_stamps_ns(d_estimates[-1]) == (last_ns, last_ns), timeout_s=120)
    g = np.array(feeder.estimates[-1].scale_factors)
    d = d_estimates[-1]
    result = (g, np.array([d.offset.x, d.offset.y, d.offset.z]),
              {"sf": sf_node.rejection_counts(), "co": co_node.rejection_counts(),
               "missing": sf_node.assembler.missing()})
    for node in (sf_node, co_node, feeder.node):
        executor.remove_node(node)
        node.destroy_node()
    return result


def test_a_publisher_stalled_mid_tick_changes_nothing(context, executor, experiment):
    g0, d0, r0 = _run(context, executor, experiment, stall=False)
    g1, d1, r1 = _run(context, executor, experiment, stall=True)
    assert r0 == r1 == {"sf": {}, "co": {}, "missing": {"star_tracker": 0, "grs1": 0, "grs2": 0}}
    np.testing.assert_array_equal(g1, g0)
    np.testing.assert_array_equal(d1, d0)


def test_two_cpu_bound_processes_beside_the_estimators_change_nothing(context, executor, experiment):
    g0, d0, r0 = _run(context, executor, experiment, stall=False)
    with cpu_bound_processes(2):
        g1, d1, r1 = _run(context, executor, experiment, stall=False)
    assert r1 == r0
    np.testing.assert_array_equal(g1, g0)
    np.testing.assert_array_equal(d1, d0)
