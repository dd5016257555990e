"""c.m.-offset estimators: recursive == bulk, node-like pipeline, checkpoints, paper filter."""

import json

import numpy as np
import pytest

from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator, PaperComOffsetFilter
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.pipeline import calibrate
from taiji2_estimator_pkg.core.scale_factor import PaperScaleFactorFilter, ScaleFactorEstimator

from estimator_support import simulate, truth


def _run_per_sample(co, out, omega, scale_factors, rows=slice(None)):
    reports = []
    for k in range(len(out))[rows]:
        reports.append(co.update(out.t_s[k], {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]}, omega[k],
                                 scale_factors))
    return reports


def test_recursive_equals_bulk_for_given_rate_and_scale_factors():
    # same inputs (omega, G): the two paths differ only by summation order, so the difference is a
    # rounding error; 1e-5 sigma bounds it with a wide margin on any CPU and BLAS (measured here
    # ~1e-8 sigma) while any modelling difference would show at the sigma level
    config, out = simulate("type2", 1200.0, 21)
    instrument = InstrumentModel.from_layout(config)
    g_true, d_true = truth(config)
    scale_factors = (g_true * (1 + 3e-4), np.diag((5e-4 * g_true) ** 2))
    omega = out.truth.omega_rad_s
    bulk = ComOffsetEstimator(instrument).process_batch(out.t_s, out.voltages_v, omega, scale_factors)
    co = ComOffsetEstimator(instrument)
    reports = _run_per_sample(co, out, omega, scale_factors)
    rec = co.estimate(scale_factors)
    assert bulk.determined and rec.determined
    assert np.all(np.abs(rec.values - bulk.values) < 1e-5 * bulk.sigma)
    # each element relative to sqrt(C_ii C_jj): a small off-diagonal element carries the rounding of
    # the large ones it is the difference of (the joint solution inverts a 33 x 33 information)
    scale = np.sqrt(np.outer(np.diag(bulk.covariance), np.diag(bulk.covariance)))
    assert np.max(np.abs(rec.covariance - bulk.covariance) / scale) < 1e-6
    nis = np.array([r.nis for r in reports])
    assert 0.9 < np.nanmean(nis[len(nis) // 2:]) / 6.0 < 1.1
    # scale-factor uncertainty is propagated: total covariance exceeds the G-exact one
    assert np.all(np.diag(rec.covariance) > np.diag(rec.covariance_given_scale_factors))
    diff, diff_cov = rec.difference()
    assert np.all(np.abs(diff - (d_true[:3] - d_true[3:])) < 5 * np.sqrt(np.diag(diff_cov)))


# 34-60 s of CI (an 1800-s record fed sample by sample); left out of the README test command for CI time
# (pytest -m long): test/nodes/test_live_vs_offline.py checks the node path against offline on its own graph
@pytest.mark.long
def test_node_like_pipeline_agrees_with_offline_calibration():
    # a node follows the running G and filtered omega; offline uses the final ones: within 0.1 sigma
    config, out = simulate("type1", 1800.0, 22)
    instrument = InstrumentModel.from_layout(config)
    offline = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, instrument)
    sf = ScaleFactorEstimator(instrument)
    co = ComOffsetEstimator(instrument)
    for k in range(len(out)):
        volts = {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]}
        sf.update(out.t_s[k], out.st_quat_xyzw[k], volts)
        g = sf.estimate() if k % 50 == 0 else None  # a node sees G at its publication rate
        co.update(out.t_s[k], volts, sf.rate_estimate(), g)
    final_g = sf.estimate()
    np.testing.assert_allclose(final_g.values, offline.scale_factors.values, rtol=1e-9)
    node_d = co.estimate(final_g)
    assert np.all(np.abs(node_d.values - offline.com_offsets.values) < 0.1 * offline.com_offsets.sigma)


def test_checkpoint_resume_mid_run():
    config, out = simulate("type1", 600.0, 23)
    instrument = InstrumentModel.from_layout(config)
    g_true, _ = truth(config)
    scale_factors = (g_true, np.diag((5e-4 * g_true) ** 2))
    omega = out.truth.omega_rad_s
    full = ComOffsetEstimator(instrument)
    _run_per_sample(full, out, omega, None)
    first = ComOffsetEstimator(instrument)
    _run_per_sample(first, out, omega, None, slice(0, 3000))
    resumed = ComOffsetEstimator.from_state_dict(instrument, json.loads(json.dumps(first.state_dict())))
    _run_per_sample(resumed, out, omega, None, slice(3000, None))
    np.testing.assert_allclose(resumed.estimate(scale_factors).values, full.estimate(scale_factors).values,
                               rtol=1e-12)


def test_bad_voltages_rejected_estimate_continues():
    config, out = simulate("type1", 900.0, 24)
    instrument = InstrumentModel.from_layout(config)
    g_true, _ = truth(config)
    scale_factors = (g_true, np.diag((5e-4 * g_true) ** 2))
    volts = out.voltages_v.copy()
    volts[1000, 0, 2] = np.nan
    volts[2000:2010, 1] = np.inf
    volts[3000, 0, 0] = 50.0  # saturated
    clean = ComOffsetEstimator(instrument).process_batch(out.t_s, out.voltages_v, out.truth.omega_rad_s,
                                                         scale_factors)
    dirty = ComOffsetEstimator(instrument).process_batch(out.t_s, volts, out.truth.omega_rad_s, scale_factors)
    assert dirty.rejected["grs1"] == {"nan_or_inf": 1, "saturated": 1}
    assert dirty.rejected["grs2"] == {"nan_or_inf": 10}
    assert dirty.determined
    assert np.all(np.abs(dirty.values - clean.values) < 0.1 * clean.sigma)


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_paper_filter_ballpark(layout):
    # Thruster force off, 3 h, 2 seeds. The paper claims < 100 um; the literal filter with the
    # star-tracker angular acceleration in A~ is limited by that regressor's noise (errors-in-
    # variables attenuation ~ (sigma_omega_dot / A)^2 |d| plus its correlated noise), 100-250 um
    # here: asserted < 400 um (same order as the paper), and its sigma far too small (> 5 x).
    errors, sigmas = [], []
    for seed in (31, 32):
        config, out = simulate(layout, 10800.0, seed, noise__thruster_force__enabled=False)
        _, d_true = truth(config)
        instrument = InstrumentModel.from_layout(config)
        g = PaperScaleFactorFilter(instrument).process_batch(out.t_s, out.st_quat_xyzw, out.voltages_v)
        d = PaperComOffsetFilter(instrument).process_batch(out.t_s, out.st_quat_xyzw, out.voltages_v, g)
        errors.append(d.values - d_true)
        sigmas.append(d.sigma)
    errors, sigmas = np.array(errors), np.array(sigmas)
    assert np.max(np.abs(errors)) < 400e-6
    assert np.all(np.sqrt(np.mean(errors**2, axis=0)) / np.mean(sigmas, axis=0) > 5.0)
