"""The impulse effect: the rate steps by J^-1 L in the step that holds the impulse, in both simulators."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_model.config import load_config
from taiji2_model.effect_catalog import Impulse, make_effect
from taiji2_sim_pkg.core.reference import simulate_reference
from taiji2_sim_pkg.core.simulator import simulate_batch

NOISE = ("thruster_torque", "thruster_force", "srp", "lfs_translational", "lfs_rotational", "tm_environment",
         "grs_voltage", "star_tracker")
L_N_M_S = np.array([2e-7, -1e-7, 3e-7])


@pytest.mark.parametrize("simulate", [simulate_batch, simulate_reference], ids=["standard", "reference"])
def test_the_rate_steps_by_the_inverse_inertia_times_the_angular_momentum(simulate):
    config = load_config("type1", overrides={f"noise.{s}.enabled": False for s in NOISE})
    out = simulate(config, 1, np.zeros((600, 3)), effects=[Impulse(12.34, L_N_M_S, (1e-7, 0.0, 0.0))])
    omega = out.truth.omega_rad_s
    expected = np.linalg.solve(config.spacecraft.inertia_kg_m2, L_N_M_S)
    # the step (12.3, 12.4] holds the impulse: sample 123 (stamp 12.4 s) is the first after it
    np.testing.assert_allclose(omega[123] - omega[122], expected, rtol=1e-9)
    assert np.all(omega[:123] == 0.0)
    # afterwards only the gyroscopic term omega x J omega of the new rate moves it: ~|omega|^2 t ~ 1e-18 rad/s
    # over the 60 s, 1e-8 of the step
    np.testing.assert_allclose(omega[-1], expected, rtol=1e-6)


def test_parameters_are_checked_and_named():
    with pytest.raises(ValueError, match=r"impulse.*angular_momentum_n_m_s"):
        make_effect("impulse", time_s=1.0, angular_momentum_n_m_s=[1.0, 2.0])
    assert make_effect("impulse", time_s=5.0, angular_momentum_n_m_s=1e-7).to_dict()["time_s"] == 5.0
