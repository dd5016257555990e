"""A readout nonlinearity from an onset against a step of its readout (naming rule 4, :mod:`.readout_step`).

Runs of 1 h at 10 Hz (about 10 s each), the readout saturation off as in the blind benchmark. A bias step of
GRS1's x readout from 1,800 s (out of the catalog; blind seed 16, set 49 named it a nonlinearity at -10.6 sigma)
is not named; a nonlinearity of that readout from 1,800 s, large enough to differ from a step (about 60 sigma:
at 12 sigma the data do not tell the two apart), is. Seeded; the step's gain beside the nonlinearity is about
its noise (delta chi2 0-3 in the trials), the nonlinearity's beside the step several times the floor.
"""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.diagnosis import diagnose, prepare_input
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_model.effects import Effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

HOUR = 36000
ONSET_S = 1800.0


class _ReadoutBiasStep(Effect):
    """Out of the catalog: a step of one GRS linear readout (m s^-2) from ``t_step_s`` on."""

    name = "grs_bias_step"

    def __init__(self, step_m_s2: float, grs: int, axis: int, t_step_s: float) -> None:
        self.step_m_s2, self.grs, self.axis, self.t_step_s = step_m_s2, grs, axis, t_step_s

    def grs_accelerations(self, t_s, grs_id, angular, linear):
        if grs_id != self.grs:
            return angular, linear
        out = np.array(linear)
        out[:, self.axis] += np.where(t_s >= self.t_step_s, self.step_m_s2, 0.0)
        return angular, out


def _diagnose(effect: Effect):
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, HOUR)
    out = simulate_batch(config, 11, commands, effects=[effect])
    return diagnose(prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz), config)


def test_a_readout_bias_step_is_not_named_a_nonlinearity():
    result = _diagnose(_ReadoutBiasStep(3e-12, 1, 0, ONSET_S))
    refused = [e for e in result.effects if e.key == "readout_nonlinearity[grs1.x]"]
    assert refused and not refused[0].accepted, [(e.key, e.accepted) for e in result.effects]
    assert refused[0].rejected.startswith("a step of the grs1.x readout at"), refused[0].rejected
    assert "readout_nonlinearity" not in result.verdict["effects"] and result.verdict["unexplained"]
    assert "a step of the grs1.x readout at" in result.verdict["summary"], result.verdict["summary"]


def test_a_nonlinearity_from_an_onset_that_differs_from_a_step_is_named():
    result = _diagnose(make_effect("readout_nonlinearity", k=2e7, grs=1, readout="x", onset_s=ONSET_S))
    assert result.verdict["summary"] == "explained by readout_nonlinearity", result.verdict
    (named,) = [e for e in result.effects if e.accepted]
    onset = named.parameters["onset_s"]
    assert named.key == "readout_nonlinearity[grs1.x]" and onset["modelled"]
    assert abs(onset["value"] - ONSET_S) < 3.0 * onset["sigma"], onset
    assert named.magnitude == pytest.approx(2e7, abs=3.0 * named.sigma)
