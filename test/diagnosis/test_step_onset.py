"""A step-onset signature from one build (:mod:`.step_onset`) equals the build at each onset."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.diagnosis import NominalModel, candidate_catalog, prepare_input
from taiji2_estimator_pkg.diagnosis.candidates import CandidateContext
from taiji2_estimator_pkg.diagnosis.channels import linearize, readouts_from_input
from taiji2_estimator_pkg.diagnosis.record import column_fft
from taiji2_estimator_pkg.diagnosis.step_onset import step_pieces
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

N_SAMPLES = 6000  # 10 min at 10 Hz
K_MAX = 120  # bins 1..120: up to 0.2 Hz


@pytest.fixture(scope="module")
def context():
    config = load_config("type1")
    commands = maneuver_torque_commands(config, N_SAMPLES)
    out = simulate_batch(config, 5, commands)
    inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)
    model = NominalModel.from_config(config)
    readouts = readouts_from_input(inp, model)
    lin = linearize(readouts, model, model.g_angular, model.com_offset_m)
    return CandidateContext(lin, readouts, model, 86164.1, 0.01, 0.7, float(np.median(readouts.t_s)))


def test_every_step_variant_from_one_build_equals_its_build_at_each_onset(context):
    """Onsets at the first samples, between samples, inside and at the last sample: the columns agree to
    rounding (relative to the column's largest entry), for every variant built from plain changes."""
    t = context.readouts.t_s
    onsets = [t[0], t[1], t[2] - 0.03, t[3], 0.5 * (t[100] + t[101]), t[3000], t[-2], t[-1]]
    covered = set()
    for candidate in candidate_catalog()[0]:
        pieces = step_pieces(candidate, context)
        if pieces is None:
            assert candidate.onset_kind != "step" or candidate.exact is not None or candidate.series is not None
            continue
        covered.add(candidate.name)
        for onset in onsets:
            built = candidate.build(context.at_onset("step", float(onset)))
            columns = pieces.columns_at(float(onset))
            spectra = pieces.ffts_at(float(onset), K_MAX)
            for fast, spectrum, direct in zip(columns, spectra, built, strict=True):
                scale = max(float(np.max(np.abs(direct))), 1e-300)
                np.testing.assert_allclose(fast, direct, rtol=0.0, atol=1e-12 * scale,
                                           err_msg=f"{candidate.key} from {onset} s")
                expected = column_fft(direct, K_MAX)
                np.testing.assert_allclose(spectrum, expected, rtol=0.0,
                                           atol=1e-12 * max(float(np.max(np.abs(expected))), 1e-300),
                                           err_msg=f"{candidate.key} from {onset} s, DFT")
    assert {"cross_coupling", "thruster_torque_gain", "gravity_gradient", "inertia_error", "tm_stiffness",
            "thruster_force_leakage", "time_offset"} <= covered


def test_a_relinearised_series_signature_from_one_build_equals_its_build_at_each_onset(context):
    """The nonlinearity relinearised at a k (its column a weighted sum of its series terms, each one change):
    the pieces of that sum give its columns at every onset, to rounding; a timing (knot) signature has none."""
    t = context.readouts.t_s
    onsets = [t[0], t[2] - 0.03, 0.5 * (t[100] + t[101]), t[3000], t[-1]]
    catalog = {c.key: c for c in candidate_catalog()[0]}
    for key, k in (("readout_nonlinearity[grs1.z]", 2e6), ("readout_nonlinearity[grs2.phi]", -3e6)):
        candidate = catalog[key]
        weights = candidate.coefficients(k) / k  # the secant's weights (Record.relinearise)
        pieces = step_pieces(candidate, context, weights)
        assert pieces is not None
        for onset in onsets:
            direct = candidate.series_sum(context.at_onset("step", float(onset)), weights)
            (fast,) = pieces.columns_at(float(onset))
            np.testing.assert_allclose(fast, direct, rtol=0.0, atol=1e-12 * float(np.max(np.abs(direct))),
                                       err_msg=f"{key} from {onset} s")
    delay = catalog["grs_time_offset"]
    assert step_pieces(delay, context, np.ones(len(delay.coefficients(0.01)))) is None


def test_the_nonlinearity_series_in_one_build_equals_the_sum_of_its_terms(context):
    """``series_sum`` builds the nonlinearity's weighted series in one perturbation (P linear): it equals the
    weighted sum of the terms built one by one, to rounding, from small k to the series bound, from the start
    and from an onset."""
    catalog = {c.key: c for c in candidate_catalog()[0]}
    t = context.readouts.t_s
    for key in ("readout_nonlinearity[grs1.z]", "readout_nonlinearity[grs2.phi]", "readout_nonlinearity[grs1.psi]"):
        candidate = catalog[key]
        assert candidate.series_weighted is not None
        bound = candidate.bound(context)
        for k in (1e-3 * bound, -0.5 * bound, bound):
            weights = candidate.coefficients(k)
            for ctx in (context, context.at_onset("step", float(t[2500]))):
                fast = candidate.series_sum(ctx, weights)
                terms = sum(w * candidate.series_term(ctx, j) for j, w in enumerate(weights))
                np.testing.assert_allclose(fast, terms, rtol=0.0, atol=1e-12 * float(np.max(np.abs(terms))),
                                           err_msg=f"{key} at k = {k:g}")
