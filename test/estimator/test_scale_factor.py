"""Scale-factor estimators: paper filter ballpark and dishonesty, recursive == bulk, checkpoints, gating."""

import json

import numpy as np
import pytest

from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.scale_factor import PaperScaleFactorFilter, ScaleFactorEstimator

from estimator_support import simulate, truth


def _per_sample(est, out, rows=slice(None), columns=(0, 1)):
    reports = []
    for k in range(len(out))[rows]:
        volts = {g: out.voltages_v[k, c] for g, c in zip(est.grs_ids, columns, strict=True)}
        reports.append(est.update(out.t_s[k], out.st_quat_xyzw[k], volts))
    return reports


@pytest.mark.parametrize("grs_ids", [(1, 2), pytest.param((2,), marks=pytest.mark.long)])  # one GRS: long (CI time)
def test_recursive_equals_bulk(grs_ids):
    # tolerance: 1e-9 relative on G (rounding of different summation orders)
    config, out = simulate("type1", 1200.0, 7)
    instrument = InstrumentModel.from_layout(config)
    columns = tuple(g - 1 for g in grs_ids)
    bulk = ScaleFactorEstimator(instrument, grs_ids).process_batch(out.t_s, out.st_quat_xyzw,
                                                                   out.voltages_v[:, list(columns)])
    est = ScaleFactorEstimator(instrument, grs_ids)
    reports = _per_sample(est, out, columns=columns)
    rec = est.estimate()
    assert bulk.determined and rec.determined
    np.testing.assert_allclose(rec.values, bulk.values, rtol=1e-9)
    np.testing.assert_allclose(rec.covariance, bulk.covariance, rtol=1e-9, atol=1e-9 * np.max(bulk.covariance))
    # every update reports its NIS once determined; consistent filter: mean NIS / dof near 1
    nis = np.array([r.nis for r in reports])
    assert np.isfinite(nis[-1])
    assert 0.9 < np.nanmean(nis[len(nis) // 2:]) / 3.0 < 1.1
    assert 0.95 < bulk.nis_mean < 1.05


@pytest.mark.long  # CI time (14 s): test_restart_exact.py restores a checkpoint exactly in CI
def test_checkpoint_resume_mid_run():
    config, out = simulate("type1", 900.0, 8)
    instrument = InstrumentModel.from_layout(config)
    uninterrupted = ScaleFactorEstimator(instrument)
    _per_sample(uninterrupted, out)
    first = ScaleFactorEstimator(instrument)
    _per_sample(first, out, slice(0, 4000))
    state = json.loads(json.dumps(first.state_dict()))  # what a node writes to disk
    resumed = ScaleFactorEstimator.from_state_dict(instrument, state)
    _per_sample(resumed, out, slice(4000, None))
    np.testing.assert_allclose(resumed.estimate().values, uninterrupted.estimate().values, rtol=1e-12)
    np.testing.assert_allclose(resumed.rate_estimate(), uninterrupted.rate_estimate(), rtol=1e-9, atol=1e-15)


def test_gross_star_tracker_outlier_is_gated_and_counted():
    config, out = simulate("type1", 1200.0, 9)
    instrument = InstrumentModel.from_layout(config)
    clean = ScaleFactorEstimator(instrument).process_batch(out.t_s, out.st_quat_xyzw, out.voltages_v)
    quats = out.st_quat_xyzw.copy()
    k = 9000
    bump = np.array([np.sin(2.5e-5), 0.0, 0.0, np.cos(2.5e-5)])  # 50 microrad: passes the jump check
    x, y, z, w = quats[k]
    bx, by, bz, bw = bump
    quats[k] = [w * bx + x * bw + y * bz - z * by, w * by - x * bz + y * bw + z * bx,
                w * bz + x * by - y * bx + z * bw, w * bw - x * bx - y * by - z * bz]
    bulk = ScaleFactorEstimator(instrument).process_batch(out.t_s, quats, out.voltages_v)
    assert bulk.rejected["star_tracker"]["gated"] >= 1
    assert np.all(np.abs(bulk.values - clean.values) < 0.05 * clean.sigma)
    est = ScaleFactorEstimator(instrument)
    for j in range(len(out)):
        report = est.update(out.t_s[j], quats[j], {1: out.voltages_v[j, 0], 2: out.voltages_v[j, 1]})
        if j == k:
            assert not report.accepted and ("star_tracker", "gated") in report.rejections
    assert est.estimate().rejected["star_tracker"]["gated"] >= 1
    assert np.all(np.abs(est.estimate().values - clean.values) < 0.05 * clean.sigma)


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_paper_filter_ballpark_and_dishonest_covariance(layout):
    # the paper's method, thruster force off, 3 h, 3 seeds: errors < 0.2 % (paper's claim) and a
    # reported sigma far too small (physics.md: 17-36 x; asserted > 5 x on the rms error)
    errors, sigmas = [], []
    for seed in (11, 12, 13):
        config, out = simulate(layout, 10800.0, seed, noise__thruster_force__enabled=False)
        g_true, _ = truth(config)
        estimate = PaperScaleFactorFilter(InstrumentModel.from_layout(config)).process_batch(
            out.t_s, out.st_quat_xyzw, out.voltages_v)
        errors.append((estimate.values - g_true) / g_true)
        sigmas.append(estimate.sigma / g_true)
    errors, sigmas = np.array(errors), np.array(sigmas)
    assert np.max(np.abs(errors)) < 2e-3
    ratio = np.sqrt(np.mean(errors**2, axis=0)) / np.mean(sigmas, axis=0)
    assert np.all(ratio > 5.0), ratio


def test_paper_filter_recursive_equals_bulk():
    config, out = simulate("type2", 600.0, 3)
    instrument = InstrumentModel.from_layout(config)
    from taiji2_estimator_pkg.core.scale_factor import PaperScaleFactorOptions

    options = PaperScaleFactorOptions(window=201)
    bulk = PaperScaleFactorFilter(instrument, (1, 2), options).process_batch(out.t_s, out.st_quat_xyzw,
                                                                             out.voltages_v)
    rec = PaperScaleFactorFilter(instrument, (1, 2), options)
    for k in range(len(out)):
        rec.update(out.t_s[k], out.st_quat_xyzw[k], {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]})
    est = rec.estimate()
    assert est.n_samples == bulk.n_samples == len(out) - 200
    np.testing.assert_allclose(est.values, bulk.values, rtol=1e-9)
    np.testing.assert_allclose(est.covariance, bulk.covariance, rtol=1e-7, atol=1e-9 * np.max(bulk.covariance))


def test_bulk_input_forms_equal_the_per_step_regressor():
    """The bulk paths' factored input regressors and their products with G (``U g``, ``D g``) equal
    the per-step regressors (to rounding: a few ulps of values of order 1)."""
    estimator = ScaleFactorEstimator(InstrumentModel.from_layout("type1"), (1, 2))
    model = estimator.model
    rng = np.random.default_rng(8)
    diffs = rng.normal(size=(50, 2, 3))
    g = rng.normal(size=6)
    dense = model.input_regressor_factors(diffs).dense()
    for k in range(diffs.shape[0]):
        per_step = model.input_regressor({1: diffs[k, 0], 2: diffs[k, 1]}, (1, 2))
        np.testing.assert_allclose(dense[k], per_step, rtol=0, atol=1e-14 * np.abs(per_step).max())
        np.testing.assert_allclose(model.input_batch(diffs, g)[k], per_step @ g, rtol=1e-12, atol=1e-14)
        row = model.difference_row(diffs[k, 0], diffs[k, 1])
        np.testing.assert_allclose(model.difference_residual(diffs, g)[k], row @ g, rtol=1e-12, atol=1e-14)
