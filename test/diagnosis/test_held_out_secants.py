"""The held-out parts take the accepted second-order signatures at their whole-run magnitudes (issue 39, pairs
fully explained; :mod:`.stages.held_out`).

A readout nonlinearity of GRS2's psi readout from 2,395 s (delta chi2 ~64,000 on the reference fidelity) beside
an 8.6-sigma scale-factor drift of GRS1's pair x, with the reference timing conventions of blind seed 17, set 46:
with the nonlinearity at first order in the held-out parts, the drift read held-out z = -0.4 where 5.8 +- 1.1 was
expected, was refused, and the set read "unexplained gap at ang_diff_z 0.003-0.01 Hz". About 60 s. Seeded (the
set's own seed); the magnitudes within 3 sigma of the truth.
"""

from __future__ import annotations

from taiji2_estimator_pkg.diagnosis import diagnose, prepare_input
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.reference import simulate_reference
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands

NONLINEARITY = 11863072.75  # 1/(rad s^-2)
DRIFT_PER_S = 1.2555e-7


def test_a_drift_beside_a_large_nonlinearity_is_held_out_against_its_secant():
    timing = {"timing.actuation_latency_s": 0.10918, "timing.thruster_time_constant_s": 0.11104}
    config = load_config("type1", {**timing, "grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, 108000)
    effects = [make_effect("readout_nonlinearity", k=NONLINEARITY, grs=2, readout="psi", onset_s=2395.35),
               make_effect("scale_factor_drift", rate_per_s=DRIFT_PER_S, grs=1, axis="x")]
    out = simulate_reference(config, 17046, commands, effects=effects)
    result = diagnose(prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz),
                      load_config("type1"))
    assert not result.verdict["unexplained"], result.verdict["summary"]
    named = {e.key: e for e in result.effects if e.accepted}
    assert {"readout_nonlinearity[grs2.psi]", "scale_factor_drift[grs1.x]"} <= set(named), sorted(named)
    for key, truth in (("readout_nonlinearity[grs2.psi]", NONLINEARITY), ("scale_factor_drift[grs1.x]", DRIFT_PER_S)):
        assert abs(named[key].magnitude - truth) < 3.0 * named[key].sigma, (key, named[key].magnitude, truth)
