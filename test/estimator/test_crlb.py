"""Cramer-Rao bounds: scaling with duration, independent frequency-domain check, reference values."""

import numpy as np
import pytest

from taiji2_apps.layout_bound import crlb_for_layout, noise_free_signals
from taiji2_estimator_pkg.core.crlb import crlb, whittle_scale_factor_information
from taiji2_estimator_pkg.core.instrument import InstrumentModel

pytest.importorskip("taiji2_sim_pkg.core.simulator")


def test_bound_scales_as_inverse_sqrt_duration():
    # 30 min vs 2 h (both whole numbers of 250 s periods... within 10 %: edge effects, nuisances)
    short = crlb_for_layout("type1", 1750.0)
    long = crlb_for_layout("type1", 7000.0)
    np.testing.assert_allclose(short.scale_factor_sigma / long.scale_factor_sigma, 2.0, rtol=0.1)
    np.testing.assert_allclose(short.com_offset_sigma / long.com_offset_sigma, 2.0, rtol=0.1)
    np.testing.assert_allclose(short.difference_sigma(True) / long.difference_sigma(True), 2.0, rtol=0.1)


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_time_domain_bound_agrees_with_whittle(layout):
    # independent frequency-domain computation of the single-GRS scale-factor information: 3 %
    from taiji2_model.config import load_config

    t, omega_dot, omega, config = noise_free_signals(layout, 3500.0)
    instrument = InstrumentModel.from_layout(load_config(layout))  # nominal noise budget
    sensor = config.grs.sensors[0]
    bound = crlb(instrument, t, omega_dot, omega, (1,), {1: sensor.angular_scale_factors},
                 {1: sensor.com_offset_m})
    whittle = whittle_scale_factor_information(instrument, omega_dot, 1, sensor.angular_scale_factors)
    np.testing.assert_allclose(bound.scale_factor_sigma, np.sqrt(np.diag(np.linalg.inv(whittle))), rtol=0.03)


@pytest.mark.slow
def test_reference_values_type1_3h():
    # physics.md (independent implementation, 3 h): G 0.04-0.09 %; d 80-150 um with thruster force
    # noise; d1 - d2 5-10 um if G exact (tens of um in practice). Tolerance: those ranges widened
    # by 25 %.
    bound = crlb_for_layout("type1", 10800.0)
    assert np.all((bound.scale_factor_relative_sigma > 0.03e-2) & (bound.scale_factor_relative_sigma < 0.11e-2))
    assert np.all((bound.com_offset_sigma > 60e-6) & (bound.com_offset_sigma < 190e-6))
    assert np.all((bound.difference_sigma(True) > 4e-6) & (bound.difference_sigma(True) < 13e-6))
    assert np.all(bound.difference_sigma() >= bound.difference_sigma(True))
    assert np.max(bound.difference_sigma()) > 20e-6  # differential scale-factor errors dominate
    # the joint bound is sharper than the single-GRS one (the GRS-pair readout difference)
    single = crlb_for_layout("type1", 10800.0, grs_ids=(1,))
    assert np.all(bound.scale_factor_sigma[:3] < single.scale_factor_sigma)


def _noise_free_offsets(layout: str, duration_s: float):
    """The c.m.-offset estimator run on noise-free signals (as crlb does) and the G-stage bound."""
    from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator, ComOffsetOptions
    from taiji2_estimator_pkg.core.crlb import noise_free_voltages
    from taiji2_estimator_pkg.core.validation import ValidationOptions

    t, omega_dot, omega, config = noise_free_signals(layout, duration_s)
    from taiji2_model.config import load_config

    instrument = InstrumentModel.from_layout(load_config(layout))
    sensors = {s.grs_id: s for s in config.grs.sensors}
    g = {k: sensors[k].angular_scale_factors for k in (1, 2)}
    d = {k: sensors[k].com_offset_m for k in (1, 2)}
    bound = crlb(instrument, t, omega_dot, omega, (1, 2), g, d)
    volts = noise_free_voltages(instrument, omega_dot, omega, (1, 2), g, d)
    options = ComOffsetOptions(gate_probability=None, adapt_noise=False,
                               validation=ValidationOptions(saturation_v=None, max_rate_rad_s=1e9))
    co = ComOffsetEstimator(instrument, (1, 2), options)
    co.process_batch(t, volts, omega, (bound.scale_factors, bound.scale_factor_covariance))
    co.eiv_sum[:] = 0.0
    return co, bound


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_full_bound_lies_between_g_exact_and_two_stage(layout):
    # the joint information adds the linear channels' information on G to the two-stage problem and
    # is the G-exact problem with the G stage's information as a prior: cov ordering in the PSD sense,
    # checked scale-free (whitened by the larger covariance; rounding of the inversions: 1e-6)
    bound = crlb_for_layout(layout, 1750.0)
    full, two, exact = (bound.com_offset_covariance, bound.com_offset_covariance_two_stage,
                        bound.com_offset_covariance_given_scale_factors)

    def smallest_whitened(larger, smaller):
        root = np.linalg.inv(np.linalg.cholesky(larger))
        return np.min(np.linalg.eigvalsh(root @ (larger - smaller) @ root.T))

    assert smallest_whitened(two, full) > -1e-6
    assert smallest_whitened(full, exact) > -1e-6
    # and it is a real gain where G matters: Type-1 d_x, Type-2 d_x by more than 5 %
    assert bound.com_offset_sigma[0] < 0.95 * bound.com_offset_sigma_two_stage[0]
    assert np.all(np.diag(bound.scale_factor_covariance_full) <= np.diag(bound.scale_factor_covariance))


def test_full_bound_tends_to_g_exact_when_g_is_known():
    # limit where they must agree: G stage information x 1e8 -> the joint bound on d is the G-exact one
    # (to 1e-6 relative: the prior's part of the covariance scales as 1e-8)
    from taiji2_estimator_pkg.core.com_offset.joint import joint_information
    from taiji2_estimator_pkg.core.twostage import solve_information

    co, bound = _noise_free_offsets("type2", 1750.0)
    g_true = bound.scale_factors
    beta, _, _ = co.solve(g_true)
    prior = np.linalg.inv(bound.scale_factor_covariance) * 1e8
    hessian, score, _ = joint_information(co.model, co.corrected_information(), g_true, beta, prior)
    _, cov, _ = solve_information(hessian, np.zeros(hessian.shape[0]))
    n_g = g_true.size
    np.testing.assert_allclose(np.diag(cov)[n_g:n_g + 6], np.diag(bound.com_offset_covariance_given_scale_factors),
                               rtol=1e-6)
    # noise-free signals at the truth: the score vanishes (the mean Jacobian is the data's own)
    assert np.all(np.abs(score) <= 1e-3 * np.sqrt(np.diag(hessian)))  # a shift below 1e-3 sigma
