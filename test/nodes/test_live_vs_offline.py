"""Live node vs offline calibration of the same data (issue 26 row 8). The c.m.-offset node accumulates every
epoch as it arrives (``ComOffsetEstimator.update``) and publishes d with the latest G as prior: with the final G
its d1 - d2 is the offline estimate without the offline-only noise adaptation (``adapt_noise``) to a small
fraction of sigma. Where ``taiji2 calibrate`` adapts the noise (``com_offset_noise.noise_adjusted``) the two
differ by what the adaptation moves (docs/estimators.md, "Live graph vs offline": 0.32 sigma on a 900-s graph,
0.014 sigma without it). A node-level check of the same equality, on a 900-s graph, is in that section."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.parameters import DEFAULTS, com_offset_options, scale_factor_options
from taiji2_estimator_pkg.core.pipeline import calibrate
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

N = 6000  # 600 s at 10 Hz: d determined
#: bound on |node path - offline| / sigma of d1 - d2 without the noise adaptation (seen: 0.014 on a 900-s graph,
#: 0.15 on this record; what remains is the bulk path's own recursion, body rate and gating, not isolated)
BOUND_SIGMA = 0.25


def test_the_node_path_equals_offline_without_noise_adaptation():
    # the unclipped readout: the paper's preset leaves the GRS range with the noise, and gating saturated
    # epochs is where the two paths differ most (the bound below was set on unclipped data)
    config = load_config("type1", overrides={"maneuver.duration_s": N / 10, "grs.readout_saturation": False})
    out = simulate_batch(config, 8, maneuver_torque_commands(config, N))
    instrument = InstrumentModel.from_layout("type1")
    sf_options = scale_factor_options(dict(DEFAULTS["scale_factor_estimator"]))
    results = {}
    for adapt in (False,):
        options = com_offset_options(dict(DEFAULTS["com_offset_estimator"], adapt_noise=adapt))
        results[adapt] = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, instrument, (1, 2), "gls", sf_options,
                                   options)
    offline = results[False]
    g = (np.asarray(offline.scale_factors.values), np.asarray(offline.scale_factors.covariance))
    node = ComOffsetEstimator(instrument, (1, 2), com_offset_options(dict(DEFAULTS["com_offset_estimator"])))
    for k in range(N):  # as the node: epoch by epoch, no body rate (use_rate_estimate false), then the final G
        node.update(float(out.t_s[k]), {1: out.voltages_v[k][0], 2: out.voltages_v[k][1]}, None, scale_factors=g)
    live, _ = node.estimate(g).difference()
    diff, cov = offline.com_offsets.difference()
    sigma = np.sqrt(np.diag(cov))
    assert np.all(np.isfinite(live)) and np.all(np.abs((live - diff) / sigma) < BOUND_SIGMA), (live - diff) / sigma
