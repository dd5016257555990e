"""The angular acceleration no GRS measured: the gap weights, the noise model's extra source, the doubt rows."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis.angular_gaps import angular_gap_weight
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.spectral import NoiseSpectrum
from taiji2_model.config import load_config

N = 40


def _lost(*spans):
    received = np.ones(N, dtype=bool)
    for start, stop in spans:
        received[start:stop] = False
    return received


def test_one_and_five_epochs_lost_by_both_grs_weigh_one_and_a_half_and_three_and_a_half():
    one = angular_gap_weight(_lost((10, 11)), _lost((10, 11)), np.ones(N, dtype=bool))
    assert one[10] == 1.5 and np.count_nonzero(one) == 1
    five = angular_gap_weight(_lost((20, 25)), _lost((20, 25)), np.ones(N, dtype=bool))
    # (k + (k/2)^2 + (k/2)^2) / k = (5 + 6.25 + 6.25) / 5
    np.testing.assert_allclose(five[20:25], 3.5, rtol=1e-15)
    assert np.count_nonzero(five) == 5


def test_an_epoch_one_grs_measured_weighs_nothing_and_a_partial_overlap_uses_grs1s_own_gap():
    assert not np.any(angular_gap_weight(_lost((10, 15)), np.ones(N, dtype=bool), np.ones(N, dtype=bool)))
    assert not np.any(angular_gap_weight(np.ones(N, dtype=bool), _lost((10, 15)), np.ones(N, dtype=bool)))
    # GRS1 lost 10..14 (interpolated from 9 to 15), GRS2 lost 12..13: s = 3/6, 4/6 on the two unmeasured epochs
    weight = angular_gap_weight(_lost((10, 15)), _lost((12, 14)), np.ones(N, dtype=bool))
    s = np.array([3.0, 4.0]) / 6.0
    np.testing.assert_allclose(weight[12:14], (2 + np.sum(1 - s) ** 2 + np.sum(s) ** 2) / 2, rtol=1e-15)
    assert np.count_nonzero(weight) == 2
    # a gap the bridge did not fill (too long, or at an end) weighs nothing
    assert not np.any(angular_gap_weight(_lost((10, 15)), _lost((10, 15)), _lost((10, 15))))


def test_the_weight_is_the_variance_of_what_linear_interpolation_leaves_of_white_noise():
    """Seeded: 20,000 gaps of 1 to 8 epochs in white noise of unit variance; the sum of the interpolation's
    error over each gap has the variance the weights sum to, within 4 standard errors of a variance."""
    rng = np.random.default_rng(4)
    lengths = rng.integers(1, 9, size=20000)
    sums, predicted = [], []
    for k in (int(v) for v in lengths):
        x = rng.standard_normal(k + 2)  # the sample before, the k lost, the sample after
        s = np.arange(1, k + 1) / (k + 1)
        sums.append(np.sum(x[1:-1] - (1 - s) * x[0] - s * x[-1]))
        received = np.ones(k + 2, dtype=bool)
        received[1:-1] = False
        predicted.append(np.sum(angular_gap_weight(received, received, np.ones(k + 2, dtype=bool))))
    ratio = np.asarray(sums) ** 2 / np.asarray(predicted)  # unit-mean chi-square(1) per gap
    assert abs(np.mean(ratio) - 1.0) < 4.0 * np.sqrt(2.0 / ratio.size)


def test_the_extra_source_adds_to_the_star_tracker_and_torque_channels_only_and_nothing_without_loss():
    model = NominalModel.from_config(load_config("type1"))
    bins = np.array([1, 10, 1000])
    plain = NoiseSpectrum(model, model.com_offset_m, 10000).matrices(bins)
    none = NoiseSpectrum(model, model.com_offset_m, 10000, (0.0, np.zeros((3, 3)))).matrices(bins)
    assert np.array_equal(plain, none)  # bit for bit: a record without such gaps is unchanged
    weight = 0.1
    extra = NoiseSpectrum(model, model.com_offset_m, 10000, (weight, np.zeros((3, 3)))).matrices(bins) - plain
    white = plain[0, 3:6, 3:6].real  # the torque channel's white covariance C
    np.testing.assert_allclose(extra[:, 3:6, 3:6].real, np.broadcast_to(weight * white, (3, 3, 3)),
                               rtol=1e-9, atol=1e-12 * np.max(np.abs(white)))
    assert np.max(np.abs(extra[:, 6:15, 6:15])) == 0.0  # ang_diff, lin_common, lin_diff: untouched
    assert np.all(np.diagonal(extra[:, 0:3, 0:3].real, axis1=1, axis2=2) > 0.0)
    # a doubted command step: rank one along J^-1 step
    step = np.array([0.0, 0.0, 2.6e-5])
    doubt = NoiseSpectrum(model, model.com_offset_m, 10000, (0.0, np.outer(step, step))).matrices(bins) - plain
    direction = model.inertia_inv @ step
    np.testing.assert_allclose(doubt[0, 3:6, 3:6].real, np.outer(direction, direction), rtol=1e-9,
                               atol=1e-12 * float(direction @ direction))


def test_the_doubt_rows_follow_a_slice_of_the_record():
    n = 100
    doubt = np.array([[10.0, 0.0, 0.0, 1e-5, 2.0], [60.0, 1e-6, 0.0, 0.0, 0.5]])
    inp = DiagnosisInput(np.arange(n) * 0.1, np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 2, 6)),
                         np.zeros((n, 3)), 10.0, angular_gap_weight=np.full(n, 0.5), command_doubt=doubt)
    weight, torque = inp.angular_loss
    assert weight == 0.5
    np.testing.assert_allclose(torque, (2.0 * np.outer(doubt[0, 1:4], doubt[0, 1:4])
                                        + 0.5 * np.outer(doubt[1, 1:4], doubt[1, 1:4])) / n, rtol=1e-15)
    late = inp.slice(50, 100)
    np.testing.assert_array_equal(late.command_doubt, [[10.0, 1e-6, 0.0, 0.0, 0.5]])
    assert inp.slice(0, 5).command_doubt is None and late.angular_gap_weight.shape == (50,)
