"""Location scan: tail probabilities, harmonic bins, false-alarm level on pure noise, detection of a tone."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import gamma

try:
    import taiji2_estimator_pkg.diagnosis  # noqa: F401
except ImportError:  # an editable install made before the package had modules
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src" / "taiji2_estimator_pkg"))

from taiji2_estimator_pkg.diagnosis.locations import LocationGrid, log10_tail, scan_locations

EDGES = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0, 5.0)


def test_log10_tail_matches_scipy_and_far_tail():
    for shape, value in ((3, 2.0), (50, 80.0), (1000, 1100.0)):
        assert log10_tail(shape, value) == np.float64(-np.log10(gamma.sf(value, shape)))
    far = float(log10_tail(10, 400.0))  # beyond double precision of the direct tail
    assert 150 < far < 200 and np.isfinite(far)
    assert float(log10_tail(10, 1.0)) >= 0.0


def test_harmonic_mask_marks_the_maneuver_lines():
    grid = LocationGrid(36000, 10.0, EDGES, 250.0, 1)
    freq = grid.frequencies_hz
    mask = grid.harmonic_mask()
    for h in (1, 2, 7, 40):
        k = int(np.argmin(np.abs(freq - h / 250.0)))
        assert mask[k]
    assert 0.18 < mask.mean() < 0.24  # three bins per harmonic spacing of 14.4 bins


def test_pure_noise_false_alarm_and_a_tone_is_found():
    n = 36000
    grid = LocationGrid(n, 10.0, EDGES, 250.0, 1)
    rng = np.random.default_rng(0)
    t = np.arange(1, n + 1) * 0.1
    alarms = 0
    for _ in range(10):
        noise = (rng.normal(size=((n - 1) // 2, 15)) + 1j * rng.normal(size=((n - 1) // 2, 15))) / np.sqrt(2)
        locations, count, threshold = scan_locations({"marginal": noise}, grid, t, 3, 0.01)
        alarms += any(loc.significant for loc in locations)
        assert count > 500 and 4.5 < threshold < 5.5
    assert alarms <= 1
    tone = noise.copy()
    k = round(0.0123 * n / 10.0)
    tone[k - 1, 4] += 12.0  # one line in torque_y in the 1e-2..3e-2 band
    locations, _, _ = scan_locations({"marginal": tone}, grid, t, 3, 0.01)
    top = locations[0]
    assert top.significant and top.channel == "torque_y" and top.band_hz == (1e-2, 3e-2)
    assert top.segment == "all" and top.gap > 1.0
