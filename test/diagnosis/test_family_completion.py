"""A full cross-talk of one GRS from an onset, named as one family and explained (issue 39, item 4;
:mod:`.family_completion`).

Misalignment about three axes and electrode imbalance of three pairs of GRS 2 from 1,800 s of a 1-h run (six
parameters, 20-50 sigma each; about 35 s). Selection takes four variants (its physical budget); the family as one
candidate stands (naming rule 3), and the final scan, run with the two variants the stack lacks from the stack's
onset, finds nothing left: without the completion the same data read "unexplained gap at ang_diff_y 0.01-0.03
Hz" after the onset. Seeded.
"""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.diagnosis import diagnose, prepare_input
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

ONSET_S = 1800.0


def test_a_full_cross_talk_from_an_onset_is_one_family_and_explained():
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, 36000)
    truth = {"misalignment_rad": [2e-3, -2.5e-3, 3e-3], "imbalance": [1e-3, -1e-3, 1.5e-3]}
    out = simulate_batch(config, 23, commands, effects=[make_effect("cross_coupling", grs=2, **truth,
                                                                    onset_s=ONSET_S)])
    result = diagnose(prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz),
                      config)
    assert result.verdict["summary"] == "explained by cross_coupling", result.verdict["summary"]
    (family,) = [f for f in result.verdict["families"] if f["family"] == "cross_coupling[grs2]"]
    assert family["stands"] and family["n_params"] == 6
    stack = [e for e in result.effects if e.accepted]
    assert len(stack) > 2 and all(e.name == "cross_coupling" and e.variant.startswith("grs2.") for e in stack)
    added = result.verdict["completed_families"]["cross_coupling[grs2]"]
    assert sorted(added + [e.key for e in stack]) == sorted(family["variants"])
    # every variant of the stack starts at the onset (each profiled on its own)
    onsets = np.array([e.parameters["onset_s"]["value"] for e in stack])
    sigmas = np.array([e.parameters["onset_s"]["sigma"] for e in stack])
    assert np.all(np.abs(onsets - ONSET_S) < 3.0 * sigmas), (onsets, sigmas)
