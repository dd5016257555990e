"""Welch PSD of every simulated noise source against its specified one-sided ASD.

Method: Welch (Hann window, 50 % overlap) of each channel; the ratio estimate/specification is
averaged over bins in log-spaced bands (and over channels with the same specification). Each band
ratio is a scaled chi-square variable with Satterthwaite-equivalent degrees of freedom
nu = (2 K / 1.056) * channels * M / (1 + 2 (1 - 1/M) 4/9 + 2 (1 - 2/M) 1/36) for K segments and M
bins (1.056: 50 %-overlap Hann segment correlation; 4/9 and 1/36: Hann correlation of neighbouring
bins). Tolerance: every band ratio inside its two-sided chi-square interval at a family-wise
false-alarm probability of 1e-3 (Bonferroni over all bands of a test). Runs are seeded.
"""

import itertools
from dataclasses import fields

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.signal import welch
from scipy.stats import chi2

from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
from taiji2_model.grs import voltages_from_accelerations
from taiji2_model.noise import NoiseStreams
from taiji2_sim_pkg.core.simulator import simulate_batch
from taiji2_sim_pkg.core.star_tracker import attitude_error_rad

FAMILY_ALPHA = 1e-3
SEED = 8675309
N_WHITE = 2**16  # 1.8 h at 10 Hz
NPERSEG_WHITE = 2**11


