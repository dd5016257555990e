"""The corrected calibration through the command line (issue 24), end to end on one bag:

``taiji2 diagnose BAG --write-config FILE`` names a mid-run effect and writes the extended layout;
``taiji2 diagnose BAG --config FILE`` then reads "no significant gap"; ``taiji2 calibrate BAG --config FILE``
removes the effect from the raw data and moves G to the diagnosis's corrected value.

A seeded statistical test (1 h, seed 11, a 2e-6 /s scale-factor drift of GRS1 x from t = 1800 s, about
15 sigma): the reproduction is checked to 2 sigma of ``calibrate``'s G (the less precise of the two
calibrations: the diagnosis's nominal calibration uses every channel).
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import yaml

from support import run_taiji2

ONSET_S = 1800.0


def _taiji2(*argv: str) -> subprocess.CompletedProcess:
    return run_taiji2(*argv, timeout=300)


def test_write_config_then_diagnose_and_calibrate_with_it(tmp_path):
    bag, layout = tmp_path / "bag", tmp_path / "extended.yaml"
    # the paper's preset, the scenario this test was made for: with the shipped design (the default maneuver now)
    # calibrate --config put GRS1 G_psi 9.0e-11 from the diagnosis's corrected value, the nominal calibrate 3.8e-12:
    # an open finding for the corrected-calibration work, not hidden here
    # (unclipped: the preset leaves the GRS range in ~15 % of its samples, which the saturation would clip)
    proc = _taiji2("simulate", "--maneuver", "paper", "--override", "grs.readout_saturation=false", "--duration-s",
                   "3600", "--seed", "11", "--out", str(bag), "--effect",
                   f"scale_factor_drift:rate_per_s=2e-6,grs=1,axis=x,onset_s={ONSET_S:g}")
    assert proc.returncode == 0, proc.stderr

    proc = _taiji2("diagnose", str(bag), "--write-config", str(layout), "--out", str(tmp_path / "d1"),
                   "--no-plots", "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["verdict"]["effects"] == ["scale_factor_drift"], report["verdict"]["summary"]
    effects = yaml.safe_load(layout.read_text())["effects"]
    assert [e["name"] for e in effects] == ["scale_factor_drift"]
    assert (effects[0]["grs"], effects[0]["axis"]) == (1, "x")
    named = next(e for e in report["effects"] if (e["name"], e["variant"]) == ("scale_factor_drift", "grs1.x"))
    onset = named["parameters"]["onset_s"]
    assert abs(effects[0]["onset_s"] - ONSET_S) < 3.0 * onset["sigma"]

    proc = _taiji2("diagnose", str(bag), "--config", str(layout), "--out", str(tmp_path / "d2"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "verdict: no significant gap" in proc.stdout

    nominal = json.loads(_taiji2("calibrate", str(bag), "--json").stdout)
    proc = _taiji2("calibrate", str(bag), "--config", str(layout), "--json")
    extended = json.loads(proc.stdout)
    assert proc.returncode == (0 if extended["verdict"]["all_met"] else 3), proc.stderr
    assert extended["known_effects"]["corrected"] == ["scale_factor_drift"]
    g_nominal = np.array(nominal["grs1"]["scale_factors"])
    g_extended = np.array(extended["grs1"]["scale_factors"])
    sigma = np.sqrt(np.diag(extended["grs1"]["scale_factors_cov"]))
    g_diagnosis = np.array(report["corrected_calibration"]["g_angular"][0])
    # the drift moves G_psi of GRS1 (its x electrodes); calibrate --config reproduces the diagnosis's correction
    assert abs(g_extended[2] - g_diagnosis[2]) < abs(g_nominal[2] - g_diagnosis[2])
    assert np.all(np.abs(g_extended - g_diagnosis) < 2.0 * sigma), (g_extended - g_diagnosis) / sigma
