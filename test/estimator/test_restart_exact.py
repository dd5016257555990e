"""A killed and restarted estimator: its checkpoint restores the state exactly, and the data it lost
meanwhile (a gap in every stream) cost precision, never bias.

The fault matrix (test/faults/test_fault_matrix.py) once found the restarted scale-factor estimator's
G_Ppsi 1.58 sigma from the fault-free run with almost no data lost. The checkpoint was exact (below,
bit for bit); the gap was not: the 6-26 s of data a restart loses were bridged with the last GRS input
held (gaps up to ``max_bridged_gap_s``, 10 s), and a torque switch of the maneuver inside the gap left
the old acceleration in the prediction, which G absorbed (2.6 sigma on G_Ppsi for 9.9 s lost at
t = 275 s, Type-1 seed 4, G_Ppsi's sigma only 0.2 % larger than without the gap). Where the input after
a gap is not the held one, the attitude and rate that the switch's unknown time leaves unexplained now
get a (nearly) diffuse variance; a gap with no GRS input after it to tell starts a new segment.

Same seed, layout and duration as the fault matrix (600 s, Type-1, seed 4): switches every 31.25 s.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.scale_factor import ScaleFactorEstimator

from estimator_support import simulate, truth

DURATION_S = 600.0
SEED = 4
#: re-delivered samples before the restart point (a restarted subscriber may see some again)
REDELIVERED = 3


@pytest.fixture(scope="module")
def run():
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands

    config, out = simulate("type1", DURATION_S, SEED)
    commands = maneuver_torque_commands(config)
    switches = np.flatnonzero(np.any(np.diff(commands, axis=0) != 0, axis=1)) + 1
    instrument = InstrumentModel.from_layout(config)
    reference = ScaleFactorEstimator(instrument)
    _feed(reference, out, range(len(out)))
    return config, out, instrument, switches, reference


def _feed(est, out, rows):
    for k in rows:
        est.update(out.t_s[k], out.st_quat_xyzw[k], {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]})


def _restored(est, cls, instrument):
    """A fresh estimator from ``est``'s checkpoint as a node writes and reads it (JSON)."""
    return cls.from_state_dict(instrument, json.loads(json.dumps(est.state_dict())))


