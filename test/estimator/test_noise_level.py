"""The c.m.-offset estimator measures the noise of the linear channels in the band that carries d.

Seeded 1-h Type-1 records. With the thruster force noise at 2x PSD in the data and the nominal
budget in the model, the band NIS is ~1.6-1.9 (the common spacecraft acceleration is most, not all,
of the linear channels' noise): far outside the scatter of the band covariance (5 sigma =
5 sqrt(2/360) = 0.37 for 360 blocks), so R is adjusted and the reported sigma of the common part of
d grows by ~sqrt(2). With the nominal budget in both, nothing changes.
"""

import numpy as np
import pytest

from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.noise_level import band_noise
from taiji2_estimator_pkg.core.pipeline import calibrate

from estimator_support import simulate

NOMINAL_FORCE_ASD = 1.0e-7


def _calibrate(seed: int, force_asd: float):
    _, out = simulate("type1", 3600.0, seed, noise__thruster_force__asd_n_rthz=force_asd)
    model, _ = simulate("type1", 3600.0, seed)  # the nominal budget (same seed: same cache entry)
    return calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, InstrumentModel.from_layout(model))


@pytest.mark.parametrize("seed", [301, 302])
def test_nominal_noise_is_left_as_it_is(seed):
    d = _calibrate(seed, NOMINAL_FORCE_ASD).com_offsets
    assert not d.noise_adjusted
    assert abs(d.nis_band - 1.0) < 0.37


@pytest.mark.parametrize("seed", [301, 302])
def test_doubled_force_noise_is_measured_and_followed(seed):
    nominal = _calibrate(seed, NOMINAL_FORCE_ASD).com_offsets
    doubled = _calibrate(seed, NOMINAL_FORCE_ASD * np.sqrt(2.0)).com_offsets
    assert doubled.noise_adjusted
    assert 1.37 < doubled.nis_band < 2.4
    # d_z of Type-1 is limited by the common acceleration alone: its sigma follows sqrt(2) within 15 %
    ratio = doubled.sigma / nominal.sigma
    assert 1.2 < ratio[2] < 1.6 and 1.2 < ratio[5] < 1.6


def test_band_covariance_of_white_unit_noise_is_the_identity():
    # 2000 blocks of 100 white unit samples in 6 channels: C_band = I within 5 sqrt(2/2000) = 0.16
    rng = np.random.default_rng(5)
    result = band_noise(rng.standard_normal((200_000, 6)), 100)
    assert result is not None and not result.significant
    assert np.max(np.abs(np.linalg.eigvalsh(result.covariance) - 1.0)) < 0.16
    # the same noise at 1.5x amplitude in one channel (2.25x PSD) is significant
    noise = rng.standard_normal((200_000, 6))
    noise[:, 2] *= 1.5
    assert band_noise(noise, 100).significant
