"""The joint (G, d) Gauss-Newton stops on convergence, not on its rounding floor."""

import numpy as np

from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator
from taiji2_estimator_pkg.core.com_offset import gls as com_offset_gls
from taiji2_estimator_pkg.core.com_offset import joint as joint_com_offset
from taiji2_estimator_pkg.core.instrument import InstrumentModel

from estimator_support import simulate, truth


def test_joint_estimate_converges_in_a_few_steps_to_its_fixed_point(monkeypatch):
    # the steps contract quadratically (0.3 -> 1e-3 -> 1e-6 sigma) to a rounding floor of ~1e-6 sigma; a tolerance
    # at that floor ran a third of these estimates to the 12-step limit, unconverged. Each estimate of a running
    # record must converge within 5 steps, and a second solve from another start (the converged beta) must reach it
    # to 1e-3 sigma (the rounding floor is 1e-6..1e-5 sigma; a wrong or unfinished step moves it by ~sigma)
    config, out = simulate("type1", 1200.0, 24)
    instrument = InstrumentModel.from_layout(config)
    g_true, _ = truth(config)
    scale_factors = (g_true * (1 + 3e-4), np.diag((5e-4 * g_true) ** 2))
    solutions = []

    def recording(*args, **kwargs):
        solution = joint_com_offset.solve_joint(*args, **kwargs)
        solutions.append((args, solution))
        return solution

    monkeypatch.setattr(com_offset_gls, "solve_joint", recording)
    co = ComOffsetEstimator(instrument)
    omega = out.truth.omega_rad_s
    estimates = 0
    for k in range(len(out)):
        co.update(out.t_s[k], {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]}, omega[k], scale_factors)
        if k % 500 == 499:
            estimates += co.estimate(scale_factors).determined
    assert estimates >= 15 and len(solutions) == estimates
    for (model, info_columns, g_prior, p_g, _), solution in solutions:
        assert solution.converged and solution.steps <= 5, solution.steps
        again = joint_com_offset.solve_joint(model, info_columns, g_prior, p_g, solution.beta)
        sigma = np.sqrt(np.diag(solution.covariance))
        moved = np.concatenate([again.g - solution.g, again.beta - solution.beta])
        assert np.all(np.abs(moved) <= 1e-3 * sigma), np.max(np.abs(moved) / sigma)