def test_scale_factor_checkpoint_restores_the_state_exactly(run):
    _, out, instrument, switches, reference = run
    s = int(switches[len(switches) // 2])
    # the first epochs (before the estimate is determined), around a torque switch, an arbitrary one, the last
    for cut in (2, s - 1, s, 4567, len(out) - 1):
        first = ScaleFactorEstimator(instrument)
        _feed(first, out, range(cut))
        resumed = _restored(first, ScaleFactorEstimator, instrument)
        _feed(resumed, out, range(max(cut - REDELIVERED, 0), len(out)))  # the repeats are refused
        got, want = resumed.estimate(), reference.estimate()
        assert want.determined and got.determined
        # rounding bound 1e-12 relative (measured: identical)
        np.testing.assert_allclose(got.values, want.values, rtol=1e-12, err_msg=f"resumed at epoch {cut}")
        np.testing.assert_allclose(got.covariance, want.covariance, rtol=1e-12,
                                   atol=1e-12 * np.abs(want.covariance).max())
        np.testing.assert_allclose(resumed.rate_estimate(), reference.rate_estimate(), rtol=1e-9, atol=1e-15)
        assert got.n_samples == want.n_samples


def test_com_offset_checkpoint_restores_the_state_exactly(run):
    config, out, instrument, switches, _ = run
    g_true, _ = truth(config)
    scale_factors = (g_true, np.diag((5e-4 * g_true) ** 2))
    omega = out.truth.omega_rad_s

    def feed(est, rows):
        for k in rows:
            est.update(out.t_s[k], {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]}, omega[k], scale_factors)

    reference = ComOffsetEstimator(instrument)
    feed(reference, range(len(out)))
    s = int(switches[len(switches) // 2])
    for cut in (s, 4567):
        first = ComOffsetEstimator(instrument)
        feed(first, range(cut))
        resumed = _restored(first, ComOffsetEstimator, instrument)
        feed(resumed, range(max(cut - REDELIVERED, 0), len(out)))
        got, want = resumed.estimate(scale_factors), reference.estimate(scale_factors)
        assert want.determined and got.determined
        np.testing.assert_allclose(got.values, want.values, rtol=1e-12, err_msg=f"resumed at epoch {cut}")
        np.testing.assert_allclose(got.covariance, want.covariance, rtol=1e-12,
                                   atol=1e-12 * np.abs(want.covariance).max())


def _nested_gap_over_bound(got, want):
    """|G - G_complete| / bound per parameter, the fault matrix's bound: 1 sigma of the complete record's
    estimate, or 3 standard deviations of the difference of nested estimates if larger."""
    bound = np.maximum(want.sigma, 3.0 * np.sqrt(np.maximum(got.sigma**2 - want.sigma**2, 0.0)))
    return np.abs(got.values - want.values) / bound


def test_data_lost_across_a_torque_switch_leave_g_unbiased(run):
    _, out, instrument, switches, reference = run
    want = reference.estimate()
    s = int(switches[np.searchsorted(switches, 2750)])  # the fault matrix's failure: 9.9 s lost at t = 275 s
    for start, lost in ((2750, 99), (s - 1, 2), (s - 15, 30)):
        assert start < s < start + lost + 1  # the switch is inside the gap (or is its end)
        est = ScaleFactorEstimator(instrument)
        _feed(est, out, range(start))
        est = _restored(est, ScaleFactorEstimator, instrument)  # killed at the checkpoint, restarted
        _feed(est, out, range(start + lost, len(out)))
        # measured: 0.21, 0.03 and 0.13 at most (sigma of G_Ppsi 10 %, 1.7 % and 10 % above the complete
        # record's); before the fix (the held input across the switch, as if none happened):
        # 2.6, 0.24 and 2.1
        gap = _nested_gap_over_bound(est.estimate(), want)
        assert np.all(gap < 1.0), (start, lost, gap)


def test_data_lost_within_one_torque_are_bridged(run):
    _, out, instrument, switches, reference = run
    want = reference.estimate()
    s = int(switches[np.searchsorted(switches, 3000)])
    for start, lost in ((s + 5, 99), (s + 100, 2)):
        est = ScaleFactorEstimator(instrument)
        _feed(est, out, range(start))
        _feed(est, out, range(start + lost, len(out)))
        assert est.filter.n_segments == 1, (start, lost)
        gap = _nested_gap_over_bound(est.estimate(), want)
        assert np.all(gap < 1.0), (start, lost, gap)


def test_bulk_path_starts_the_same_segments_as_the_node_path(run):
    _, out, instrument, switches, _ = run
    s = int(switches[np.searchsorted(switches, 2750)])
    keep = np.ones(len(out), dtype=bool)
    keep[2750:2849] = False  # across the switch at s
    keep[s + 300:s + 302] = False  # within one torque
    keep[s + 400:s + 420] = False  # ... whose next epoch has no GRS sample: a new segment
    volts = out.voltages_v.copy()
    volts[s + 420] = np.nan
    rows = np.flatnonzero(keep)
    node = ScaleFactorEstimator(instrument)
    for k in rows:
        node.update(out.t_s[k], out.st_quat_xyzw[k], {g: volts[k, g - 1] for g in (1, 2) if k != s + 420})
    bulk_est = ScaleFactorEstimator(instrument)
    bulk = bulk_est.process_batch(out.t_s[rows], out.st_quat_xyzw[rows], volts[rows])
    assert node.filter.n_segments == bulk_est.filter.n_segments == 2
    got = node.estimate()
    # the two paths' rounding (test_bulk_irregular.py): 1e-6 sigma
    assert np.all(np.abs(got.values - bulk.values) < 1e-6 * bulk.sigma)
