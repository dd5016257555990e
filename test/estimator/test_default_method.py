"""Default (gls) method, small seeded Monte Carlo: honest covariance, no bias, at the Cramer-Rao bound.

The full check (>= 20 seeds, 3 h, both layouts, thruster force on/off) belongs to the benchmark;
here 10 x 1 h of Type-1 (thruster force on) and of Type-2 (thruster force off). With so few seeds a
single std ratio scatters by 1/sqrt(2(n-1)) (24 %), so the tolerances are the 99.9 % bands of the
sampling distributions (deterministic for the fixed seeds; a real inconsistency of 30 % fails):

- consistency: mean NEES ``e^T P^-1 e / dim`` of each quantity (G, d: 6-vectors with the joint
  covariance; d1 - d2: 3-vector) inside the chi-square(n dim) 99.9 % band;
- honesty per parameter ``error std / mean reported sigma`` inside the chi-square(n-1) 99.9 % band;
- bias per parameter ``|mean| / (std / sqrt(n))`` below the Student-t(n-1) 99.9 % quantile;
- efficiency ``error std / CRLB`` inside the same band as honesty, and the reported sigma equal to
  the bound within [0.95, 1.1] (the GLS covariance is the Fisher information of the data).
"""

import functools

import numpy as np
import pytest
from scipy.stats import chi2
from scipy.stats import t as student_t

from taiji2_apps.layout_bound import crlb_for_layout
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.pipeline import calibrate

from estimator_support import simulate, truth

DIFF = np.hstack((np.eye(3), -np.eye(3)))
SEEDS = 10
CASES = {
    "type1_thruster_on": ("type1", {}),
    "type2_thruster_off": ("type2", {"noise__thruster_force__enabled": False}),
}
P_TAIL = 5e-4  # each side of the 99.9 % bands


@pytest.fixture(scope="module", params=sorted(CASES))
def monte_carlo(request):
    return request.param, _monte_carlo(request.param)


@functools.cache
def _monte_carlo(case: str) -> dict:
    """Errors, covariances and bound per quantity: once per case and process, whatever order the tests run in
    (a module fixture is made again each time the case changes between consecutive tests)."""
    layout, overrides = CASES[case]
    rows = []
    for seed in range(SEEDS):
        config, out = simulate(layout, 3600.0, 100 + seed, **overrides)
        g_true, d_true = truth(config)
        result = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, InstrumentModel.from_layout(config))
        g, d = result.scale_factors, result.com_offsets
        diff, diff_cov = d.difference()
        rows.append({
            "G": ((g.values - g_true) / g_true, g.covariance / np.outer(g_true, g_true)),
            "d": (d.values - d_true, d.covariance),
            "d1-d2": (diff - DIFF @ d_true, diff_cov),
        })
    sim_overrides = {k.replace("__", "."): v for k, v in overrides.items()}
    bound = crlb_for_layout(layout, 3600.0, overrides=sim_overrides)
    bounds = {"G": bound.scale_factor_relative_sigma, "d": bound.com_offset_sigma,
              "d1-d2": bound.difference_sigma()}
    return {name: (np.array([r[name][0] for r in rows]), np.array([r[name][1] for r in rows]), bounds[name])
            for name in ("G", "d", "d1-d2")}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["G", "d", "d1-d2"])
def test_honest_unbiased_and_at_the_bound(monte_carlo, name):
    case, stats = monte_carlo
    errors, covariances, bound = stats[name]
    n, dim = errors.shape
    sigmas = np.sqrt(np.diagonal(covariances, axis1=1, axis2=2))
    nees = np.mean([e @ np.linalg.solve(p, e) for e, p in zip(errors, covariances, strict=True)]) / dim
    nees_band = chi2.ppf([P_TAIL, 1 - P_TAIL], n * dim) / (n * dim)
    std = errors.std(axis=0, ddof=1)
    ratio_band = np.sqrt(chi2.ppf([P_TAIL, 1 - P_TAIL], n - 1) / (n - 1))
    honesty = std / sigmas.mean(axis=0)
    t_stat = errors.mean(axis=0) / (std / np.sqrt(n))
    efficiency = std / bound
    reported = sigmas.mean(axis=0) / bound
    message = (f"{case} {name}: NEES/dim {nees:.2f} (band {np.round(nees_band, 2)}), honesty {np.round(honesty, 2)}"
               f" (band {np.round(ratio_band, 2)}), t {np.round(t_stat, 2)}, std/CRLB {np.round(efficiency, 2)}, "
               f"sigma/CRLB {np.round(reported, 3)}")
    assert nees_band[0] < nees < nees_band[1], message
    assert np.all((honesty > ratio_band[0]) & (honesty < ratio_band[1])), message
    assert np.all(np.abs(t_stat) < student_t.ppf(1 - P_TAIL, n - 1)), message
    assert np.all((efficiency > ratio_band[0]) & (efficiency < ratio_band[1])), message
    assert np.all((reported > 0.95) & (reported < 1.1)), message