def band_ratios(x, fs, nperseg, expected_psd, f_lo, f_hi, n_bands):
    """Band-averaged Welch/expected ratios and their degrees of freedom.

    x: (n, m) channels; expected_psd(f) -> (nf, m) or (nf, 1) one-sided PSD.
    """
    x = np.asarray(x).reshape(x.shape[0], -1)
    f, p = welch(x, fs=fs, window="hann", nperseg=nperseg, noverlap=nperseg // 2, detrend=False, axis=0)
    segments = (x.shape[0] - nperseg) // (nperseg // 2) + 1
    ratio = p / expected_psd(f)
    results = []
    edges = np.geomspace(f_lo, f_hi, n_bands + 1)
    for lo, hi in itertools.pairwise(edges):
        in_band = (f >= lo) & (f < hi)
        m = int(np.count_nonzero(in_band))
        assert m >= 2, (lo, hi)
        correlation = 1 + 2 * (1 - 1 / m) * 4 / 9 + 2 * max(0.0, 1 - 2 / m) / 36
        nu = (2 * segments / 1.056) * x.shape[1] * m / correlation
        results.append((lo, hi, float(ratio[in_band].mean()), nu))
    return results


def assert_bands(results, alpha):
    failures = []
    for lo, hi, ratio, nu in results:
        lower, upper = chi2.ppf(alpha / 2, nu) / nu, chi2.ppf(1 - alpha / 2, nu) / nu
        if not lower <= ratio <= upper:
            failures.append(f"[{lo:.3g}, {hi:.3g}) Hz: ratio {ratio:.4f} outside [{lower:.4f}, {upper:.4f}]")
    assert not failures, "\n".join(failures)


def only(source, layout="type2"):
    return load_config(layout, overrides={f"noise.{n}.enabled": n == source for n in NOISE_SOURCE_NAMES})


def white_series(cfg, source, out):
    """(series (n, m), ASD per channel (m,)) of one white source, extracted from simulator output."""
    t, noise = out.truth, cfg.noise
    if source == "thruster_torque":
        return t.torque_applied_n_m - t.torque_command_n_m, noise.thruster_torque.asd
    if source == "thruster_force":
        return t.a_sc_m_s2 * cfg.spacecraft.mass_kg, noise.thruster_force.asd
    if source == "lfs_translational":
        return (t.grs_linear_meas - t.grs_linear_true).reshape(-1, 6), np.tile(noise.lfs_translational.asd, 2)
    if source == "tm_environment":
        return (t.grs_linear_meas - t.grs_linear_true).reshape(-1, 6), np.tile(noise.tm_environment.asd, 2)
    if source == "lfs_rotational":
        return (t.grs_angular_meas - t.grs_angular_true).reshape(-1, 6), np.tile(noise.lfs_rotational.asd, 2)
    if source == "grs_voltage":
        series, asd = [], []
        for i, sensor in enumerate(cfg.grs.sensors):
            clean = voltages_from_accelerations(t.grs_angular_meas[:, i], t.grs_linear_meas[:, i],
                                                sensor.angular_scale_factors, sensor.linear_scale_factors)
            series.append(out.voltages_v[:, i] - clean)
            level = noise.grs_voltage.linear_equivalent_asd_m_s2_rthz
            per_axis = level / (np.sqrt(2) * sensor.linear_scale_factors)
            asd.append(np.repeat(per_axis, 2))
        return np.hstack(series), np.concatenate(asd)
    if source == "star_tracker":
        # white per-sample sigma: one-sided PSD 2 sigma^2 / fs, i.e. ASD sigma sqrt(2 / fs)
        return attitude_error_rad(out.st_quat_xyzw, t.quat_xyzw), noise.star_tracker.sigma_rad * np.sqrt(
            2.0 / cfg.sample_rate_hz)
    raise AssertionError(source)


WHITE_SOURCES = ["thruster_torque", "thruster_force", "lfs_translational", "lfs_rotational", "tm_environment",
                 "grs_voltage", "star_tracker"]


@pytest.mark.parametrize("source", WHITE_SOURCES)
def test_white_source_psd_matches_its_asd(source):
    """Band 0.02 Hz .. 4.9 Hz (the whole band below Nyquist where the sampled noise is defined)."""
    cfg = only(source)
    out = simulate_batch(cfg, SEED, np.zeros((N_WHITE, 3)))
    series, asd = white_series(cfg, source, out)
    assert np.all(asd > 0)
    results = band_ratios(series, cfg.sample_rate_hz, NPERSEG_WHITE,
                          lambda f: np.broadcast_to(asd**2, (f.size, asd.size)), 0.02, 4.9, 8)
    assert_bands(results, FAMILY_ALPHA / len(results))
    # the disabled sources are silent: what remains of them is rounding (< 1e-6 of their level)
    shared = {"lfs_translational", "tm_environment"}  # both observed as linear meas - true
    for other in set(WHITE_SOURCES) - {source} - (shared if source in shared else set()):
        residue, other_asd = white_series(cfg, other, out)
        assert np.max(np.abs(residue)) <= 1e-6 * np.max(other_asd) * np.sqrt(cfg.sample_rate_hz / 2), other


def _srp_spec_psd(cfg):
    srp = cfg.noise.srp

    def psd(f):  # one-sided, from the configured A, f_ref, f_c
        return (srp.asd_at_f_ref_m_s2_rthz * srp.f_ref_hz) ** 2 / (np.asarray(f) ** 2 + srp.f_corner_hz**2)

    return psd


def _aliased(cfg, fs):
    """PSD of the point-sampled process, sum over all aliases f + m fs of the specification
    C / (f^2 + f_c^2), in closed form:
    sum_m C / ((f + m fs)^2 + f_c^2)
        = C pi / (fs f_c) sinh(2 pi f_c / fs) / (cosh(2 pi f_c / fs) - cos(2 pi f / fs)).
    """
    srp = cfg.noise.srp
    c = (srp.asd_at_f_ref_m_s2_rthz * srp.f_ref_hz) ** 2
    x = 2 * np.pi * srp.f_corner_hz / fs

    def expected(f):
        f = np.asarray(f)
        psd = c * np.pi / (fs * srp.f_corner_hz) * np.sinh(x) / (np.cosh(x) - np.cos(2 * np.pi * f / fs))
        return psd[:, None]

    return expected


def test_aliased_closed_form_equals_the_alias_sum():
    cfg = only("srp")
    f = np.array([1e-4, 3e-3, 0.1, 1.0, 4.9])
    m = np.arange(-200000, 200001)
    direct = np.array([np.sum(_srp_spec_psd(cfg)(x + m * 10.0)) for x in f])
    np.testing.assert_allclose(_aliased(cfg, 10.0)(f)[:, 0], direct, rtol=1e-5)  # truncated tail ~ 1e-6


def test_srp_psd_high_band():
    """SRP, 3 mHz .. 4.9 Hz at fs = 10 Hz, 2^20 samples (29 h); expectation = specified ASD^2 of the
    sampled process (aliases summed: +2.7 % at 1 Hz)."""
    cfg = only("srp")
    draws = NoiseStreams(cfg, SEED).draw(2**20).srp_m_s2
    expected = _aliased(cfg, cfg.sample_rate_hz)
    results = band_ratios(draws, cfg.sample_rate_hz, 2**15, expected, 3e-3, 4.9, 10)
    assert_bands(results, FAMILY_ALPHA / len(results))


def test_srp_psd_low_band():
    """SRP, 0.1 mHz .. 40 mHz: the 10 Hz stream (6.5e6 samples, 182 h, drawn in blocks) read every
    100th sample, Welch with 8192-sample (22.8 h) segments; expectation aliased at 0.1 Hz."""
    cfg = only("srp")
    streams = NoiseStreams(cfg, SEED + 1)
    decimation, n_out, block = 100, 2**16, 2**20
    kept = []
    for _ in range(n_out * decimation // block):
        kept.append(streams.draw(block).srp_m_s2[::decimation])
    series = np.concatenate(kept)
    fs = cfg.sample_rate_hz / decimation
    expected = _aliased(cfg, fs)
    results = band_ratios(series, fs, 2**13, expected, 1e-4, 4e-2, 8)
    assert_bands(results, FAMILY_ALPHA / len(results))


def test_srp_corner_sets_the_stationary_variance():
    """The flattening below f_c = 1e-5 Hz fixes the total power: the stationary start of 3000 seeds x 3
    axes has variance integral_0^inf ASD^2 df (numerical quadrature of the specification); tolerance:
    two-sided chi-square interval at alpha = 1e-3 with 9000 degrees of freedom (+-5 %)."""
    cfg = only("srp")
    f_c = cfg.noise.srp.f_corner_hz
    edges = [0.0, f_c, 10 * f_c, 100 * f_c, 1e3 * f_c, 1e4 * f_c, np.inf]  # quad needs the scale
    variance = sum(quad(_srp_spec_psd(cfg), a, b)[0] for a, b in itertools.pairwise(edges))
    starts = np.array([NoiseStreams(cfg, seed).draw(1).srp_m_s2[0] for seed in range(3000)])
    nu = starts.size
    ratio = np.mean(starts**2) / variance
    assert chi2.ppf(5e-4, nu) / nu <= ratio <= chi2.ppf(1 - 5e-4, nu) / nu, ratio


def test_simulator_uses_the_srp_stream_and_force_over_mass():
    cfg = only("srp", "type1")
    out = simulate_batch(cfg, SEED, np.zeros((500, 3)))
    np.testing.assert_array_equal(out.truth.a_sc_m_s2, NoiseStreams(cfg, SEED).draw(500).srp_m_s2)
    cfg = only("thruster_force", "type1")
    out = simulate_batch(cfg, SEED, np.zeros((500, 3)))
    force = NoiseStreams(cfg, SEED).draw(500).thruster_force_n
    np.testing.assert_array_equal(out.truth.a_sc_m_s2, force / cfg.spacecraft.mass_kg)


def test_every_source_is_covered():
    covered = set(WHITE_SOURCES) | {"srp"}
    assert covered == set(NOISE_SOURCE_NAMES)
    assert {f.name for f in fields(load_config("type1").noise)} == set(NOISE_SOURCE_NAMES)
