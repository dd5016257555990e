"""A gravity gradient is named on every axis it torques, and leaves neither a gap nor an "impulse" (issue 39, pairs
fully explained; :mod:`.evaluation`, :mod:`.impulses`).

The catalog gradient of a high Earth orbit (orbit normal (0.3, 0.2, 0.93)) at 7 % of its point-mass size torques
all three axes; 3 h hold a quarter of its 2n period. Its components trained on the first 2 h extrapolate into the
last hour with the training error dominating the held-out z (its spread 2-2.5 where 1 was assumed): before the spread
was included, the x and z components were "contradicted by the held-out data" in every blind set where they were
selected, each leaving a sub-mHz torque gap; its constant part, which the fit's dropped DC bin leaves in the
residual, made the impulse statistic non-central (an SNR-6 "impulse" in 3 of 4 seeds). About 40 s. Seeded (the
seed that read "unexplained gap at torque_x" before).

The noise of this seed holds one sample at the impulse search's threshold (SNR 5.97 at 1,946.5 s, threshold 5.96:
a 1 %-per-record false alarm that the noise alone reports); the non-central statistic raised it to 6.85. So the
gradient is held to adding no impulse to those of the same noise alone and moving none of theirs by more than 0.2
in SNR.
"""

from __future__ import annotations

from taiji2_estimator_pkg.diagnosis import diagnose, prepare_input
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch


def _diagnosed(effects: list) -> object:
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, 108000)
    out = simulate_batch(config, 6, commands, effects=effects)
    return diagnose(prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz),
                    load_config("type1"))


def test_a_gravity_gradient_is_named_on_its_axes_with_no_gap_and_no_impulse():
    result = _diagnosed([make_effect("gravity_gradient", orbit_period_s=86164.1, scale=0.0711)])
    assert result.verdict["summary"].startswith("explained by gravity_gradient"), result.verdict["summary"]
    named = {e.variant: e for e in result.effects if e.accepted}
    assert set(named) >= {"y", "z"}, sorted(named)
    # the extrapolated components' held-out z spreads well beyond 1 (the trained magnitude's error)
    assert max(e.heldout_z_sd for e in named.values()) > 1.5, {k: e.heldout_z_sd for k, e in named.items()}
    noise_alone = {round(event["time_s"], 1): event["snr"] for event in _diagnosed([]).impulses["events"]}
    for event in result.impulses["events"]:
        assert round(event["time_s"], 1) in noise_alone, (event, noise_alone)
        assert abs(event["snr"] - noise_alone[round(event["time_s"], 1)]) < 0.2, (event, noise_alone)
