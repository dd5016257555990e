"""Attacks on the uplink of a running link graph (docs/security.md, "Attacks"): an intruder sends forged tables,
replays of genuine ones, genuine ones with a bit flipped, tables signed with a revoked key and a flood of
garbage. Every attack frame is refused onboard with its reason and counted; the planner's tables are accepted
and fly as planned; the estimates equal those of the same run without the intruder.

The short link of test_link_faults.py (fast passes, 600 s of data); the same seed for both runs, so that the
spacecraft, the link and the estimators see the same data unless an attack frame were executed.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from taiji2_runtime.packets.sdls_keys import new_key_table, write_key_file

from support import FAST_LINK_YAML, run_taiji2


def _run(tmp_path, name, key_file, *extra):
    link = tmp_path / "link.yaml"
    link.write_text(FAST_LINK_YAML % 10**12)
    out = tmp_path / name
    proc = run_taiji2("experiment", "--link", str(link), "--duration-s", "600", "--key-file", str(key_file),
                      "--out", str(out), *extra, timeout=900)
    assert proc.returncode in (0, 3), proc.stderr[-3000:]
    return json.loads((out / "results.json").read_text()), proc.stdout


@pytest.mark.slow
def test_every_attack_is_refused_reported_and_changes_nothing(tmp_path):
    # the operators' key file: SPI 1 revoked (the intruder has leaked it), SPI 2 signs
    key_file = write_key_file(tmp_path / "keys.json", new_key_table((1, 2), revoked=(1,)))
    clean, _ = _run(tmp_path, "clean", key_file)
    attacked, text = _run(tmp_path, "attacked", key_file, "--uplink-attack", "all")

    attacks = attacked["link"]["attacks"]
    intruder = attacks["intruder"]
    assert intruder["sent"] == {"forged": 3, "replay": 3, "bit_flip": 3, "revoked": 3, "garbage": 50}, intruder
    # 100 % refused, each with the reason it was built for (garbage: any refusal), none accepted
    assert attacks["refused_total"] == intruder["frames"] == 62, attacks
    expected = {k: n for k, n in intruder["expected_refusals"].items() if k != "any"}
    for reason, n in expected.items():
        assert attacks["frames_refused"].get(reason, 0) >= n, (reason, attacks)
    tables = attacked["link"]["commanding"]["tables"]
    assert attacks["frames_accepted"] == tables == clean["link"]["commanding"]["tables"]
    assert attacks["invalid_telecommands"] == 0
    # reported in telemetry too: the last frame security report the ground received counts them
    fsr = attacked["link"]["frame_security"]
    assert fsr is not None and fsr["alarm"] and sum(fsr["refused"].values()) == 62, fsr
    assert "Uplink attack: 62 frames sent" in text, text[-3000:]
    # the genuine maneuver flew as planned, as in the run without the intruder
    for key in ("tables", "acknowledged", "completed", "refused_activities", "lost_on_uplink"):
        assert attacked["link"]["commanding"][key] == clean["link"]["commanding"][key], key
    assert attacked["link"]["commanding"]["refused_activities"] == 0
    # and the estimates are those of the clean run (the same data: nothing of an attack was executed)
    for g in ("grs1", "grs2"):
        for key, cov in (("scale_factors", "scale_factors_cov"), ("com_offset", "com_offset_cov")):
            a, b = np.array(attacked[g][key]), np.array(clean[g][key])
            sigma = np.sqrt(np.diag(np.array(clean[g][cov])))
            assert np.all(np.abs(a - b) <= 1e-6 * sigma), (g, key, a, b, sigma)
    assert attacked["verdict"]["met"] == clean["verdict"]["met"]
